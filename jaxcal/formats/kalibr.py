"""Kalibr (ethz-asl/kalibr): its ``scale-misalignment`` IMU intrinsics, written and read back.

:func:`to_kalibr` writes a linear model in Kalibr's parameterisation (:data:`KALIBR_CONVENTION`): the
accelerometer in m/s^2 and the gyroscope in rad/s, by default from the input a ROS driver publishes
(``sensor_msgs/Imu``, m/s^2 and rad/s: :mod:`jaxcal.formats.ros_input`, the conversion written in the
file), or with ``units="model"`` from the raw input ``y`` in the model's own input unit (the unit
conversion and any counts-to-physical scale folded into its matrices). Kalibr holds no constant bias, so ``b`` goes under
``jaxcal_b_a`` / ``jaxcal_b_g``; a gyro g-sensitivity is Kalibr's ``A = S_g G C_gyro_b^T / G0``. The noise
keys of a Kalibr ``imu.yaml`` (:mod:`jaxcal.formats.noise_yaml`) go in as ``imu_fields``.
:func:`document` writes the file, :func:`from_kalibr` reads it back as a ``linear`` model (lever arms
and other IMU models refused). Pure functions, no I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from jaxcal.constants import G0
from jaxcal.formats.base import Exported, ExportOptions, Format, Imported
from jaxcal.formats.linear_io import (
    g_sensitivity,
    imported_model,
    inv,
    keep_gsens,
    lower_times_rotation,
    matrix,
    rotation,
    rows,
)
from jaxcal.formats.noise_yaml import NOISE_KEYS
from jaxcal.formats.ros_input import RosInput, RosTool
from jaxcal.formats.yaml_doc import (
    document_text,
    export_cals,
    imu0,
    imu_dict,
    intrinsics_sd,
    parse_yaml,
    to_model_unit,
    yaml_bias_units,
    yaml_export,
)
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.sensor import LinearCal

__all__ = ["FORMAT", "KALIBR_CONVENTION", "KALIBR_KEYS", "ROS_TOOL", "document", "from_kalibr", "to_kalibr"]

ROS_TOOL = RosTool("Kalibr", "the constant bias (Kalibr has no bias key: it estimates the bias itself; jaxcal_b_a / "
                   "jaxcal_b_g are not read)", "Kalibr has no key for a bias prior")
"""Kalibr, the tool that reads the export, and what its file lacks (:func:`~jaxcal.formats.ros_input.not_carried`)."""

KALIBR_CONVENTION = """\
Kalibr IMU intrinsics, model scale-misalignment (kalibr IccSensors.py, IccScaledMisalignedImu:
addAccelerometerErrorTerms / addGyroscopeErrorTerms), forward model with lever arm 0:
  alpha = M_a @ (C_i_b @ a_b) + b_a
  omega = M_g @ (C_gyro_i @ C_i_b @ w_b) + A @ (C_gyro_i @ C_i_b @ a_b) + b_g
so the calibrated samples are
  a_b = C_i_b.T @ inv(M_a) @ (alpha - b_a)                 [m/s^2]
  w_b = C_i_b.T @ C_gyro_i.T @ inv(M_g) @ (omega - b_g - A @ C_gyro_i @ C_i_b @ a_b)     [rad/s]
a_b: the specific force in the body frame, m/s^2 (Kalibr: C_b_w (a_w - g_w)); applied, the calibrated a_b above.
A (gyroscopes.A, g-sensitivity, input unit per m/s^2) = S_g @ G @ (C_gyro_i @ C_i_b).T / 9.80665 for a jaxcal
model y_g = S_g (w_b + G f) + b_g with g-sensitivity G ((rad/s)/g, f = a_b / 9.80665, S_g = M_g C_gyro_i C_i_b);
0 when the model has none.
M_a, M_g: lower triangular (accelerometers.M, gyroscopes.M); C_gyro_i: rotation (gyroscopes.C_gyro_i);
C_i_b: rotation block of T_i_b (translation 0), from jaxcal's calibrated frame b to Kalibr's IMU frame i,
whose axes Kalibr ties to the accelerometer (lower-triangular M_a). alpha, omega: raw samples in the
input unit jaxcal_input_unit_acc/_gyr names; b_a, b_g: jaxcal_b_a, jaxcal_b_g in that unit (Kalibr stores no
constant bias). Noise keys: Kalibr's imu.yaml values (SI, continuous time). Matrices are lists of rows."""
"""The convention header of :func:`to_kalibr`'s file (also in its :func:`document`)."""

