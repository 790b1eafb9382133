"""Exports of a linear calibration model that leave jaxcal, and imports that bring one back.

A linear model (a method whose ``apply`` is :func:`~jaxcal.methods.base.apply_linear_state`:
``linear``, ``multipos``, ``online``) holds per sensor an affine calibration, applied as::

    x = A @ (y - b)

``y``: one raw sample (3,) in the sensor's unit at fit time (``meta["units"]``, e.g. ``LSB``);
``b``: the bias (3,) in that same unit, subtracted first; ``A``: a 3x3 matrix multiplying the
column vector ``y - b`` from the left (it is the inverse ``S^{-1}`` of the forward model
``y = S x + b``); ``x``: the calibrated sample in ``g`` (accelerometer) or ``rad/s`` (gyroscope).
The plain JSON (:func:`to_json`) and the C header (:func:`to_c_header`) write ``A`` and ``b`` of
this applied form (:class:`~jaxcal.sensor.LinearCal`), never the forward ``S``, and say so in the
file. Numbers are written with Python's shortest round-trip ``repr``, so a reader parsing them as
IEEE doubles gets jaxcal's float64 values exactly.

Non-linear models (``nn``, ``cubic``, ``online-thesis``) are refused: a 3x3 matrix and a bias cannot
hold them.

Two YAML exports write the same calibration in the parameterisations of Kalibr
(:func:`to_kalibr`) and OpenVINS (:func:`to_openvins`); both need an IMU model (``acc`` and ``gyr``),
write the accelerometer in m/s^2 (``x`` in g times :data:`~jaxcal.constants.G0`) and the gyroscope in
rad/s, and keep the raw input ``y`` in the model's own input unit (the unit conversion and any
counts-to-physical scale are folded into their matrices; a model fitted on ``LSB`` expects raw counts
on the IMU topic). Neither format holds a constant bias (both estimate biases online as random
walks), so ``b`` is written under the extra keys ``jaxcal_b_a`` / ``jaxcal_b_g`` (input unit),
which both tools ignore; use them as the initial bias or subtract them upstream. The noise keys of
a Kalibr ``imu.yaml`` (:data:`NOISE_KEYS`, :func:`noise_fields`) go in as ``imu_fields``; without
them the file says, in a comment, which keys are missing.

imucal's ``FerrarisCalibrationInfo`` JSON (:func:`to_imucal`, :data:`IMUCAL_CONVENTION`) holds the
forward matrix as ``K @ R`` (diagonal scale times unit-row misalignment, :func:`scale_misalignment`)
in m/s^2 and deg/s; imucal's own ``CalibrationInfo.from_json_file`` reads it.

Imports (:func:`import_model` of a :func:`read_document`): imucal's CalibrationInfo JSON (written by
imucal or by jaxcal), jaxcal's plain JSON, and the Kalibr / OpenVINS YAML jaxcal writes, each as a
``linear`` model (forward ``S``, ``b`` per sensor, and the gyro g-sensitivity ``G`` when the file has a
non-zero one); what a linear model cannot hold (a lever arm, another IMU model) is refused with one line.

Gyro g-sensitivity: a linear model's gyroscope may hold ``G`` (3x3, (rad/s)/g, ``state/gyr/G``, e.g.
``jaxcal calibrate --method multipos --g-sensitivity``), applied as ``w = A_g (y_g - b_g) - G f`` with
``f = A_a (y_a - b_a)`` the calibrated accelerometer (g) of the same sample; its forward model is
``y_g = S_g (w + G f) + b_g``. Every export writes it in the format's own term: Kalibr's
``A = S_g G C_gyro_b^T / G0``, OpenVINS's ``Tg = S_g G / G0``, imucal's ``K_ga = S_g G / G0`` (input unit per
m/s^2), the JSON's ``G`` and the C function's ``acc_cal`` argument; each import reads it back.

Pure functions, no I/O: the ``jaxcal export`` and ``jaxcal import-model`` commands read and write the files.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax
import numpy as np
import yaml
from jaxtyping import Float

from jaxcal import methods
from jaxcal._version import __version__
from jaxcal.arrays import Array
from jaxcal.constants import G0, PHYS_UNIT
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.methods.base import GSENS_KEY, MAX_CONDITION, affine_state, apply_linear_state, check_linear_state, gsens_of
from jaxcal.safe_yaml import YamlLimitError, load_yaml
from jaxcal.sensor import LinearCal

__all__ = [
    "EQUATION",
    "EQUATION_GSENS",
    "IMPORT_FORMATS",
    "IMUCAL_CONVENTION",
    "IMUCAL_FORMAT_VERSION",
    "JSON_FORMAT",
    "KALIBR_CONVENTION",
    "KALIBR_KEYS",
    "NOISE_KEYS",
    "OPENVINS_CONVENTION",
    "OPENVINS_KEYS",
    "Imported",
    "from_imucal",
    "from_json_export",
    "from_kalibr",
    "from_openvins",
    "g_sensitivity",
    "import_model",
    "is_linear",
    "linear_cals",
    "linear_methods",
    "lower_times_rotation",
    "missing_noise_keys",
    "noise_fields",
    "physical_cals",
    "read_document",
    "scale_misalignment",
    "to_c_header",
    "to_imucal",
    "to_json",
    "to_kalibr",
    "to_openvins",
    "yaml_document",
]

EQUATION = "x = A @ (y - b)"
"""The applied form both exports write out (``A`` multiplies the column vector ``y - b``)."""

EQUATION_GSENS = "x_gyr = A_gyr @ (y_gyr - b_gyr) - G @ x_acc"
"""The gyroscope's applied form when the model has a g-sensitivity ``G`` ((rad/s)/g; ``x_acc`` in g)."""

JSON_FORMAT = "jaxcal-linear-calibration/1"
"""The ``format`` field of :func:`to_json`'s output (name/version of this JSON layout)."""

_C_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def linear_methods() -> tuple[str, ...]:
    """The registered methods whose models are linear (their ``apply`` is ``apply_linear_state``)."""
    return tuple(n for n, m in methods.REGISTRY.items() if m.apply is apply_linear_state)


def is_linear(model: CalibrationModel) -> bool:
    """Whether ``model``'s method stores a linear (affine) calibration per sensor."""
    return model.method in linear_methods()


def linear_cals(model: CalibrationModel) -> dict[str, LinearCal]:
    """``sensor -> LinearCal`` (numpy float64 ``A``, ``b``) of a linear model, in ``model.sensors`` order.

    ``A = S^{-1}`` is computed exactly as ``jaxcal apply`` computes it
    (:meth:`~jaxcal.sensor.LinearCal.from_forward` of :func:`~jaxcal.methods.base.affine_state`, float64).

    Args:
        model: a fitted or loaded :class:`~jaxcal.methods.CalibrationModel`.

    Raises:
        ModelError: the model is not linear (one line naming the methods that are).
    """
    if not is_linear(model):
        raise ModelError(
            f"model of method '{model.method}' is not linear: the json and c exports hold one affine "
            f"calibration {EQUATION} per sensor, which only the methods {', '.join(linear_methods())} fit"
        )
    out = {}
    with jax.enable_x64(True):
        for s in model.sensors:
            cal = LinearCal.from_forward(affine_state(model.state[s]))
            out[s] = LinearCal(np.asarray(cal.A, np.float64), np.asarray(cal.b, np.float64))
    return out


