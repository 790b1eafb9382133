"""OpenVINS (rpng/open_vins): its IMU intrinsics in ``kalibr_imu_chain.yaml`` form, written and read back.

:func:`to_openvins` writes a linear model as OpenVINS reads it (:data:`OPENVINS_CONVENTION`, IMU model
``"kalibr"``: lower-triangular ``Tw``, ``Ta`` times rotations), the accelerometer in m/s^2 and the
gyroscope in rad/s, by default from the input a ROS driver publishes (``sensor_msgs/Imu``, m/s^2 and
rad/s: :mod:`jaxcal.formats.ros_input`), with ``units="model"`` from raw samples in the model's input
unit; the bias under ``jaxcal_b_a`` / ``jaxcal_b_g`` (OpenVINS holds no constant bias); a gyro g-sensitivity as ``Tg = S_g G / G0``. With the
noise keys of a Kalibr ``imu.yaml`` the file has every key of OpenVINS's own ``kalibr_imu_chain.yaml``
(:data:`OPENVINS_KEYS`). :func:`document` writes the file (``%YAML:1.0`` first, as OpenCV's reader
expects), :func:`from_openvins` reads it back as a ``linear`` model. Pure functions, no I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from jaxcal.constants import G0
from jaxcal.formats.base import Exported, ExportOptions, Format, Imported
from jaxcal.formats.linear_io import (
    gsens_forward,
    imported_model,
    inv,
    keep_gsens,
    lower_times_rotation,
    matrix,
    rotation,
    rows,
)
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

__all__ = ["FORMAT", "OPENVINS_CONVENTION", "OPENVINS_KEYS", "ROS_TOOL", "document", "from_openvins", "to_openvins"]

ROS_TOOL = RosTool("OpenVINS", "the constant bias (kalibr_imu_chain.yaml has no bias key; OpenVINS reads an initial "
                   "bias only as init_dyn_bias_a / init_dyn_bias_g in estimator_config.yaml, for its dynamic "
                   "initialisation: copy jaxcal_b_a / jaxcal_b_g there)",
                   "OpenVINS has no key for it either: it inflates its own initial covariance, init_dyn_inflation_bg / _ba")
"""OpenVINS, the tool that reads the export, and what its file lacks (:func:`~jaxcal.formats.ros_input.not_carried`)."""

OPENVINS_CONVENTION = """\
OpenVINS IMU intrinsics (kalibr_imu_chain.yaml, imu model "kalibr"). OpenVINS reads Tw, Ta, R_IMUtoGYRO,
R_IMUtoACC, Tg and sets Dw = inv(Tw), Da = inv(Ta), R_GYROtoIMU = R_IMUtoGYRO.T, R_ACCtoIMU = R_IMUtoACC.T
(ov_msckf VioManagerOptions.h); the corrected samples are (ov_msckf Propagator.cpp, docs.openvins.com
propagation_analytical):
  a_I = R_ACCtoIMU @ Da @ (a_m - b_a)                  [m/s^2]
  w_I = R_GYROtoIMU @ Dw @ (w_m - b_g - Tg @ a_I)      [rad/s]
Tg (input unit per m/s^2) = S_g @ G / 9.80665 for a jaxcal model y_g = S_g (w + G f) + b_g with g-sensitivity G
((rad/s)/g, f = a_I / 9.80665, S_g = Tw R_IMUtoGYRO); 0 when the model has none.
Tw, Ta: lower triangular (the "kalibr" model keeps the lower triangle of Dw, Da); I: jaxcal's calibrated
frame (T_i_b identity, time_offset 0). a_m, w_m: raw samples in the input unit
jaxcal_input_unit_acc/_gyr names; b_a, b_g: jaxcal_b_a, jaxcal_b_g in that unit (OpenVINS stores no constant
bias). Noise keys: Kalibr's imu.yaml values (SI, continuous time). Matrices are lists of rows."""
"""The convention header of :func:`to_openvins`'s file (also in its :func:`document`)."""

