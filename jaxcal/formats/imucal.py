"""imucal (mad-lab-fau/imucal): its recording CSVs in, its ``CalibrationInfo`` JSON out and back.

Recordings (:func:`read_imucal`): a pandas CSV with an ``n_samples`` (or ``samples``) index, ``acc_*``,
``gyr_*`` and optionally ``part`` (the Ferraris section), ``t = index / fs``.

Models: imucal's ``FerrarisCalibrationInfo`` JSON (:func:`to_imucal`, :data:`IMUCAL_CONVENTION`)
holds the forward matrix as ``K @ R`` (diagonal scale times unit-row misalignment,
:func:`scale_misalignment`) in m/s^2 and deg/s; imucal's own ``CalibrationInfo.from_json_file`` reads
it, and :func:`from_imucal` reads it (or one imucal wrote) back as a ``linear`` model. A gyro
g-sensitivity ``G`` is imucal's ``K_ga = S_g G / G0`` (input unit per m/s^2).

File input only in :func:`read_imucal`; the rest is pure.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from jaxtyping import Float

from jaxcal._version import __version__
from jaxcal.arrays import Array
from jaxcal.constants import G0, PHYS_UNIT
from jaxcal.flags import Flag
from jaxcal.formats.base import SHARED_FLAGS, Exported, ExportOptions, Format, Imported
from jaxcal.formats.linear_io import (
    IMU_SENSORS,
    gsens_forward,
    imported_model,
    inv,
    keep_gsens,
    linear_cals,
    matrix,
    model_units,
    parse_json,
    rows,
)
from jaxcal.formats.table import ReaderError, column, convert3, finish_recording, need_rows, positive_rate, read_table, read_text
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.recording import Recording

__all__ = [
    "FORMAT",
    "IMUCAL_CONVENTION",
    "IMUCAL_FORMAT_VERSION",
    "from_imucal",
    "read_imucal",
    "scale_misalignment",
    "to_imucal",
]


# ----------------------------------------------------------------------------- recordings (CSV)

_IMUCAL_PHYS = ("gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z")


def read_imucal(
    path: str | Path,
    *,
    fs: float,
    acc_unit: str | None = None,
    gyr_unit: str | None = None,
    sections: str | Path | None = None,
) -> Recording:
    """imucal / pandas CSV: ``n_samples`` (or ``samples``) index, ``acc_*``, ``gyr_*``, optional ``part``.

    Two variants exist: a continuous session in physical units (imucal's example session:
    m/s^2 and deg/s, which must be stated, the header carries no units) and an annotated session
    of raw counts (``part`` column naming the Ferraris section; units ``"a.u."`` = LSB). The
    index column is a sample counter, not time: ``t = index / fs`` and ``fs`` is required.
    Annotated rows are re-ordered by sample index; ``section`` (N,) int and ``section_names``
    record the parts. A ``sections`` JSON (``{"x_p": {"start": i, "end": j}, ...}``) labels a
    continuous session the same way (-1 outside every section).

    Args:
        path: the CSV file.
        fs: sampling rate (Hz); ``t = index / fs``.
        acc_unit: unit of the ``acc_*`` columns (e.g. ``"m/s^2"``); required for a continuous session,
            default ``"a.u."`` (LSB) for an annotated one.
        gyr_unit: unit of the ``gyr_*`` columns (e.g. ``"deg/s"``); as ``acc_unit``.
        sections: optional JSON file labelling the sections of a continuous session.
    """
    path = Path(path)
    fs = positive_rate(fs, f"{path}: --fs")
    header, rows = read_table(path)
    idx_name = "n_samples" if "n_samples" in header else "samples" if "samples" in header else None
    if idx_name is None:
        raise ReaderError(f"{path}: no 'n_samples' or 'samples' index column; header has {header[:12]}")
    need_rows(path, rows)
    n = column(path, header, rows, idx_name)
    has_part = "part" in header
    if has_part:
        acc_unit = acc_unit or "a.u."
        gyr_unit = gyr_unit or "a.u."
    if acc_unit is None or gyr_unit is None:
        raise ReaderError(
            f"{path}: columns 'acc_x'/'gyr_x' carry no unit; pass --acc-unit (e.g. 'm/s^2') and "
            "--gyr-unit (e.g. 'deg/s') for this imucal session"
        )
    acc, au = convert3(path, header, rows, ("acc_x", "acc_y", "acc_z"), "acc", acc_unit)
    gyr, gu = convert3(path, header, rows, ("gyr_x", "gyr_y", "gyr_z"), "gyr", gyr_unit)
    order = np.argsort(n, kind="stable")
    rec: dict[str, Any] = {
        "t": n[order] / float(fs), "acc": acc[order], "gyr": gyr[order], "acc_unit": au,
        "gyr_unit": gu, "fs": float(fs), "_acc_columns": "'acc_x'", "_gyr_columns": "'gyr_x'",
    }
    if has_part:
        j = header.index("part")
        parts = np.array([r[j].strip() if j < len(r) else "" for r in rows])[order]
        names = sorted(set(parts.tolist()))
        rec["section"] = np.array([names.index(p) for p in parts], dtype=np.int32)
        rec["section_names"] = np.array(names)
    elif sections is not None:
        spans = _sections_json(Path(sections))
        sec = np.full(len(n), -1, dtype=np.int32)
        ni = n[order]
        for k, (start, end) in enumerate(spans.values()):
            sec[(ni >= start) & (ni <= end)] = k
        rec["section"] = sec
        rec["section_names"] = np.array(list(spans))
    return finish_recording(rec, str(path))



def _sections_json(path: Path) -> dict[str, tuple[float, float]]:
    """imucal's section list ``{"x_p": {"start": i, "end": j}, ...}`` as ``name -> (start, end)``."""
    try:
        spec = json.loads(read_text(path))
    except ValueError as e:
        raise ReaderError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(spec, dict) or not spec:
        raise ReaderError(f"{path}: expected a JSON object of sections {{\"name\": {{\"start\": i, \"end\": j}}, ...}}")
    out = {}
    for name, v in spec.items():
        ends = [v.get(k) for k in ("start", "end")] if isinstance(v, dict) else [None, None]
        if not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in ends):
            raise ReaderError(f"{path}: section {name!r}: needs numeric 'start' and 'end' sample indices, got {v!r}"[:300])
        if ends[1] < ends[0]:
            raise ReaderError(f"{path}: section {name!r}: 'end' {ends[1]} comes before 'start' {ends[0]}")
        out[str(name)] = (float(ends[0]), float(ends[1]))
    return out