def g_sensitivity(model: CalibrationModel) -> np.ndarray | None:
    """The gyroscope g-sensitivity ``G`` (3, 3), (rad/s)/g, of a linear model, or ``None`` when it has none.

    Args:
        model: a fitted or loaded :class:`~jaxcal.methods.CalibrationModel`.
    """
    return gsens_of(model.state) if is_linear(model) else None


def _json_safe(v: Any) -> bool:
    """Whether ``v`` is plain, finite JSON (no NaN/inf, no numpy objects)."""
    try:
        json.dumps(v, allow_nan=False)
    except (TypeError, ValueError):
        return False
    return True


def _units(model: CalibrationModel, sensor: str) -> tuple[str | None, str]:
    """(input unit at fit time or ``None`` if the model does not say, output unit)."""
    units = model.meta.get("units", {})
    unit = units.get(sensor) if isinstance(units, Mapping) else None
    return (unit if isinstance(unit, str) else None), PHYS_UNIT[sensor]


def to_json(model: CalibrationModel) -> dict[str, Any]:
    """A plain-JSON description of a linear model (``json.dumps`` it as is).

    Layout: ``format`` (:data:`JSON_FORMAT`), ``equation`` (:data:`EQUATION`), ``convention`` (the
    equation in words), with a gyro g-sensitivity also ``equation_gyr`` (:data:`EQUATION_GSENS`),
    ``convention_gyr`` and ``sensors.gyr.G`` (3x3 rows, ``G_unit`` ``(rad/s)/g``), ``method``, ``jaxcal_version``, ``sensors``: ``{sensor: {"A": 3x3 row-major
    (a list of 3 rows), "b": [3], "input_unit", "output_unit"}}``, and ``meta``: the model's
    metadata entries that are plain finite JSON (others are dropped).

    Args:
        model: a linear model (see :func:`linear_cals`).

    Raises:
        ModelError: the model is not linear.
    """
    cals = linear_cals(model)
    G = g_sensitivity(model)
    sensors = {}
    for s, cal in cals.items():
        unit_in, unit_out = _units(model, s)
        sensors[s] = {
            "A": [[float(v) for v in row] for row in cal.A],
            "b": [float(v) for v in cal.b],
            "input_unit": unit_in,
            "output_unit": unit_out,
        }
    gs = {}
    if G is not None:
        sensors["gyr"]["G"] = _rows(G)
        sensors["gyr"]["G_unit"] = "(rad/s)/g"
        gs = {"equation_gyr": EQUATION_GSENS,
              "convention_gyr": "the gyroscope has a g-sensitivity G (3x3, rows listed first, (rad/s)/g): its "
              "calibrated sample is A (y - b) - G x_acc, x_acc the calibrated accelerometer sample (g) of the same "
              "instant (forward model y = S (x + G x_acc) + b)."}
    return {
        "format": JSON_FORMAT,
        "equation": EQUATION,
        "convention": "per sensor: y is one raw sample (3-vector) in input_unit; b (input_unit) is subtracted "
        "first; A (3x3, rows listed first: A[i][j] is row i, column j) multiplies the column vector y - b from "
        "the left; x is the calibrated sample in output_unit. A is the inverse of the forward model's S in "
        "y = S x + b.",
        **gs,
        "method": model.method,
        "jaxcal_version": __version__,
        "sensors": sensors,
        "meta": {k: v for k, v in model.meta.items() if _json_safe(v)},
    }


def _c_double(v: float) -> str:
    """A C double literal that parses back to exactly ``v`` (shortest round-trip repr)."""
    if not math.isfinite(v):
        raise ModelError(f"non-finite calibration value {v!r} cannot be exported")
    return repr(float(v))


def _c_comment(text: str) -> str:
    """``text`` made safe inside a C block comment."""
    return text.replace("*/", "* /")