OPENVINS_KEYS = (
    "T_i_b",
    "accelerometer_noise_density",
    "accelerometer_random_walk",
    "gyroscope_noise_density",
    "gyroscope_random_walk",
    "rostopic",
    "time_offset",
    "update_rate",
    "model",
    "Tw",
    "R_IMUtoGYRO",
    "Ta",
    "R_IMUtoACC",
    "Tg",
)
"""The ``imu0`` keys of OpenVINS's own ``kalibr_imu_chain.yaml`` (rpng/open_vins
config/rpng_sim/kalibr_imu_chain.yaml), in its order; :func:`to_openvins` writes them all when
given the noise keys, then jaxcal's ``jaxcal_*`` keys."""


def to_openvins(model: CalibrationModel, imu_fields: Mapping[str, Any] | None = None, units: str = "ros",
                datasheet: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A linear model as OpenVINS's IMU intrinsics in its ``kalibr_imu_chain.yaml`` form (``{"imu0": {...}}``).

    Convention (:data:`OPENVINS_CONVENTION`): OpenVINS corrects ``a_I = R_IMUtoACC^T Ta^{-1} (a_m - b_a)``
    and ``w_I = R_IMUtoGYRO^T Tw^{-1} (w_m - b_g)`` (``Tg`` = 0), i.e. the forward matrices are
    ``S_a = Ta R_IMUtoACC`` and ``S_g = Tw R_IMUtoGYRO`` (input unit per m/s^2 or rad/s), split with
    :func:`lower_times_rotation`. ``Tw``, ``Ta`` are forward (OpenVINS inverts them into ``Dw``, ``Da``)
    and lower triangular, as OpenVINS's ``"kalibr"`` IMU model requires. The IMU frame ``I`` is jaxcal's
    calibrated frame: ``T_i_b`` is the identity, ``time_offset`` 0. With the noise keys of a Kalibr
    ``imu.yaml`` in ``imu_fields`` (:func:`noise_fields`) the file has every key of OpenVINS's own
    ``kalibr_imu_chain.yaml`` (:data:`OPENVINS_KEYS`, in that order), then jaxcal's ``jaxcal_*`` keys.

    Args:
        model: a linear model with ``acc`` and ``gyr``.
        imu_fields: further ``imu0`` entries (e.g. ``rostopic``, ``update_rate``, noise densities),
            added after jaxcal's; they may not replace them.
        units: ``"ros"``: ``a_m``, ``w_m`` are a ROS driver's m/s^2 and rad/s
            (:func:`~jaxcal.formats.yaml_doc.export_cals`); ``"model"``: the model's own input unit.
        datasheet: a raw model's ``acc_lsb_per_g`` / ``gyr_lsb_per_rads`` (``units="ros"``).

    Raises:
        ModelError: the model is not linear, lacks a sensor, or has a singular matrix.
        ValueError: ``imu_fields`` would replace a calibration key.
    """
    return _openvins_dict(model, imu_fields, units, datasheet)[0]


def _openvins_dict(model: CalibrationModel, imu_fields: Mapping[str, Any] | None, units: str,
                   datasheet: Mapping[str, Any] | None) -> tuple[dict[str, Any], RosInput | None]:
    """:func:`to_openvins`'s dict and the ROS conversion it used (``None`` with ``units="model"``)."""
    cals, ros = export_cals(model, units, datasheet)
    imu = {"T_i_b": rows(np.eye(4)), "time_offset": 0.0, "model": "kalibr", **_intrinsics(model, cals)}
    return imu_dict(model, imu, cals, ros, imu_fields, OPENVINS_KEYS, intrinsics_sd(model, ros, _intrinsics)), ros


def _intrinsics(model: CalibrationModel, cals: Mapping[str, LinearCal]) -> dict[str, Any]:
    """The calibration keys of :func:`to_openvins`'s file from the ``x = A (y - b)`` it writes."""
    Ta, R_IMUtoACC = lower_times_rotation(np.linalg.inv(cals["acc"].A))
    Tw, R_IMUtoGYRO = lower_times_rotation(np.linalg.inv(cals["gyr"].A))
    return {"Tw": rows(Tw), "R_IMUtoGYRO": rows(R_IMUtoGYRO), "Ta": rows(Ta), "R_IMUtoACC": rows(R_IMUtoACC),
            "Tg": rows(gsens_forward(model, np.linalg.inv(cals["gyr"].A)))}


def from_openvins(doc: Any, drop_g_sensitivity: bool = False) -> Imported:
    """OpenVINS's IMU intrinsics (:func:`to_openvins`'s ``kalibr_imu_chain.yaml``) as a ``linear`` model.

    As OpenVINS reads them (:data:`OPENVINS_CONVENTION`): ``Da = tril(Ta^{-1})``, ``Dw = tril(Tw^{-1})``
    and ``a_I = R_IMUtoACC^T Da (a_m - b_a)``, so jaxcal's forward matrices are
    ``S_a = G0 (R_IMUtoACC^T Da)^{-1}`` and ``S_g = (R_IMUtoGYRO^T Dw)^{-1}``. Bias and input units
    from the ``jaxcal_*`` keys (absent: bias 0, raw input, with a note). ``T_i_b`` is not read
    (OpenVINS does not apply it to the IMU). Refused: a model other than ``kalibr`` / ``calibrated``
    (OpenVINS's ``rpng`` model keeps other triangles), ``Tw`` or ``Ta`` not lower triangular. A non-zero
    ``Tg`` becomes the gyro g-sensitivity ``G = G0 S_g^{-1} Tg`` ((rad/s)/g), unless ``drop_g_sensitivity``.

    Args:
        doc: the parsed YAML.
        drop_g_sensitivity: import a non-zero ``Tg`` as zero (with a note).

    Raises:
        ModelError: what jaxcal's linear model cannot hold, or a malformed file (one line).
    """
    where = "OpenVINS imu0"
    imu = imu0(doc, where)
    if imu.get("model") not in ("kalibr", "calibrated"):
        raise ModelError(f"{where}: model {imu.get('model')!r} is not 'kalibr' or 'calibrated' (the OpenVINS IMU "
                         "models whose lower-triangular Tw, Ta jaxcal reads)")
    notes: list[str] = []
    mats = {}
    for key in ("Tw", "R_IMUtoGYRO", "Ta", "R_IMUtoACC", "Tg"):
        mats[key] = matrix(imu, key, (3, 3), where)
        if key.startswith("R_"):
            rotation(mats[key], key, where)
    for key in ("Tw", "Ta"):
        if np.any(np.triu(mats[key], 1)):
            raise ModelError(f"{where}: {key} is not lower triangular (OpenVINS's kalibr model keeps only the lower "
                             f"triangle of its inverse, so this file does not mean what it says)")
    keep = keep_gsens(mats["Tg"], "Tg", where, drop_g_sensitivity, notes)
    bias, units = yaml_bias_units(imu, where, notes)
    Da, Dw = np.tril(inv(mats["Ta"], "Ta", where)), np.tril(inv(mats["Tw"], "Tw", where))
    S_a = G0 * inv(mats["R_IMUtoACC"].T @ Da, "R_IMUtoACC^T Da", where)
    S_g = inv(mats["R_IMUtoGYRO"].T @ Dw, "R_IMUtoGYRO^T Dw", where)
    fwd = to_model_unit({"acc": (S_a, bias["acc"]), "gyr": (S_g, bias["gyr"])}, imu, where)
    G = G0 * inv(S_g, "R_IMUtoGYRO^T Dw", where) @ mats["Tg"] if keep else None
    return Imported(imported_model(fwd, units, {"format": "openvins", "notes": notes}, G), tuple(notes))


def document(d: Mapping[str, Any]) -> str:
    """The YAML text of :func:`to_openvins`'s dict: ``%YAML:1.0`` first (OpenVINS's OpenCV reader expects
    it; a YAML reader skips that line), the convention as a comment header (and the missing noise keys,
    if any, named), then the keys (:func:`jaxcal.formats.yaml_doc.document_text`).

    Args:
        d: :func:`to_openvins`'s dict.
    """
    return document_text(OPENVINS_CONVENTION, d, opencv=True)


def _export(model: CalibrationModel, options: ExportOptions) -> Exported:
    return yaml_export(ROS_TOOL, OPENVINS_CONVENTION, _openvins_dict, model, options, opencv=True)


FORMAT = Format("openvins", "OpenVINS kalibr_imu_chain.yaml IMU intrinsics (YAML)", export=_export, suffix=".yaml",
                export_options=("noise", "units", "datasheet"), parse=parse_yaml, import_model=from_openvins,
                ros_tool=ROS_TOOL)
