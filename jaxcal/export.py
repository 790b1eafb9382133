"""Exports of a linear calibration model that leave jaxcal: a plain JSON and a C99 header.

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

from jaxcal import __version__, methods
from jaxcal.constants import PHYS_UNIT
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.methods.base import affine_state, apply_linear_state
from jaxcal.sensor import LinearCal

__all__ = ["EQUATION", "JSON_FORMAT", "is_linear", "linear_cals", "linear_methods", "to_c_header", "to_json"]

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