def to_c_header(model: CalibrationModel, name: str = "jaxcal_cal") -> str:
    """A dependency-free C99 header applying a linear model in firmware.

    Per sensor ``s``: ``static const double <name>_<s>_A[3][3]`` and ``<name>_<s>_b[3]``, and
    ``static inline void <name>_apply_<s>(const double y[3], double x[3])`` computing
    ``x = A (y - b)`` (``y`` and ``x`` may be the same array). A comment block states the convention
    and the units.

    Args:
        model: a linear model (see :func:`linear_cals`).
        name: prefix of every identifier and of the include guard; a C identifier.

    Raises:
        ModelError: the model is not linear.
        ValueError: ``name`` is not a C identifier.
    """
    if not _C_NAME.match(name):
        raise ValueError(f"C name {name!r} is not an identifier (letters, digits, '_'; not starting with a digit)")
    cals = linear_cals(model)
    G = g_sensitivity(model)
    guard = f"{name.upper()}_H"
    lines = [
        f"/* {name}.h: IMU calibration exported by jaxcal {_c_comment(__version__)} "
        f"(method '{_c_comment(model.method)}').",
        " *",
        f" * Convention, per sensor:  {EQUATION}",
        " *   y: one raw sample (3 values) in the sensor's input unit;",
        " *   b: bias in the same unit, subtracted first;",
        " *   A: 3x3 matrix, A[i][j] = row i, column j, multiplying the column vector (y - b) from the left",
        " *      (A is the inverse of the forward model's S in y = S x + b);",
        " *   x: calibrated sample in the output unit.",
        " * Values are IEEE-754 doubles written to round-trip exactly. C99, no dependencies.",
    ]
    for s in cals:
        unit_in, unit_out = _units(model, s)
        call = f"{name}_apply_{s}(y, acc_cal, x)" if (s == "gyr" and G is not None) else f"{name}_apply_{s}(y, x)"
        lines.append(f" *   {s}: input {_c_comment(unit_in or 'unit not recorded')}, output {unit_out}; {call}")
    if G is not None:
        lines += [" *",
                  f" * The gyroscope has a g-sensitivity G ((rad/s)/g):  {EQUATION_GSENS}",
                  f" *   x_acc: the calibrated accelerometer sample (g) of the same instant ({name}_apply_acc's output),",
                  f" *   passed as acc_cal; G = {name}_gyr_G[3][3], rows first."]
    lines += [" */", f"#ifndef {guard}", f"#define {guard}", ""]
    for s, cal in cals.items():
        rows = ",\n".join("    {" + ", ".join(_c_double(v) for v in row) + "}" for row in cal.A)
        lines += [
            f"static const double {name}_{s}_A[3][3] = {{\n{rows}\n}};",
            f"static const double {name}_{s}_b[3] = {{{', '.join(_c_double(v) for v in cal.b)}}};",
            "",
        ]
        if s == "gyr" and G is not None:
            grows = ",\n".join("    {" + ", ".join(_c_double(v) for v in row) + "}" for row in G)
            lines += [
                f"static const double {name}_gyr_G[3][3] = {{\n{grows}\n}};",
                "",
                "/* x = A (y - b) - G acc_cal for the gyr sensor (acc_cal: calibrated accelerometer, g); any of",
                " * y, acc_cal, x may be the same array. */",
                f"static inline void {name}_apply_gyr(const double y[3], const double acc_cal[3], double x[3])",
                "{",
                f"    const double d0 = y[0] - {name}_gyr_b[0];",
                f"    const double d1 = y[1] - {name}_gyr_b[1];",
                f"    const double d2 = y[2] - {name}_gyr_b[2];",
                "    const double f0 = acc_cal[0], f1 = acc_cal[1], f2 = acc_cal[2];",
                "    int i;",
                "    for (i = 0; i < 3; ++i) {",
                f"        x[i] = ({name}_gyr_A[i][0] * d0 + {name}_gyr_A[i][1] * d1 + {name}_gyr_A[i][2] * d2)",
                f"             - ({name}_gyr_G[i][0] * f0 + {name}_gyr_G[i][1] * f1 + {name}_gyr_G[i][2] * f2);",
                "    }",
                "}",
                "",
            ]
            continue
        lines += [
            f"/* x = A (y - b) for the {s} sensor; y and x may be the same array. */",
            f"static inline void {name}_apply_{s}(const double y[3], double x[3])",
            "{",
            f"    const double d0 = y[0] - {name}_{s}_b[0];",
            f"    const double d1 = y[1] - {name}_{s}_b[1];",
            f"    const double d2 = y[2] - {name}_{s}_b[2];",
            "    int i;",
            "    for (i = 0; i < 3; ++i) {",
            f"        x[i] = {name}_{s}_A[i][0] * d0 + {name}_{s}_A[i][1] * d1 + {name}_{s}_A[i][2] * d2;",
            "    }",
            "}",
            "",
        ]
    lines += [f"#endif /* {guard} */", ""]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- Kalibr and OpenVINS (YAML)

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
model's input unit (jaxcal_input_unit_acc/_gyr); b_a, b_g: jaxcal_b_a, jaxcal_b_g in that unit (Kalibr stores no
constant bias). Noise keys: Kalibr's imu.yaml values (SI, continuous time). Matrices are lists of rows."""
"""The convention header of :func:`to_kalibr`'s file (also in its ``yaml_document``)."""

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
frame (T_i_b identity, time_offset 0). a_m, w_m: raw samples in the model's input unit
(jaxcal_input_unit_acc/_gyr); b_a, b_g: jaxcal_b_a, jaxcal_b_g in that unit (OpenVINS stores no constant
bias). Noise keys: Kalibr's imu.yaml values (SI, continuous time). Matrices are lists of rows."""
"""The convention header of :func:`to_openvins`'s file (also in its ``yaml_document``)."""

_IMU_SENSORS = ("acc", "gyr")
_KALIBR_UNIT = {"acc": "m/s^2", "gyr": "rad/s"}


def lower_times_rotation(X: Float[Array, "3 3"]) -> tuple[np.ndarray, np.ndarray]:
    """``X = T @ C`` with ``T`` lower triangular and ``C`` a rotation (orthonormal, det +1).

    From the QR decomposition of ``X.T = Q R``: ``X = R.T @ Q.T``, ``T = R.T``, ``C = Q.T``. Signs are
    chosen so that ``T``'s diagonal is positive; when ``det X < 0`` a rotation cannot absorb the
    reflection and ``T[2, 2]`` is negative instead.

    Args:
        X: an invertible 3x3 matrix.

    Raises:
        ModelError: ``X`` is singular or not finite.
    """
    X = np.asarray(X, np.float64)
    if X.shape != (3, 3) or not np.all(np.isfinite(X)) or abs(np.linalg.det(X)) < 1e-300:
        raise ModelError("a singular or non-finite calibration matrix cannot be written as triangular x rotation")
    Q, R = np.linalg.qr(X.T)
    d = np.where(np.diag(R) < 0, -1.0, 1.0)
    Q, R = Q * d, d[:, None] * R  # Q D, D R: same product, R's diagonal positive
    if np.linalg.det(Q) < 0:
        Q[:, 2], R[2, :] = -Q[:, 2], -R[2, :]
    T, C = np.tril(R.T), Q.T  # R is upper triangular; tril drops QR's exact zeros only
    return T, C


def physical_cals(model: CalibrationModel) -> dict[str, LinearCal]:
    """``acc``, ``gyr`` -> ``LinearCal`` with ``x = A (y - b)`` in m/s^2 and rad/s (Kalibr's, OpenVINS's units).

    ``y`` and ``b`` stay in the model's input unit; the accelerometer's ``A`` is jaxcal's times
    :data:`~jaxcal.constants.G0` (g -> m/s^2).

    Args:
        model: a linear model with both sensors.

    Raises:
        ModelError: the model is not linear or lacks ``acc`` or ``gyr``.
    """
    cals = linear_cals(model)
    missing = [s for s in _IMU_SENSORS if s not in cals]
    if missing:
        raise ModelError(f"the kalibr and openvins exports describe a 6-axis IMU, but the model has no "
                         f"{' or '.join(missing)} calibration (sensors: {', '.join(model.sensors)})")
    scale = {"acc": G0, "gyr": 1.0}
    return {s: LinearCal(cals[s].A * scale[s], cals[s].b) for s in _IMU_SENSORS}


def _rows(M: np.ndarray) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.asarray(M, np.float64)]


def _jaxcal_fields(model: CalibrationModel, cals: Mapping[str, LinearCal]) -> dict[str, Any]:
    units = {s: _units(model, s)[0] or "unit not recorded" for s in _IMU_SENSORS}
    return {
        "jaxcal_b_a": [float(v) for v in cals["acc"].b],
        "jaxcal_b_g": [float(v) for v in cals["gyr"].b],
        "jaxcal_input_unit_acc": units["acc"],
        "jaxcal_input_unit_gyr": units["gyr"],
        "jaxcal_method": model.method,
        "jaxcal_version": __version__,
    }


