"""jaxcal's own plain JSON of a linear model (:func:`to_json`) and its import (:func:`from_json_export`).

Per sensor the applied form ``x = A @ (y - b)`` (:data:`~jaxcal.formats.linear_io.EQUATION`) is
written out: ``y`` one raw sample (3,) in the sensor's unit at fit time, ``b`` the bias in that unit,
``A`` the 3x3 inverse ``S^{-1}`` of the forward model ``y = S x + b``, ``x`` in g or rad/s. Numbers are
written with Python's shortest round-trip ``repr``, so a reader parsing them as IEEE doubles gets
jaxcal's float64 values exactly. A gyro g-sensitivity is written as ``sensors.gyr.G``.

Pure functions, no I/O.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from jaxcal._version import __version__
from jaxcal.constants import PHYS_UNIT
from jaxcal.formats.base import Exported, ExportOptions, Format, Imported
from jaxcal.formats.linear_io import (
    EQUATION,
    EQUATION_GSENS,
    IMU_SENSORS,
    g_sensitivity,
    imported_model,
    inv,
    linear_cals,
    matrix,
    model_units,
    parse_json,
    rows,
)
from jaxcal.methods import CalibrationModel, ModelError

__all__ = ["FORMAT", "JSON_FORMAT", "from_json_export", "to_json"]

JSON_FORMAT = "jaxcal-linear-calibration/1"
"""The ``format`` field of :func:`to_json`'s output (name/version of this JSON layout)."""


def _json_safe(v: Any) -> bool:
    """Whether ``v`` is plain, finite JSON (no NaN/inf, no numpy objects)."""
    try:
        json.dumps(v, allow_nan=False)
    except (TypeError, ValueError):
        return False
    return True


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
        unit_in, unit_out = model_units(model, s)
        sensors[s] = {
            "A": [[float(v) for v in row] for row in cal.A],
            "b": [float(v) for v in cal.b],
            "input_unit": unit_in,
            "output_unit": unit_out,
        }
    gs = {}
    if G is not None:
        sensors["gyr"]["G"] = rows(G)
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
    if not isinstance(sensors, Mapping) or not sensors or any(s not in IMU_SENSORS for s in sensors):
        raise ModelError(f"{where}: 'sensors' must map some of acc, gyr to their calibration")
    notes: list[str] = []
    fwd, units = {}, {}
    for s in IMU_SENSORS:
        if s not in sensors:
            continue
        p = sensors[s]
        A = matrix(p, "A", (3, 3), f"{where} {s}")
        b = matrix(p, "b", (3,), f"{where} {s}")
        if not isinstance(p, Mapping) or p.get("output_unit") != PHYS_UNIT[s]:
            raise ModelError(f"{where} {s}: output_unit {p.get('output_unit')!r} is not {PHYS_UNIT[s]!r}")
        unit = p.get("input_unit")
        if unit not in ("LSB", PHYS_UNIT[s]):
            notes.append(f"{s} input_unit {unit!r} taken as raw numbers (jaxcal unit LSB)")
            unit = "LSB"
        fwd[s] = (inv(A, "A", f"{where} {s}"), b)
        units[s] = unit
    G = None
    if isinstance(sensors.get("gyr"), Mapping) and "G" in sensors["gyr"]:
        G = matrix(sensors["gyr"], "G", (3, 3), f"{where} gyr")
        if "acc" not in fwd:
            raise ModelError(f"{where} gyr: a g-sensitivity G is applied with the calibrated accelerometer, but the file has no acc")
    source = {"format": "json", "method": doc.get("method"), "notes": notes}
    return Imported(imported_model(fwd, units, source, G), tuple(notes))


def _import(doc: Any, drop_g_sensitivity: bool = False) -> Imported:
    return from_json_export(doc)  # the JSON's G is jaxcal's own: there is nothing to drop


def _export(model: CalibrationModel, options: ExportOptions) -> Exported:
    return Exported(json.dumps(to_json(model), indent=2) + "\n")


FORMAT = Format("json", f"plain JSON of a linear model, {EQUATION} written out", export=_export, suffix=".json",
                parse=parse_json, import_model=_import)