# ----------------------------------------------------------------------------- models (CalibrationInfo JSON)

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

PER_JAXCAL_UNIT = {"acc": {"g": 1.0, "m/s^2": G0}, "gyr": {"rad/s": 1.0, "deg/s": 180.0 / math.pi}}
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
    missing = [s for s in IMU_SENSORS if s not in model.sensors]
    if missing:
        raise ModelError(f"imucal's CalibrationInfo holds an accelerometer and a gyroscope, but the model has no "
                         f"{' or '.join(missing)} calibration (sensors: {', '.join(model.sensors)})")
    out_unit = {"acc": _IMUCAL_ACC_UNIT, "gyr": _IMUCAL_GYR_UNIT}
    paras: dict[str, Any] = {}
    for s, tag in (("acc", "a"), ("gyr", "g")):
        S, b = _forward(model, s)
        K, R = scale_misalignment(S / PER_JAXCAL_UNIT[s][out_unit[s]])
        paras[s] = {f"K_{tag}": rows(K), f"R_{tag}": rows(R), f"b_{tag}": [float(v) for v in b]}
    return {
        "acc_unit": out_unit["acc"],
        "gyr_unit": out_unit["gyr"],
        "from_acc_unit": model_units(model, "acc")[0],
        "from_gyr_unit": model_units(model, "gyr")[0],
        "comment": f"{IMUCAL_CONVENTION} Exported by jaxcal {__version__} from a '{model.method}' model.",
        **paras["acc"],
        "K_g": paras["gyr"]["K_g"],
        "R_g": paras["gyr"]["R_g"],
        "K_ga": rows(gsens_forward(model, _forward(model, "gyr")[0])),
        "b_g": paras["gyr"]["b_g"],
        "cal_type": "Ferraris",
        "_format_version": IMUCAL_FORMAT_VERSION,
    }


def _input_unit(sensor: str, unit: Any, what: str, notes: list[str]) -> tuple[str, float]:
    """(jaxcal input unit, the file's input value per that unit) for a file's raw-input unit."""
    phys = PER_JAXCAL_UNIT[sensor]
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
        if out_unit not in PER_JAXCAL_UNIT[s]:
            raise ModelError(f"{where}: {s}_unit {out_unit!r} is not one jaxcal converts "
                             f"({', '.join(PER_JAXCAL_UNIT[s])})")
        K = matrix(doc, f"K_{tag}", (3, 3), where)
        R = matrix(doc, f"R_{tag}", (3, 3), where)
        b = matrix(doc, f"b_{tag}", (3,), where)
        units[s], per_in = _input_unit(s, doc.get(f"from_{s}_unit"), f"from_{s}_unit", notes)
        fwd[s] = (K @ R * (PER_JAXCAL_UNIT[s][out_unit] / per_in), b / per_in)
    K_ga = matrix(doc, "K_ga", (3, 3), where)
    G = None
    if keep_gsens(K_ga, "K_ga", where, drop_g_sensitivity, notes):
        # raw_file = K R gyr + K_ga acc_ms2 + b; jaxcal's input is raw_file / per_in and acc_ms2 = G0 f
        per_in = _input_unit("gyr", doc.get("from_gyr_unit"), "from_gyr_unit", [])[1]
        G = G0 * inv(fwd["gyr"][0], "K_g R_g", where) @ K_ga / per_in
    source = {"format": "imucal", "cal_type": doc["cal_type"], "notes": notes}
    return Imported(imported_model(fwd, units, source, G), tuple(notes))




# ----------------------------------------------------------------------------- the registry record


def _read(files: list[Path], **options: Any) -> Recording:
    if "fs" not in options:
        raise ReaderError(f"{files[0]}: imucal CSVs hold a sample index, not time: pass --fs (the sample rate, Hz)")
    return read_imucal(files[0], sections=files[1] if len(files) > 1 else None, **options)


def _export(model: CalibrationModel, options: ExportOptions) -> Exported:
    return Exported(json.dumps(to_imucal(model), indent=4) + "\n")


FORMAT = Format("imucal", "imucal: a recording CSV (and a sections JSON) in; its FerrarisCalibrationInfo JSON out "
                "and back", read=_read, files=(1, 2), export=_export, suffix=".json", parse=parse_json,
                import_model=from_imucal, read_help="CSV [sections.json]; needs --fs",
                flags={"fs": SHARED_FLAGS["fs"],
                       "acc_unit": Flag("--acc-unit", str, None, "accelerometer unit where the file does not say (imucal)"),
                       "gyr_unit": Flag("--gyr-unit", str, None, "gyroscope unit where the file does not say (imucal)")})