def to_kalibr(model: CalibrationModel, imu_fields: Mapping[str, Any] | None = None) -> dict[str, Any]:
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

    Raises:
        ModelError: the model is not linear, lacks a sensor, or has a singular matrix.
        ValueError: ``imu_fields`` would replace a calibration key.
    """
    cals = physical_cals(model)
    S_a, S_g = np.linalg.inv(cals["acc"].A), np.linalg.inv(cals["gyr"].A)
    M_a, C_i_b = lower_times_rotation(S_a)
    M_g, C_gyro_i = lower_times_rotation(S_g @ C_i_b.T)
    T_i_b = np.eye(4)
    T_i_b[:3, :3] = C_i_b
    imu = {
        "model": "scale-misalignment",
        "T_i_b": _rows(T_i_b),
        "accelerometers": {"M": _rows(M_a)},
        "gyroscopes": {"M": _rows(M_g), "A": _rows(_kalibr_A(model, S_g, C_gyro_i @ C_i_b)), "C_gyro_i": _rows(C_gyro_i)},
        **_jaxcal_fields(model, cals),
    }
    return {"imu0": _ordered(_merge(imu, imu_fields), KALIBR_KEYS)}


def _kalibr_A(model: CalibrationModel, S_g: np.ndarray, C_gyro_b: np.ndarray) -> np.ndarray:
    """Kalibr's gyro g-sensitivity ``A = S_g G C_gyro_b^T / G0`` (input unit per m/s^2; zero without ``G``)."""
    G = g_sensitivity(model)
    return np.zeros((3, 3)) if G is None else S_g @ G @ C_gyro_b.T / G0


def _tg(model: CalibrationModel, S_g: np.ndarray) -> np.ndarray:
    """OpenVINS's ``Tg`` / imucal's ``K_ga``: ``S_g G / G0`` (input unit per m/s^2; zero without ``G``)."""
    G = g_sensitivity(model)
    return np.zeros((3, 3)) if G is None else S_g @ G / G0


