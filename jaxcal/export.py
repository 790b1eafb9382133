"""Exports of a linear calibration model that leave jaxcal: plain JSON, a C99 header, Kalibr and OpenVINS YAML.

A linear model (a method whose ``apply`` is :func:`~jaxcal.methods.base.apply_linear_state`:
``linear``, ``multipos``, ``online``) holds per sensor an affine calibration, applied as::

    x = A @ (y - b)

``y``: one raw sample (3,) in the sensor's unit at fit time (``meta["units"]``, e.g. ``LSB``);
``b``: the bias (3,) in that same unit, subtracted first; ``A``: a 3x3 matrix multiplying the
column vector ``y - b`` from the left (it is the inverse ``S^{-1}`` of the forward model
``y = S x + b``); ``x``: the calibrated sample in ``g`` (accelerometer) or ``rad/s`` (gyroscope).
Both exports write ``A`` and ``b`` of this applied form (:class:`~jaxcal.sensor.LinearCal`), never
the forward ``S``, and say so in the file. Numbers are written with Python's shortest round-trip
``repr``, so a reader parsing them as IEEE doubles gets jaxcal's float64 values exactly.

Non-linear models (``nn``, ``cubic``, ``online-thesis``) are refused: a 3x3 matrix and a bias cannot
hold them.

Two YAML exports write the same calibration in the parameterisations of Kalibr
(:func:`to_kalibr`) and OpenVINS (:func:`to_openvins`); both need an IMU model (``acc`` and ``gyr``),
write the accelerometer in m/s^2 (``x`` in g times :data:`~jaxcal.constants.G0`) and the gyroscope in
rad/s, and keep the raw input ``y`` in the model's own input unit (the unit conversion and any
counts-to-physical scale are folded into their matrices; a model fitted on ``LSB`` expects raw counts
on the IMU topic). Neither format holds a constant bias (both estimate biases online as random
walks), so ``b`` is written under the extra keys ``jaxcal_b_a`` / ``jaxcal_b_g`` (input unit),
which both tools ignore; use them as the initial bias or subtract them upstream.

Pure functions, no I/O: the ``jaxcal export`` command writes the files.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from typing import Any

import jax
import numpy as np
import yaml
from jaxtyping import Float

from jaxcal import __version__, methods
from jaxcal.arrays import Array
from jaxcal.constants import G0, PHYS_UNIT
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.methods.base import affine_state, apply_linear_state
from jaxcal.sensor import LinearCal

__all__ = [
    "EQUATION",
    "JSON_FORMAT",
    "KALIBR_CONVENTION",
    "OPENVINS_CONVENTION",
    "is_linear",
    "linear_cals",
    "linear_methods",
    "lower_times_rotation",
    "physical_cals",
    "to_c_header",
    "to_json",
    "to_kalibr",
    "to_openvins",
    "yaml_document",
]

EQUATION = "x = A @ (y - b)"
"""The applied form both exports write out (``A`` multiplies the column vector ``y - b``)."""

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
    equation in words), ``method``, ``jaxcal_version``, ``sensors``: ``{sensor: {"A": 3x3 row-major
    (a list of 3 rows), "b": [3], "input_unit", "output_unit"}}``, and ``meta``: the model's
    metadata entries that are plain finite JSON (others are dropped).

    Args:
        model: a linear model (see :func:`linear_cals`).

    Raises:
        ModelError: the model is not linear.
    """
    cals = linear_cals(model)
    sensors = {}
    for s, cal in cals.items():
        unit_in, unit_out = _units(model, s)
        sensors[s] = {
            "A": [[float(v) for v in row] for row in cal.A],
            "b": [float(v) for v in cal.b],
            "input_unit": unit_in,
            "output_unit": unit_out,
        }
    return {
        "format": JSON_FORMAT,
        "equation": EQUATION,
        "convention": "per sensor: y is one raw sample (3-vector) in input_unit; b (input_unit) is subtracted "
        "first; A (3x3, rows listed first: A[i][j] is row i, column j) multiplies the column vector y - b from "
        "the left; x is the calibrated sample in output_unit. A is the inverse of the forward model's S in "
        "y = S x + b.",
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
        lines.append(f" *   {s}: input {_c_comment(unit_in or 'unit not recorded')}, output {unit_out}; "
                     f"{name}_apply_{s}(y, x)")
    lines += [" */", f"#ifndef {guard}", f"#define {guard}", ""]
    for s, cal in cals.items():
        rows = ",\n".join("    {" + ", ".join(_c_double(v) for v in row) + "}" for row in cal.A)
        lines += [
            f"static const double {name}_{s}_A[3][3] = {{\n{rows}\n}};",
            f"static const double {name}_{s}_b[3] = {{{', '.join(_c_double(v) for v in cal.b)}}};",
            "",
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
  w_b = C_i_b.T @ C_gyro_i.T @ inv(M_g) @ (omega - b_g)     [rad/s]   (A = 0: jaxcal fits no g-sensitivity)
M_a, M_g: lower triangular (accelerometers.M, gyroscopes.M); C_gyro_i: rotation (gyroscopes.C_gyro_i);
C_i_b: rotation block of T_i_b (translation 0), from jaxcal's calibrated frame b to Kalibr's IMU frame i,
whose axes Kalibr ties to the accelerometer (lower-triangular M_a). alpha, omega: raw samples in the
model's input unit (jaxcal_input_unit_acc/_gyr); b_a, b_g: jaxcal_b_a, jaxcal_b_g in that unit (Kalibr stores no
constant bias). Matrices are lists of rows."""
"""The convention header of :func:`to_kalibr`'s file (also in its ``yaml_document``)."""

OPENVINS_CONVENTION = """\
OpenVINS IMU intrinsics (kalibr_imu_chain.yaml, imu model "kalibr"). OpenVINS reads Tw, Ta, R_IMUtoGYRO,
R_IMUtoACC, Tg and sets Dw = inv(Tw), Da = inv(Ta), R_GYROtoIMU = R_IMUtoGYRO.T, R_ACCtoIMU = R_IMUtoACC.T
(ov_msckf VioManagerOptions.h); the corrected samples are (ov_msckf Propagator.cpp, docs.openvins.com
propagation_analytical):
  a_I = R_ACCtoIMU @ Da @ (a_m - b_a)                  [m/s^2]
  w_I = R_GYROtoIMU @ Dw @ (w_m - b_g - Tg @ a_I)      [rad/s]   (Tg = 0: jaxcal fits no g-sensitivity)
Tw, Ta: lower triangular (the "kalibr" model keeps the lower triangle of Dw, Da); I: jaxcal's calibrated
frame. a_m, w_m: raw samples in the model's input unit (jaxcal_input_unit_acc/_gyr); b_a, b_g: jaxcal_b_a,
jaxcal_b_g in that unit (OpenVINS stores no constant bias). Matrices are lists of rows."""
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
        "gyroscopes": {"M": _rows(M_g), "A": _rows(np.zeros((3, 3))), "C_gyro_i": _rows(C_gyro_i)},
        **_jaxcal_fields(model, cals),
    }
    return {"imu0": _merge(imu, imu_fields)}