KALIBR_KEYS = ("T_i_b", *NOISE_KEYS, "model", "accelerometers", "gyroscopes")
"""The order of the ``imu0`` keys of :func:`to_kalibr`'s file (then jaxcal's ``jaxcal_*`` keys)."""


def to_kalibr(model: CalibrationModel, imu_fields: Mapping[str, Any] | None = None, units: str = "ros",
              datasheet: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A linear model as Kalibr's ``scale-misalignment`` IMU intrinsics (``{"imu0": {...}}``).

    Convention (:data:`KALIBR_CONVENTION`): Kalibr's forward model is ``alpha = M_a C_i_b a_b + b_a``,
    ``omega = M_g C_gyro_i C_i_b w_b + b_g`` (``A`` = 0), so jaxcal's forward matrices (input unit per
    m/s^2 or rad/s, the inverses of :func:`physical_cals`' ``A``) are split as ``S_a = M_a C_i_b``
    and ``S_g C_i_b^T = M_g C_gyro_i`` with :func:`lower_times_rotation`. ``M`` are forward matrices
    (raw per physical), not inverses. ``C_i_b`` goes in ``T_i_b`` (4x4, translation 0): Kalibr's IMU
    frame ``i`` follows the accelerometer axes, jaxcal's calibrated frame is ``b``.

    Args:
        model: a linear model with ``acc`` and ``gyr``.
        imu_fields: further ``imu0`` entries (e.g. ``rostopic``, ``update_rate``, noise densities),
            added after jaxcal's; they may not replace them.
        units: ``"ros"``: ``alpha``, ``omega`` are a ROS driver's m/s^2 and rad/s
            (:func:`~jaxcal.formats.yaml_doc.export_cals`); ``"model"``: the model's own input unit.
        datasheet: a raw model's ``acc_lsb_per_g`` / ``gyr_lsb_per_rads`` (``units="ros"``).

    Raises:
        ModelError: the model is not linear, lacks a sensor, or has a singular matrix.
        ValueError: ``imu_fields`` would replace a calibration key.
    """
    return _kalibr_dict(model, imu_fields, units, datasheet)[0]


def _kalibr_dict(model: CalibrationModel, imu_fields: Mapping[str, Any] | None, units: str,
                 datasheet: Mapping[str, Any] | None) -> tuple[dict[str, Any], RosInput | None]:
    """:func:`to_kalibr`'s dict and the ROS conversion it used (``None`` with ``units="model"``)."""
    cals, ros = export_cals(model, units, datasheet)
    imu = {"model": "scale-misalignment", **_intrinsics(model, cals)}
    return imu_dict(model, imu, cals, ros, imu_fields, KALIBR_KEYS, intrinsics_sd(model, ros, _intrinsics)), ros


def _intrinsics(model: CalibrationModel, cals: Mapping[str, LinearCal]) -> dict[str, Any]:
    """The calibration keys of :func:`to_kalibr`'s file from the ``x = A (y - b)`` it writes."""
    S_a, S_g = np.linalg.inv(cals["acc"].A), np.linalg.inv(cals["gyr"].A)
    M_a, C_i_b = lower_times_rotation(S_a)
    M_g, C_gyro_i = lower_times_rotation(S_g @ C_i_b.T)
    T_i_b = np.eye(4)
    T_i_b[:3, :3] = C_i_b
    return {"T_i_b": rows(T_i_b), "accelerometers": {"M": rows(M_a)},
            "gyroscopes": {"M": rows(M_g), "A": rows(_kalibr_A(model, S_g, C_gyro_i @ C_i_b)), "C_gyro_i": rows(C_gyro_i)}}


def _kalibr_A(model: CalibrationModel, S_g: np.ndarray, C_gyro_b: np.ndarray) -> np.ndarray:
    """Kalibr's gyro g-sensitivity ``A = S_g G C_gyro_b^T / G0`` (input unit per m/s^2; zero without ``G``)."""
    G = g_sensitivity(model)
    return np.zeros((3, 3)) if G is None else S_g @ G @ C_gyro_b.T / G0


def from_kalibr(doc: Any, drop_g_sensitivity: bool = False) -> Imported:
    """Kalibr's ``scale-misalignment`` IMU intrinsics (:func:`to_kalibr`'s YAML) as a ``linear`` model.

    Kalibr's forward model (:data:`KALIBR_CONVENTION`) gives jaxcal's forward matrices
    ``S_a = G0 M_a C_i_b`` (raw per g) and ``S_g = M_g C_gyro_i C_i_b`` (raw per rad/s). The bias and
    input units come from the ``jaxcal_*`` keys (absent: bias 0, raw input, with a note). Refused: a
    model other than ``scale-misalignment``, a ``T_i_b`` translation (a lever arm). A non-zero ``A``
    becomes the gyro g-sensitivity ``G = G0 S_g^{-1} A C_gyro_i C_i_b`` ((rad/s)/g), unless ``drop_g_sensitivity``.

    Args:
        doc: the parsed YAML.
        drop_g_sensitivity: import a non-zero ``A`` as zero (with a note).

    Raises:
        ModelError: what jaxcal's linear model cannot hold, or a malformed file (one line).
    """
    where = "Kalibr imu0"
    imu = imu0(doc, where)
    if imu.get("model") != "scale-misalignment":
        raise ModelError(f"{where}: model {imu.get('model')!r} is not 'scale-misalignment' (the Kalibr IMU model "
                         "jaxcal reads; 'calibrated' holds no intrinsics, 'scale-misalignment-size-effect' has "
                         "per-axis lever arms)")
    T = matrix(imu, "T_i_b", (4, 4), where)
    if np.any(T[:3, 3]):
        raise ModelError(f"{where}: T_i_b has a translation (lever arm {T[:3, 3].tolist()} m), which a jaxcal "
                         "linear model cannot hold")
    if np.any(T[3] != [0.0, 0.0, 0.0, 1.0]):
        raise ModelError(f"{where}: T_i_b's last row is {T[3].tolist()}, not [0, 0, 0, 1] (not a rigid transform)")
    C_i_b = rotation(T[:3, :3], "T_i_b's rotation", where)
    M_a = matrix(imu.get("accelerometers"), "M", (3, 3), f"{where} accelerometers")
    M_g = matrix(imu.get("gyroscopes"), "M", (3, 3), f"{where} gyroscopes")
    C_gyro_i = rotation(matrix(imu.get("gyroscopes"), "C_gyro_i", (3, 3), f"{where} gyroscopes"), "C_gyro_i", f"{where} gyroscopes")
    notes: list[str] = []
    A = matrix(imu.get("gyroscopes"), "A", (3, 3), f"{where} gyroscopes")
    keep = keep_gsens(A, "A", where, drop_g_sensitivity, notes)
    bias, units = yaml_bias_units(imu, where, notes)
    S_g = M_g @ C_gyro_i @ C_i_b
    fwd = to_model_unit({"acc": (G0 * (M_a @ C_i_b), bias["acc"]), "gyr": (S_g, bias["gyr"])}, imu, where)
    G = G0 * inv(S_g, "M_g C_gyro_i C_i_b", where) @ A @ C_gyro_i @ C_i_b if keep else None
    return Imported(imported_model(fwd, units, {"format": "kalibr", "notes": notes}, G), tuple(notes))


def document(d: Mapping[str, Any]) -> str:
    """The YAML text of :func:`to_kalibr`'s dict: the convention as a comment header (and the missing
    noise keys, if any, named), then the keys (:func:`jaxcal.formats.yaml_doc.document_text`).

    Args:
        d: :func:`to_kalibr`'s dict.
    """
    return document_text(KALIBR_CONVENTION, d, opencv=False)


def _export(model: CalibrationModel, options: ExportOptions) -> Exported:
    return yaml_export(ROS_TOOL, KALIBR_CONVENTION, _kalibr_dict, model, options, opencv=False)


FORMAT = Format("kalibr", "Kalibr scale-misalignment IMU intrinsics (YAML)", export=_export, suffix=".yaml",
                export_options=("noise", "units", "datasheet"), parse=parse_yaml, import_model=from_kalibr,
                ros_tool=ROS_TOOL)