def to_openvins(model: CalibrationModel, imu_fields: Mapping[str, Any] | None = None) -> dict[str, Any]:
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

    Raises:
        ModelError: the model is not linear, lacks a sensor, or has a singular matrix.
        ValueError: ``imu_fields`` would replace a calibration key.
    """
    cals = physical_cals(model)
    Ta, R_IMUtoACC = lower_times_rotation(np.linalg.inv(cals["acc"].A))
    Tw, R_IMUtoGYRO = lower_times_rotation(np.linalg.inv(cals["gyr"].A))
    imu = {
        "T_i_b": _rows(np.eye(4)),
        "time_offset": 0.0,
        "model": "kalibr",
        "Tw": _rows(Tw),
        "R_IMUtoGYRO": _rows(R_IMUtoGYRO),
        "Ta": _rows(Ta),
        "R_IMUtoACC": _rows(R_IMUtoACC),
        "Tg": _rows(_tg(model, np.linalg.inv(cals["gyr"].A))),
        **_jaxcal_fields(model, cals),
    }
    return {"imu0": _ordered(_merge(imu, imu_fields), OPENVINS_KEYS)}


def _merge(imu: dict[str, Any], extra: Mapping[str, Any] | None) -> dict[str, Any]:
    clash = sorted(set(extra or {}) & set(imu))
    if clash:
        raise ValueError(f"imu_fields may not replace the calibration keys {', '.join(clash)}")
    return {**imu, **(extra or {})}


class _IndentedDumper(yaml.SafeDumper):
    """PyYAML's safe dumper with block sequences indented under their key (``key:\n  - [..]``).

    PyYAML writes ``key:\n- [..]`` by default, which YAML allows but OpenCV's ``cv::FileStorage``
    (OpenVINS's configuration reader) refuses ("Incorrect indentation").
    """

    def increase_indent(self, flow: bool = False, indentless: bool = False) -> None:  # noqa: D102 - PyYAML API
        return super().increase_indent(flow, False)


def _represent_str(dumper: yaml.SafeDumper, value: str) -> yaml.ScalarNode:
    """Quote strings that start like a number (``0.1.0``): OpenCV's reader parses them as numbers and fails."""
    style = '"' if value[:1].isdigit() or value[:1] in "+-." else None
    return dumper.represent_scalar("tag:yaml.org,2002:str", value, style=style)


_IndentedDumper.add_representer(str, _represent_str)


def yaml_document(fmt: str, d: Mapping[str, Any]) -> str:
    """The YAML text of :func:`to_kalibr`'s (``fmt="kalibr"``) or :func:`to_openvins`'s (``"openvins"``) dict.

    A ``#`` comment header states the convention; the OpenVINS file starts with ``%YAML:1.0`` as
    OpenVINS's own configuration files do (its OpenCV reader expects it; a YAML reader skips that
    first line), and sequences are indented under their keys as OpenCV's reader requires. When
    ``d["imu0"]`` lacks any of the noise keys (:data:`NOISE_KEYS`), a comment line names them. Floats are written with their shortest round-trip ``repr``.

    Args:
        fmt: ``"kalibr"`` or ``"openvins"``.
        d: the export's dict.

    Raises:
        ValueError: unknown ``fmt``.
    """
    conventions = {"kalibr": KALIBR_CONVENTION, "openvins": OPENVINS_CONVENTION}
    if fmt not in conventions:
        raise ValueError(f"unknown YAML export format {fmt!r} (kalibr, openvins)")
    head = [f"# IMU calibration exported by jaxcal {__version__}.", "#"]
    head += [f"# {line}".rstrip() for line in conventions[fmt].splitlines()]
    missing = missing_noise_keys(d)
    if missing:
        head += ["#", f"# Missing IMU noise keys (Kalibr imu.yaml, SI units): {', '.join(missing)}.",
                 "# Add them before the tool reads this file, e.g. `jaxcal export ... --noise imu.yaml` (from `jaxcal noise`)."]
    body = yaml.dump(dict(d), Dumper=_IndentedDumper, sort_keys=False, default_flow_style=None, width=200)
    first = ["%YAML:1.0"] if fmt == "openvins" else []
    return "\n".join(first + head) + "\n" + body


def _ordered(d: Mapping[str, Any], order: tuple[str, ...]) -> dict[str, Any]:
    """``d`` with the keys of ``order`` first, in that order, then the others as they come."""
    return {**{k: d[k] for k in order if k in d}, **{k: v for k, v in d.items() if k not in order}}


# ----------------------------------------------------------------------------- noise keys (Kalibr imu.yaml)

NOISE_KEYS = (
    "accelerometer_noise_density",
    "accelerometer_random_walk",
    "gyroscope_noise_density",
    "gyroscope_random_walk",
    "rostopic",
    "update_rate",
)
"""The keys of Kalibr's ``imu.yaml`` (IMU noise model, SI units, continuous time), which
:func:`noise_fields` reads and both YAML exports carry when given."""

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

KALIBR_KEYS = ("T_i_b", *NOISE_KEYS, "model", "accelerometers", "gyroscopes")
"""The order of the ``imu0`` keys of :func:`to_kalibr`'s file (then jaxcal's ``jaxcal_*`` keys)."""


def noise_fields(doc: Mapping[str, Any]) -> dict[str, Any]:
    """The noise keys (:data:`NOISE_KEYS`) of a Kalibr ``imu.yaml``, checked, for a YAML export's ``imu_fields``.

    ``doc`` is the parsed file: Kalibr's flat ``imu.yaml`` (the keys at top level, as
    ``jaxcal noise`` and Kalibr's wiki write it) or a chain file with them under ``imu0`` (OpenVINS's
    ``kalibr_imu_chain.yaml``). The four densities (``>= 0``, SI units: m/s^2/sqrt(Hz),
    m/s^3/sqrt(Hz), rad/s/sqrt(Hz), rad/s^2/sqrt(Hz)) and ``update_rate`` (Hz, ``> 0``) are required,
    ``rostopic`` (a non-empty string) is taken when present. Other keys are ignored.

    Args:
        doc: the parsed YAML document.

    Raises:
        ValueError: not a mapping, a key missing, or a value of the wrong kind (one line).
    """
    if not isinstance(doc, Mapping):
        raise ValueError(f"expected a YAML mapping of Kalibr imu.yaml keys, got {type(doc).__name__}")
    if isinstance(doc.get("imu0"), Mapping):
        doc = doc["imu0"]
    numbers = [k for k in NOISE_KEYS if k != "rostopic"]
    missing = [k for k in numbers if k not in doc]
    if missing:
        raise ValueError(f"no {', '.join(missing)} (the Kalibr imu.yaml noise keys)")
    out: dict[str, Any] = {}
    for k in numbers:
        v = doc[k]
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        if not ok or v < 0 or (k == "update_rate" and v == 0):
            want = "a rate > 0 in Hz" if k == "update_rate" else "a finite number >= 0"
            raise ValueError(f"{k} must be {want}, got {v!r}")
        out[k] = float(v)
    if "rostopic" in doc:
        if not isinstance(doc["rostopic"], str) or not doc["rostopic"]:
            raise ValueError(f"rostopic must be a topic name, got {doc['rostopic']!r}")
        out["rostopic"] = doc["rostopic"]
    return {k: out[k] for k in NOISE_KEYS if k in out}


def missing_noise_keys(d: Mapping[str, Any]) -> list[str]:
    """The :data:`NOISE_KEYS` that a YAML export's dict (``{"imu0": {...}}``) lacks."""
    imu = d.get("imu0", {})
    return [k for k in NOISE_KEYS if k not in imu]


# ----------------------------------------------------------------------------- imucal CalibrationInfo (JSON)

IMUCAL_FORMAT_VERSION = "2.0.0"
"""imucal's ``_format_version`` of the CalibrationInfo JSON this module writes and reads (imucal 2.x)."""

IMUCAL_CONVENTION = (
    "imucal FerrarisCalibrationInfo (imucal/ferraris_calibration_info.py, calibrate): "
    "acc = inv(R_a) @ inv(K_a) @ (acc_raw - b_a) in acc_unit; "
    "gyr = inv(R_g) @ inv(K_g) @ (gyr_raw - K_ga @ acc - b_g) in gyr_unit; "
    "acc_raw, gyr_raw, b_a, b_g in from_acc_unit, from_gyr_unit. Matrices are lists of rows. "
    "K_a @ R_a and K_g @ R_g are the forward matrices S of raw = S x + b (raw per output unit); "
    "K = diag(row norms of S) is the scale, R = inv(K) @ S the misalignment, rows of unit norm, as imucal's "
    "Ferraris fit normalises them. K_ga (from_gyr_unit per m/s^2; acc the calibrated acc in m/s^2) = "
    "S_g @ G / 9.80665 for a jaxcal gyro y_g = S_g (w + G f) + b_g (S_g raw per rad/s, g-sensitivity G in (rad/s)/g, "
    "f = acc / 9.80665); 0 when the model has none."
)
"""The convention written into the ``comment`` field of :func:`to_imucal`'s JSON (imucal's
``from_json`` accepts no extra keys, so the convention lives in its one free-text field)."""

_IMUCAL_ACC_UNIT, _IMUCAL_GYR_UNIT = "m/s^2", "deg/s"
_PER_JAXCAL_UNIT = {"acc": {"g": 1.0, "m/s^2": G0}, "gyr": {"rad/s": 1.0, "deg/s": 180.0 / math.pi}}
"""Physical units each tool may use, as their value per jaxcal's ``g`` / ``rad/s``."""


def _forward(model: CalibrationModel, sensor: str) -> tuple[np.ndarray, np.ndarray]:
    """The stored forward model ``y = S x + b`` of a linear model's sensor (float64 numpy)."""
    p = model.state[sensor]
    return np.asarray(p["S"], np.float64), np.asarray(p["b"], np.float64)


def scale_misalignment(S: Float[Array, "3 3"]) -> tuple[np.ndarray, np.ndarray]:
    """``S = K @ R``: ``K = diag(row norms of S)`` (positive), ``R = inv(K) @ S`` (rows of unit norm).

    imucal's factorisation (its Ferraris fit, eq. 12 and 22-23 of Ferraris et al.): defined for every
    ``S`` without a zero row, exact up to one rounding per entry of ``R``.

    Args:
        S: a 3x3 forward matrix.

    Raises:
        ModelError: ``S`` has a zero or non-finite row.
    """
    S = np.asarray(S, np.float64)
    k = np.sqrt(np.sum(S * S, axis=1))
    if not (np.all(np.isfinite(k)) and np.all(k > 0)):
        raise ModelError("a calibration matrix with a zero or non-finite row has no scale x misalignment form")
    return np.diag(k), S / k[:, None]


def to_imucal(model: CalibrationModel) -> dict[str, Any]:
    """A linear model as imucal's ``FerrarisCalibrationInfo`` JSON (``json.dumps`` it as is).

    imucal (:data:`IMUCAL_CONVENTION`) calibrates ``acc = R_a^{-1} K_a^{-1} (acc_raw - b_a)`` and
    ``gyr = R_g^{-1} K_g^{-1} (gyr_raw - K_ga acc - b_g)``, i.e. ``K R`` is the forward matrix. jaxcal's
    stored forward ``S`` (raw per g, raw per rad/s) is converted to raw per imucal's default output
    units (``acc_unit`` m/s^2, ``gyr_unit`` deg/s) and factored with :func:`scale_misalignment`;
    ``K_ga`` is zero; ``b`` and the raw input are in the model's input unit (``from_acc_unit`` /
    ``from_gyr_unit``: e.g. ``LSB``; ``None`` when the model does not record it). The keys are
    exactly those of imucal's ``CalibrationInfo.to_json`` (``cal_type`` ``"Ferraris"``,
    ``_format_version`` :data:`IMUCAL_FORMAT_VERSION`); the convention goes in ``comment``.

    Args:
        model: a linear model with ``acc`` and ``gyr`` (imucal's calibration holds both).

    Raises:
        ModelError: the model is not linear, lacks a sensor, or has a zero row.
    """
    linear_cals(model)  # refuses non-linear models
    missing = [s for s in _IMU_SENSORS if s not in model.sensors]
    if missing:
        raise ModelError(f"imucal's CalibrationInfo holds an accelerometer and a gyroscope, but the model has no "
                         f"{' or '.join(missing)} calibration (sensors: {', '.join(model.sensors)})")
    out_unit = {"acc": _IMUCAL_ACC_UNIT, "gyr": _IMUCAL_GYR_UNIT}
    paras: dict[str, Any] = {}
    for s, tag in (("acc", "a"), ("gyr", "g")):
        S, b = _forward(model, s)
        K, R = scale_misalignment(S / _PER_JAXCAL_UNIT[s][out_unit[s]])
        paras[s] = {f"K_{tag}": _rows(K), f"R_{tag}": _rows(R), f"b_{tag}": [float(v) for v in b]}
    return {
        "acc_unit": out_unit["acc"],
        "gyr_unit": out_unit["gyr"],
        "from_acc_unit": _units(model, "acc")[0],
        "from_gyr_unit": _units(model, "gyr")[0],
        "comment": f"{IMUCAL_CONVENTION} Exported by jaxcal {__version__} from a '{model.method}' model.",
        **paras["acc"],
        "K_g": paras["gyr"]["K_g"],
        "R_g": paras["gyr"]["R_g"],
        "K_ga": _rows(_tg(model, _forward(model, "gyr")[0])),
        "b_g": paras["gyr"]["b_g"],
        "cal_type": "Ferraris",
        "_format_version": IMUCAL_FORMAT_VERSION,
    }


# ----------------------------------------------------------------------------- imports

IMPORT_FORMATS = ("imucal", "json", "kalibr", "openvins")
"""The formats :func:`import_model` reads."""


class Imported(NamedTuple):
    """What :func:`import_model` returns.

    Args:
        model: a ``linear`` :class:`~jaxcal.methods.CalibrationModel` (forward ``S``, ``b`` per sensor,
            and the gyro g-sensitivity ``G`` when the file has one).
        notes: one-line remarks on what the import assumed or dropped (e.g. a bias the file lacks).
    """

    model: CalibrationModel
    notes: tuple[str, ...]


def read_document(fmt: str, text: str) -> Any:
    """The parsed document of an import file's text: JSON (imucal, json) or YAML (kalibr, openvins).

    An OpenCV ``%YAML:1.0`` first line (OpenVINS's files) is skipped.

    Args:
        fmt: one of :data:`IMPORT_FORMATS`.
        text: the file's text.

    Raises:
        ModelError: unknown format or text that does not parse (one line).
    """
    if fmt not in IMPORT_FORMATS:
        raise ModelError(f"unknown import format {fmt!r} ({', '.join(IMPORT_FORMATS)})")
    try:
        if fmt in ("imucal", "json"):
            return json.loads(text)
        if text.startswith("%YAML:"):
            text = text.split("\n", 1)[1] if "\n" in text else ""
        return load_yaml(text)
    except YamlLimitError as e:
        raise ModelError(f"YAML refused: {e}") from None
    except (ValueError, yaml.YAMLError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ModelError(f"not valid {'JSON' if fmt in ('imucal', 'json') else 'YAML'} ({first})") from None


def _matrix(d: Any, key: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """``d[key]`` as a finite float64 array of ``shape`` (one-line :class:`ModelError` otherwise)."""
    if not isinstance(d, Mapping) or key not in d or d[key] is None:
        raise ModelError(f"{where}: no {key}")
    v = d[key]
    if isinstance(v, (list, tuple)) and not _list_shape(v, shape):  # before any allocation
        got = _outer_shape(v)
        if got != shape:
            raise ModelError(f"{where}: {key} has shape {got}, expected {shape}")
        raise ModelError(f"{where}: {key} is not a {'x'.join(map(str, shape))} array of numbers (ragged rows)")
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise ModelError(f"{where}: {key} is not a {'x'.join(map(str, shape))} array of numbers") from None
    if a.shape != shape:
        raise ModelError(f"{where}: {key} has shape {a.shape}, expected {shape}")
    if not np.all(np.isfinite(a)):
        raise ModelError(f"{where}: {key} has a non-finite value")
    return a


ROTATION_TOL = 1e-6  # |R R^T - I| and |det R - 1| of a matrix a format defines as a rotation


def _rotation(R: np.ndarray, key: str, where: str) -> np.ndarray:
    """``R`` if it is a rotation (orthonormal, determinant +1, within :data:`ROTATION_TOL`); a one-line
    :class:`ModelError` otherwise (a scaled one would change the sensor's scale, a reflection would
    make a left-handed frame)."""
    err = float(np.max(np.abs(R @ R.T - np.eye(3))))
    det = float(np.linalg.det(R))
    if err > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
        what = ("a reflection (determinant -1: a left-handed frame)" if det < 0 else
                f"not orthonormal (|R R^T - I| = {err:.3g}, determinant {det:.6g})")
        raise ModelError(f"{where}: {key} must be a rotation, but it is {what}")
    return R


def _list_shape(v: Any, shape: tuple[int, ...]) -> bool:
    """Whether nested lists ``v`` have exactly ``shape`` (checked before any array is built)."""
    if not shape:
        return not isinstance(v, (list, tuple, Mapping))
    return isinstance(v, (list, tuple)) and len(v) == shape[0] and all(_list_shape(x, shape[1:]) for x in v)


def _outer_shape(v: Any) -> tuple[int, ...]:
    """The shape of nested lists read along their first elements (no array built)."""
    out = []
    while isinstance(v, (list, tuple)):
        out.append(len(v))
        v = v[0] if v else None
    return tuple(out)


def _inv(M: np.ndarray, what: str, where: str) -> np.ndarray:
    """``M^{-1}``, or a one-line :class:`ModelError` when ``M`` is singular."""
    cond = np.linalg.cond(M)
    if not np.isfinite(cond) or cond > MAX_CONDITION:
        raise ModelError(f"{where}: {what} is singular (condition number {cond:.3g})")
    return np.linalg.inv(M)


def _g_sensitivity(M: np.ndarray, name: str, where: str, drop: bool, notes: list[str]) -> bool:
    """Whether to import a gyro g-sensitivity matrix ``M``: ``False`` when it is zero, or non-zero and
    dropped (``drop``, with a note)."""
    if not np.any(M):
        return False
    if drop:
        notes.append(f"dropped the gyroscope g-sensitivity {name} (max |{name}| = {float(np.max(np.abs(M))):.3g})")
        return False
    return True


def _linear_model(fwd: Mapping[str, tuple[np.ndarray, np.ndarray]], units: Mapping[str, str],
                  source: Mapping[str, Any], G: np.ndarray | None = None) -> CalibrationModel:
    """A ``linear`` model from forward ``(S, b)`` per sensor (jaxcal units) and an optional gyro
    g-sensitivity ``G`` ((rad/s)/g), checked as ``load_model`` would."""
    state = {s: {"S": np.asarray(S, np.float64), "b": np.asarray(b, np.float64)} for s, (S, b) in fwd.items()}
    if G is not None:
        state["gyr"][GSENS_KEY] = np.asarray(G, np.float64)
    meta = {"units": dict(units), "imported_from": dict(source)}
    check_linear_state(state, meta, tuple(state))
    return CalibrationModel("linear", tuple(state), state, meta)


def _input_unit(sensor: str, unit: Any, what: str, notes: list[str]) -> tuple[str, float]:
    """(jaxcal input unit, the file's input value per that unit) for a file's raw-input unit."""
    phys = _PER_JAXCAL_UNIT[sensor]
    if isinstance(unit, str) and unit in phys:
        return PHYS_UNIT[sensor], phys[unit]
    if unit != "LSB":
        notes.append(f"{what} {unit!r} taken as raw numbers (jaxcal unit LSB)")
    return "LSB", 1.0


def _imucal_version_ok(v: Any) -> bool:
    """imucal's format 2 in any spelling it writes or reads (``"2.0.0"``, its own example's ``"2.0"``)."""
    if not isinstance(v, str) or not re.fullmatch(r"\d+(\.\d+){0,2}", v.strip()):
        return False
    return int(v.strip().split(".")[0]) == int(IMUCAL_FORMAT_VERSION.split(".")[0])


def from_imucal(doc: Any, drop_g_sensitivity: bool = False) -> Imported:
    """imucal's ``FerrarisCalibrationInfo`` / ``TurntableCalibrationInfo`` JSON as a ``linear`` model.

    Inverts :func:`to_imucal`'s mapping: imucal's forward matrix ``K R`` (raw per ``acc_unit`` /
    ``gyr_unit``: m/s^2 or g, deg/s or rad/s) becomes jaxcal's ``S`` (raw per g, raw per rad/s). A raw
    input unit (``from_acc_unit`` / ``from_gyr_unit``) that is physical (m/s^2, g; deg/s, rad/s) becomes
    jaxcal's ``g`` / ``rad/s`` (``S`` and ``b`` rescaled); any other (``a.u.``, ``LSB``, none) is raw
    (``LSB``). A non-zero ``K_ga`` becomes the gyro g-sensitivity ``G = G0 S_g^{-1} K_ga`` ((rad/s)/g,
    with ``K_ga`` in jaxcal's input unit per m/s^2), unless ``drop_g_sensitivity``.

    Args:
        doc: the parsed JSON (:func:`read_document`).
        drop_g_sensitivity: import a non-zero ``K_ga`` as zero (with a note).

    Raises:
        ModelError: not an imucal Ferraris/Turntable CalibrationInfo of format 2 (2.0.0, 2.0), a missing or
            malformed matrix, or an output unit jaxcal does not know (one line).
    """
    where = "imucal CalibrationInfo"
    if not isinstance(doc, Mapping) or "cal_type" not in doc:
        raise ModelError(f"{where}: no 'cal_type' key (not a file written by imucal's CalibrationInfo.to_json_file)")
    if doc["cal_type"] not in ("Ferraris", "Turntable"):
        raise ModelError(f"{where}: cal_type {doc['cal_type']!r} is not one jaxcal reads (Ferraris, Turntable)")
    if not _imucal_version_ok(doc.get("_format_version")):
        raise ModelError(f"{where}: _format_version {doc.get('_format_version')!r} is not {IMUCAL_FORMAT_VERSION} (nor another spelling of format 2) "
                         "(convert older files with imucal.legacy first)")
    notes: list[str] = []
    fwd, units = {}, {}
    for s, tag in (("acc", "a"), ("gyr", "g")):
        out_unit = doc.get(f"{s}_unit")
        if out_unit not in _PER_JAXCAL_UNIT[s]:
            raise ModelError(f"{where}: {s}_unit {out_unit!r} is not one jaxcal converts "
                             f"({', '.join(_PER_JAXCAL_UNIT[s])})")
        K = _matrix(doc, f"K_{tag}", (3, 3), where)
        R = _matrix(doc, f"R_{tag}", (3, 3), where)
        b = _matrix(doc, f"b_{tag}", (3,), where)
        units[s], per_in = _input_unit(s, doc.get(f"from_{s}_unit"), f"from_{s}_unit", notes)
        fwd[s] = (K @ R * (_PER_JAXCAL_UNIT[s][out_unit] / per_in), b / per_in)
    K_ga = _matrix(doc, "K_ga", (3, 3), where)
    G = None
    if _g_sensitivity(K_ga, "K_ga", where, drop_g_sensitivity, notes):
        # raw_file = K R gyr + K_ga acc_ms2 + b; jaxcal's input is raw_file / per_in and acc_ms2 = G0 f
        per_in = _input_unit("gyr", doc.get("from_gyr_unit"), "from_gyr_unit", [])[1]
        G = G0 * _inv(fwd["gyr"][0], "K_g R_g", where) @ K_ga / per_in
    source = {"format": "imucal", "cal_type": doc["cal_type"], "notes": notes}
    return Imported(_linear_model(fwd, units, source, G), tuple(notes))


def from_json_export(doc: Any) -> Imported:
    """jaxcal's own plain JSON (:func:`to_json`, format :data:`JSON_FORMAT`) as a ``linear`` model.

    Args:
        doc: the parsed JSON.

    Raises:
        ModelError: another format, or a sensor entry that is malformed (one line).
    """
    where = "jaxcal JSON"
    if not isinstance(doc, Mapping) or doc.get("format") != JSON_FORMAT:
        got = doc.get("format") if isinstance(doc, Mapping) else type(doc).__name__
        raise ModelError(f"{where}: format {got!r} is not {JSON_FORMAT!r} (written by `jaxcal export --format json`)")
    sensors = doc.get("sensors")
    if not isinstance(sensors, Mapping) or not sensors or any(s not in _IMU_SENSORS for s in sensors):
        raise ModelError(f"{where}: 'sensors' must map some of acc, gyr to their calibration")
    notes: list[str] = []
    fwd, units = {}, {}
    for s in _IMU_SENSORS:
        if s not in sensors:
            continue
        p = sensors[s]
        A = _matrix(p, "A", (3, 3), f"{where} {s}")
        b = _matrix(p, "b", (3,), f"{where} {s}")
        if not isinstance(p, Mapping) or p.get("output_unit") != PHYS_UNIT[s]:
            raise ModelError(f"{where} {s}: output_unit {p.get('output_unit')!r} is not {PHYS_UNIT[s]!r}")
        unit = p.get("input_unit")
        if unit not in ("LSB", PHYS_UNIT[s]):
            notes.append(f"{s} input_unit {unit!r} taken as raw numbers (jaxcal unit LSB)")
            unit = "LSB"
        fwd[s] = (_inv(A, "A", f"{where} {s}"), b)
        units[s] = unit
    G = None
    if isinstance(sensors.get("gyr"), Mapping) and "G" in sensors["gyr"]:
        G = _matrix(sensors["gyr"], "G", (3, 3), f"{where} gyr")
        if "acc" not in fwd:
            raise ModelError(f"{where} gyr: a g-sensitivity G is applied with the calibrated accelerometer, but the file has no acc")
    source = {"format": "json", "method": doc.get("method"), "notes": notes}
    return Imported(_linear_model(fwd, units, source, G), tuple(notes))


def _imu0(doc: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(doc, Mapping) or not isinstance(doc.get("imu0"), Mapping):
        raise ModelError(f"{where}: no 'imu0' mapping")
    return doc["imu0"]


def _yaml_bias_units(imu: Mapping[str, Any], where: str, notes: list[str]) -> tuple[dict, dict]:
    """Raw bias (``jaxcal_b_a``/``_g``, zero when absent) and input units of a YAML export."""
    bias, units = {}, {}
    for s, key in (("acc", "jaxcal_b_a"), ("gyr", "jaxcal_b_g")):
        if key in imu:
            bias[s] = _matrix(imu, key, (3,), where)
        else:
            bias[s] = np.zeros(3)
            notes.append(f"no {key}: {s} bias taken as 0 (the tool estimates it online)")
        unit = imu.get(f"jaxcal_input_unit_{s}")
        if unit in ("LSB", PHYS_UNIT[s]):
            units[s] = unit
        else:
            units[s] = "LSB"
            notes.append(f"{s} input unit {unit!r} taken as raw numbers (jaxcal unit LSB)")
    return bias, units


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
    imu = _imu0(doc, where)
    if imu.get("model") != "scale-misalignment":
        raise ModelError(f"{where}: model {imu.get('model')!r} is not 'scale-misalignment' (the Kalibr IMU model "
                         "jaxcal reads; 'calibrated' holds no intrinsics, 'scale-misalignment-size-effect' has "
                         "per-axis lever arms)")
    T = _matrix(imu, "T_i_b", (4, 4), where)
    if np.any(T[:3, 3]):
        raise ModelError(f"{where}: T_i_b has a translation (lever arm {T[:3, 3].tolist()} m), which a jaxcal "
                         "linear model cannot hold")
    if np.any(T[3] != [0.0, 0.0, 0.0, 1.0]):
        raise ModelError(f"{where}: T_i_b's last row is {T[3].tolist()}, not [0, 0, 0, 1] (not a rigid transform)")
    C_i_b = _rotation(T[:3, :3], "T_i_b's rotation", where)
    M_a = _matrix(imu.get("accelerometers"), "M", (3, 3), f"{where} accelerometers")
    M_g = _matrix(imu.get("gyroscopes"), "M", (3, 3), f"{where} gyroscopes")
    C_gyro_i = _rotation(_matrix(imu.get("gyroscopes"), "C_gyro_i", (3, 3), f"{where} gyroscopes"), "C_gyro_i", f"{where} gyroscopes")
    notes: list[str] = []
    A = _matrix(imu.get("gyroscopes"), "A", (3, 3), f"{where} gyroscopes")
    keep = _g_sensitivity(A, "A", where, drop_g_sensitivity, notes)
    bias, units = _yaml_bias_units(imu, where, notes)
    S_g = M_g @ C_gyro_i @ C_i_b
    fwd = {"acc": (G0 * (M_a @ C_i_b), bias["acc"]), "gyr": (S_g, bias["gyr"])}
    G = G0 * _inv(S_g, "M_g C_gyro_i C_i_b", where) @ A @ C_gyro_i @ C_i_b if keep else None
    return Imported(_linear_model(fwd, units, {"format": "kalibr", "notes": notes}, G), tuple(notes))


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
    imu = _imu0(doc, where)
    if imu.get("model") not in ("kalibr", "calibrated"):
        raise ModelError(f"{where}: model {imu.get('model')!r} is not 'kalibr' or 'calibrated' (the OpenVINS IMU "
                         "models whose lower-triangular Tw, Ta jaxcal reads)")
    notes: list[str] = []
    mats = {}
    for key in ("Tw", "R_IMUtoGYRO", "Ta", "R_IMUtoACC", "Tg"):
        mats[key] = _matrix(imu, key, (3, 3), where)
        if key.startswith("R_"):
            _rotation(mats[key], key, where)
    for key in ("Tw", "Ta"):
        if np.any(np.triu(mats[key], 1)):
            raise ModelError(f"{where}: {key} is not lower triangular (OpenVINS's kalibr model keeps only the lower "
                             f"triangle of its inverse, so this file does not mean what it says)")
    keep = _g_sensitivity(mats["Tg"], "Tg", where, drop_g_sensitivity, notes)
    bias, units = _yaml_bias_units(imu, where, notes)
    Da, Dw = np.tril(_inv(mats["Ta"], "Ta", where)), np.tril(_inv(mats["Tw"], "Tw", where))
    S_a = G0 * _inv(mats["R_IMUtoACC"].T @ Da, "R_IMUtoACC^T Da", where)
    S_g = _inv(mats["R_IMUtoGYRO"].T @ Dw, "R_IMUtoGYRO^T Dw", where)
    fwd = {"acc": (S_a, bias["acc"]), "gyr": (S_g, bias["gyr"])}
    G = G0 * _inv(S_g, "R_IMUtoGYRO^T Dw", where) @ mats["Tg"] if keep else None
    return Imported(_linear_model(fwd, units, {"format": "openvins", "notes": notes}, G), tuple(notes))


def import_model(fmt: str, doc: Any, drop_g_sensitivity: bool = False) -> Imported:
    """A parsed calibration file of format ``fmt`` (:data:`IMPORT_FORMATS`) as a jaxcal ``linear`` model.

    Args:
        fmt: ``imucal``, ``json``, ``kalibr`` or ``openvins``.
        doc: the parsed document (:func:`read_document`).
        drop_g_sensitivity: import a gyro g-sensitivity (imucal ``K_ga``, Kalibr ``A``, OpenVINS ``Tg``)
            as zero instead of into ``state/gyr/G`` (not used by ``json``).

    Raises:
        ModelError: unknown format, or what the format's reader refuses (one line).
    """
    if fmt == "imucal":
        return from_imucal(doc, drop_g_sensitivity)
    if fmt == "json":
        return from_json_export(doc)
    if fmt == "kalibr":
        return from_kalibr(doc, drop_g_sensitivity)
    if fmt == "openvins":
        return from_openvins(doc, drop_g_sensitivity)
    raise ModelError(f"unknown import format {fmt!r} ({', '.join(IMPORT_FORMATS)})")
