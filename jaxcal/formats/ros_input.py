"""What a filter fed by a ROS driver reads: ``sensor_msgs/Imu`` samples in m/s^2 and rad/s.

The Kalibr and OpenVINS exports write, by default (``units="ros"``), the intrinsics expressed on that
input: the driver multiplies the model's input ``y`` (the unit the model was fitted on) by a per-axis
conversion ``c`` (ROS unit per model unit), so the file's equation ``x = A_ros (y_ros - b_ros)`` with
``y_ros = c * y`` has ``A_ros = A diag(1/c)`` and ``b_ros = c * b`` (:func:`ros_cals`).
:func:`ros_input` chooses ``c`` per sensor: a model fitted on ``g`` -> 9.80665 (m/s^2 per g), on
``rad/s`` -> 1; a raw (``LSB``) model -> the datasheet scale the driver applies (``acc_lsb_per_g``,
``gyr_lsb_per_rads``), or, without one, the model's own mean diagonal scale (said in the file).
:func:`not_carried` names what a linear model's file cannot give the filter, in the words of the tool that
reads it (a :class:`RosTool`, declared by its format). Pure functions, no I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from jaxcal.constants import G0
from jaxcal.formats.linear_io import IMU_SENSORS, model_units
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.sensor import LinearCal

__all__ = ["DATASHEET_KEYS", "IMU0_LIMITS", "ROS_UNIT", "UNITS", "RosInput", "RosTool", "not_carried", "ros_cals",
           "ros_input"]

ROS_UNIT = {"acc": "m/s^2", "gyr": "rad/s"}
"""The units of ``sensor_msgs/Imu`` (``linear_acceleration``, ``angular_velocity``)."""

DATASHEET_KEYS = {"acc": "acc_lsb_per_g", "gyr": "gyr_lsb_per_rads"}
"""The datasheet scale of a raw model's sensor, named as in a recording's metadata (LSB/g, LSB/(rad/s))."""

UNITS = ("ros", "model")
"""``ExportOptions.units``: ``ros`` (the driver's m/s^2 and rad/s, the default) or ``model`` (the model's own input unit)."""

_PER_JAXCAL_UNIT = {"acc": G0, "gyr": 1.0}  # ROS unit per jaxcal output unit (m/s^2 per g, rad/s per rad/s)


class RosInput(NamedTuple):
    """The ROS driver's conversion of a model's input, per sensor.

    Args:
        per_model_unit: ``sensor -> (3,)`` ROS unit (m/s^2, rad/s) per model input unit, per axis.
        model_unit: ``sensor ->`` the model's input unit (``g``, ``rad/s``, ``LSB``).
        how: ``sensor ->`` one line saying where the conversion comes from.
    """

    per_model_unit: dict[str, np.ndarray]
    model_unit: dict[str, str]
    how: dict[str, str]


class RosTool(NamedTuple):
    """A ROS-fed tool that reads an export's ``imu0`` file (``Format.ros_tool``: Kalibr, OpenVINS), and
    what that file cannot give it, in the tool's own terms (:func:`not_carried`).

    Args:
        name: the tool, as the file's header names it (``"Kalibr"``).
        bias: the phrase on the constant bias the file does not carry (``"the constant bias (...)"``).
        prior: why the tool gets no prior on the bias (one clause, e.g. ``"Kalibr has no key for a bias prior"``).
    """

    name: str
    bias: str
    prior: str


def _datasheet_value(datasheet: Mapping[str, Any], key: str) -> np.ndarray | None:
    """A datasheet scale (one number or three, finite and non-zero) as (3,), or ``None`` when not given."""
    v = datasheet.get(key)
    if v is None:
        return None
    a = np.broadcast_to(np.asarray(v, np.float64), (3,)) if np.ndim(v) in (0, 1) else None
    if a is None or a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a == 0):
        raise ModelError(f"--{key.replace('_', '-')} must be one non-zero number or three, got {v!r}")
    return np.array(a)


def ros_input(model: CalibrationModel, cals: Mapping[str, LinearCal],
              datasheet: Mapping[str, Any] | None = None) -> RosInput:
    """The conversion a ROS driver applies to the model's input, per sensor (``acc``, ``gyr``).

    Args:
        model: a linear model (its ``meta["units"]`` gives the input unit; none recorded: raw).
        cals: :func:`~jaxcal.formats.linear_io.linear_cals` of the model (jaxcal units: g, rad/s).
        datasheet: ``acc_lsb_per_g`` / ``gyr_lsb_per_rads`` (one number or three) for a raw model.

    Raises:
        ModelError: a datasheet scale for a sensor that is not raw, or not a usable number.
    """
    datasheet = datasheet or {}
    unknown = sorted(set(datasheet) - set(DATASHEET_KEYS.values()))
    if unknown:
        raise ModelError(f"unknown datasheet keys {', '.join(unknown)} (expected {', '.join(DATASHEET_KEYS.values())})")
    per, unit, how = {}, {}, {}
    for s in IMU_SENSORS:
        u = model_units(model, s)[0] or "LSB"
        key, ros = DATASHEET_KEYS[s], ROS_UNIT[s]
        v = _datasheet_value(datasheet, key)
        if u != "LSB":
            if v is not None:
                raise ModelError(f"--{key.replace('_', '-')} is a raw model's datasheet scale, but the {s} model was "
                                 f"fitted on {u}")
            per[s] = np.full(3, _PER_JAXCAL_UNIT[s])
            how[s] = f"{ros} = {u} x {float(per[s][0])!r} (the model was fitted on {u})"
        elif v is not None:
            per[s] = _PER_JAXCAL_UNIT[s] / v
            how[s] = f"{ros} = LSB x {_PER_JAXCAL_UNIT[s]!r} / {key} (datasheet {key} = {[float(x) for x in v]})"
        else:
            k = float(np.mean(np.abs(np.diag(np.linalg.inv(cals[s].A)))))
            per[s] = np.full(3, _PER_JAXCAL_UNIT[s] / k)
            how[s] = (f"{ros} = LSB x {float(per[s][0])!r}: no datasheet {key} given, so the model's own mean scale "
                      f"({k!r} LSB per {'g' if s == 'acc' else 'rad/s'}) stands in for the driver's conversion")
        unit[s] = u
    return RosInput(per, unit, how)


def ros_cals(phys: Mapping[str, LinearCal], ros: RosInput) -> dict[str, LinearCal]:
    """:func:`~jaxcal.formats.linear_io.physical_cals` on the driver's input: ``A diag(1/c)``, ``c * b``.

    Args:
        phys: ``acc``, ``gyr`` -> ``x = A (y - b)`` in m/s^2 and rad/s from the model's input unit.
        ros: :func:`ros_input`.
    """
    return {s: LinearCal(phys[s].A / ros.per_model_unit[s][None, :], phys[s].b * ros.per_model_unit[s])
            for s in IMU_SENSORS}


IMU0_LIMITS = ("imu0's time_offset and T_i_b are relative to imu0 (identity and 0 for one IMU), and the camera-IMU "
               "time shift is timeshift_cam_imu in the camchain, against a camera: a time offset or lever arm against "
               "a reference, as diagnose and align find, has no key in this file")
"""Why a Kalibr / OpenVINS IMU file cannot hold a time offset or transform against a reference."""


def not_carried(tool: RosTool, units: str, has_bias_sd: bool = False, intrinsics_folds: int = 0) -> list[str]:
    """What a linear model's file for ``tool`` (Kalibr, OpenVINS) does not give the filter, one phrase each.

    Args:
        tool: the tool that reads the file (its format's ``ros_tool``).
        units: ``ros`` or ``model``.
        has_bias_sd: the file holds the biases' standard errors (``jaxcal_b_a_sd``, ``jaxcal_b_g_sd``).
        intrinsics_folds: the number of held-out folds whose jackknife gave the file's
            ``jaxcal_intrinsics_sd`` (0: the file has none).
    """
    bias, prior = tool.bias, tool.prior
    if has_bias_sd:
        sd = (f"a prior on the bias ({prior}; its standard error is in jaxcal_b_a_sd / jaxcal_b_g_sd: for multipos a "
              "delete-one-pose jackknife of this session's estimate, to which the part's turn-on repeatability adds)")
    else:
        sd = f"a standard deviation of the bias (this model's fit recorded none; {prior})"
    where = (f"their standard errors, a delete-one-pose jackknife over {intrinsics_folds} folds of the file's own numbers "
             "(a g-sensitivity held at the whole fit's value), are in jaxcal_intrinsics_sd"
             if intrinsics_folds else "this model's fit recorded no standard errors for them")
    out = [bias, sd, f"a prior on the intrinsics ({tool.name} has no key for one; {where})",
           f"time_offset and T_i_b ({IMU0_LIMITS})"]
    if units == "model":
        out.append("the ROS units (written in the model's input unit: a ROS driver's m/s^2 and rad/s need --units ros)")
    return out