def to_openvins(model: CalibrationModel, imu_fields: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A linear model as OpenVINS's IMU intrinsics in its ``kalibr_imu_chain.yaml`` form (``{"imu0": {...}}``).

    Convention (:data:`OPENVINS_CONVENTION`): OpenVINS corrects ``a_I = R_IMUtoACC^T Ta^{-1} (a_m - b_a)``
    and ``w_I = R_IMUtoGYRO^T Tw^{-1} (w_m - b_g)`` (``Tg`` = 0), i.e. the forward matrices are
    ``S_a = Ta R_IMUtoACC`` and ``S_g = Tw R_IMUtoGYRO`` (input unit per m/s^2 or rad/s), split with
    :func:`lower_times_rotation`. ``Tw``, ``Ta`` are forward (OpenVINS inverts them into ``Dw``, ``Da``)
    and lower triangular, as OpenVINS's ``"kalibr"`` IMU model requires. The IMU frame ``I`` is jaxcal's
    calibrated frame.

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
        "model": "kalibr",
        "Tw": _rows(Tw),
        "R_IMUtoGYRO": _rows(R_IMUtoGYRO),
        "Ta": _rows(Ta),
        "R_IMUtoACC": _rows(R_IMUtoACC),
        "Tg": _rows(np.zeros((3, 3))),
        **_jaxcal_fields(model, cals),
    }
    return {"imu0": _merge(imu, imu_fields)}


def _merge(imu: dict[str, Any], extra: Mapping[str, Any] | None) -> dict[str, Any]:
    clash = sorted(set(extra or {}) & set(imu))
    if clash:
        raise ValueError(f"imu_fields may not replace the calibration keys {', '.join(clash)}")
    return {**imu, **(extra or {})}


def yaml_document(fmt: str, d: Mapping[str, Any]) -> str:
    """The YAML text of :func:`to_kalibr`'s (``fmt="kalibr"``) or :func:`to_openvins`'s (``"openvins"``) dict.

    A ``#`` comment header states the convention; the OpenVINS file starts with ``%YAML:1.0`` as
    OpenVINS's own configuration files do (its OpenCV reader expects it; a YAML reader skips that
    first line). Floats are written with their shortest round-trip ``repr``.

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
    body = yaml.safe_dump(dict(d), sort_keys=False, default_flow_style=None, width=200)
    first = ["%YAML:1.0"] if fmt == "openvins" else []
    return "\n".join(first + head) + "\n" + body
