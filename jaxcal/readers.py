"""Readers: public IMU recording formats -> :class:`jaxcal.recording.Recording` (``CONVENTIONS.md``).

Every reader returns a validated :class:`~jaxcal.recording.Recording` (the only in-memory
recording; files in the conventions' own format are read by :func:`jaxcal.recording.load_recording`):

* ``t`` (N,) float64, seconds, increasing. Uneven sampling is kept as recorded.
* ``acc`` (N, 3) and ``gyr`` (N, 3): raw integer counts (``acc_unit`` / ``gyr_unit`` = ``"LSB"``)
  or physical values converted explicitly to **g** and **rad/s** (``"g"`` / ``"rad/s"``).
* where the format has them: ``fs`` (Hz), ``acc_lsb_per_g``, ``gyr_lsb_per_rads`` (datasheet
  values where the format documents them), ``pos_ref`` (m) / ``quat_ref`` (Hamilton, **scalar
  first**, body to world) with ``ref_valid`` and the original track ``gt_t`` / ``gt_pos`` /
  ``gt_quat``, ``t0`` (s), ``mag`` (uT), ``section`` ids with ``section_names``; format-specific
  extras (``meta_*`` header values, BROAD's ``movement``, EuRoC's ``t0_ns``) in ``Recording.extra``.

:func:`read` dispatches on a format name (``jaxcal import FORMAT FILES...``); the per-format
functions are public too. Units are never guessed silently: a unit is taken from the caller or
from the header (``Name (unit)`` / ``Name [unit]``), and an unknown, conflicting or implausible
unit raises :class:`ReaderError` naming the file, the column and the reason; a result that breaks
the conventions raises :class:`jaxcal.recording.RecordingError`.

Readers do file input by design (with :mod:`jaxcal.recording`, this is the recording I/O
boundary); they hold no state. Internally a reader fills a ``dict`` and hands it to
:func:`jaxcal.recording.recording_from_dict` once (:func:`finish_recording`).
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.constants import ACC_LSB_PER_G, G0, GYR_LSB_PER_DPS, PHYS_UNIT, SENSORS
from jaxcal.recording import Recording, implausible, recording_from_dict

__all__ = [
    "FORMATS",
    "ReaderError",
    "attach_pose",
    "finish_recording",
    "unit_quaternions",
    "read",
    "read_imu_tk",
    "read_imucal",
    "read_euroc",
    "read_tumvi",
    "read_mpu6050",
    "read_fusion",
    "read_broad",
    "read_generic_csv",
    "unit_factor",
    "unit_from_header",
    "check_column_units",
    "MPU6050_ACC_LSB_PER_G",
    "MPU6050_GYR_LSB_PER_RADS",
]

# Factors to the conventions' units. ``None`` marks raw counts (kept as integers).
_ACC_UNITS: dict[str, float | None] = {
    "g": 1.0, "g0": 1.0, "mg": 1e-3, "m/s^2": 1.0 / G0, "m/s2": 1.0 / G0, "ms^-2": 1.0 / G0,
    "m s^-2": 1.0 / G0, "m/s/s": 1.0 / G0, "lsb": None, "counts": None, "a.u.": None, "raw": None,
}
_GYR_UNITS: dict[str, float | None] = {
    "rad/s": 1.0, "rad s^-1": 1.0, "rad/sec": 1.0, "mrad/s": 1e-3, "deg/s": math.pi / 180.0,
    "dps": math.pi / 180.0, "degree/s": math.pi / 180.0, "°/s": math.pi / 180.0,
    "lsb": None, "counts": None, "a.u.": None, "raw": None,
}
_TIME_UNITS: dict[str, float] = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}
_MAG_UNITS: dict[str, float] = {"ut": 1.0, "µt": 1.0, "gauss": 100.0, "mgauss": 0.1, "nt": 1e-3}

_QUANTITY_UNITS = {"acc": _ACC_UNITS, "gyr": _GYR_UNITS, "t": _TIME_UNITS, "mag": _MAG_UNITS}
_CANONICAL = {**PHYS_UNIT, "t": "s", "mag": "uT"}

FORMATS = ("imu_tk", "imucal", "euroc", "tumvi", "mpu6050", "fusion", "broad", "csv")


class ReaderError(ValueError):
    """Bad input: the message names the file, the column (where there is one) and the reason."""


# --------------------------------------------------------------------------------------- helpers

def _norm_unit(u: str) -> str:
    return u.strip().lower().replace(" ", "").replace("²", "^2").replace("sec", "s") if u else u


def unit_factor(quantity: str, unit: str, *, where: str) -> float | None:
    """Factor from ``unit`` to the conventions' unit of ``quantity`` (``None``: raw counts).

    Args:
        quantity: ``"acc"``, ``"gyr"``, ``"t"`` or ``"mag"``.
        unit: e.g. ``"m/s^2"``, ``"deg/s"``, ``"ns"``, ``"LSB"``.
        where: ``file: column`` text used in the error message.

    Raises:
        ReaderError: unknown unit for that quantity.
    """
    table = _QUANTITY_UNITS[quantity]
    key = _norm_unit(unit)
    lookup = {_norm_unit(k): v for k, v in table.items()}
    if key not in lookup:
        raise ReaderError(
            f"{where}: unknown {quantity} unit {unit!r}; expected one of {sorted(table)}"
        )
    return lookup[key]


_UNIT_IN_NAME = re.compile(r"[\(\[]\s*([^\)\]]*?)\s*[\)\]]\s*$")


def unit_from_header(name: str) -> str | None:
    """The unit written in a column header as ``Name (unit)`` or ``Name [unit]``, else ``None``."""
    m = _UNIT_IN_NAME.search(name)
    if not m or not m.group(1):
        return None
    return m.group(1)


def _read_text(path: Path) -> str:
    """The whole file as UTF-8 text (a byte-order mark is dropped); a binary file is refused."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        raise ReaderError(f"{path}: not a text file (byte {e.start} is not UTF-8); is it the right file?") from None
    except OSError as e:
        raise ReaderError(f"{path}: cannot read ({e.strerror or e})") from None
    if "\x00" in text:
        raise ReaderError(f"{path}: not a text file (it holds NUL bytes); is it the right file?")
    return text


def _read_table(path: Path, skip: int = 0) -> tuple[list[str], list[list[str]]]:
    lines = _read_text(path).splitlines()[skip:]
    try:
        rows = list(csv.reader(io.StringIO("\n".join(lines))))
    except csv.Error as e:
        raise ReaderError(f"{path}: not a readable CSV ({e})") from None
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        raise ReaderError(f"{path}: no header line")
    header = [h.strip().lstrip("#").strip() for h in rows[0]]
    return header, rows[1:]


def _need_rows(path: Path, rows: list[list[str]], n: int = 2) -> None:
    """Refuse a table with fewer than ``n`` data rows (e.g. a header and nothing else)."""
    if len(rows) < n:
        raise ReaderError(f"{path}: {len(rows)} data rows after the header; need at least {n}")


def _need_columns(path: Path, header: list[str], names: Sequence[str], what: str) -> None:
    """Refuse a table lacking any of ``names`` (e.g. another format's CSV), naming the first missing."""
    missing = [n for n in names if n not in header]
    if missing:
        raise ReaderError(f"{path}: column {missing[0]!r} not found; not {what}? header has {header[:12]}")


def _column(path: Path, header: list[str], rows: list[list[str]], name: str) -> np.ndarray:
    if name not in header:
        raise ReaderError(f"{path}: column {name!r} not found; header has {header}")
    j = header.index(name)
    out = np.empty(len(rows), dtype=np.float64)
    for i, r in enumerate(rows):
        try:
            out[i] = float(r[j])
        except (ValueError, IndexError):
            cell = repr(r[j]) if j < len(r) else "nothing"
            raise ReaderError(f"{path}: column {name!r} row {i} (line {i + 2}): expected a number, "
                              f"got {cell}") from None
    return out


_COUNT_LIMIT = 2**31 - 1  # counts are stored as int32


def _as_counts(x: np.ndarray, where: str) -> np.ndarray:
    """Raw counts as int32; they must be finite, integer-valued and fit 32 bits (never wrapped)."""
    if not np.all(np.isfinite(x)) or np.any(np.abs(x - np.round(x)) > 1e-6):
        raise ReaderError(f"{where}: unit says raw counts (LSB) but the values are not integers")
    big = np.argwhere(np.abs(x) > _COUNT_LIMIT)
    if big.size:
        raise ReaderError(f"{where} row {int(big[0][0])}: count {x[tuple(big[0])]:.6g} does not fit 32 bits; "
                          "these are not raw ADC counts")
    return np.round(x).astype(np.int32)


def _check_time(t: np.ndarray, where: str) -> np.ndarray:
    if t.ndim != 1 or t.size < 2:
        raise ReaderError(f"{where}: need at least two samples")
    if not np.all(np.isfinite(t)):
        raise ReaderError(f"{where}: non-finite time stamps")
    if np.any(np.diff(t) <= 0):
        i = int(np.argmax(np.diff(t) <= 0))
        raise ReaderError(f"{where}: time is not strictly increasing at row {i + 1}")
    return t


_SENSOR_WORD = {"acc": "accelerometer", "gyr": "gyroscope"}


def check_column_units(rec: Mapping[str, Any], where: str = "recording") -> None:
    """Reject the physical unit a file declares for its columns where the values cannot be in it
    (a wrong unit, e.g. m/s^2 declared as g).

    The rule is :func:`jaxcal.recording.implausible` (the one every loaded recording passes too);
    here the message names the file's own column. ``rec`` is the ``name -> array`` mapping a
    reader is filling (with its ``_acc_columns`` / ``_gyr_columns`` labels), before
    :func:`finish_recording` makes it a :class:`~jaxcal.recording.Recording`.

    Args:
        rec: the ``name -> array`` mapping a reader is filling.
        where: prefix of the error message (the file).
    """
    for s in SENSORS:
        unit, word = PHYS_UNIT[s], _SENSOR_WORD[s]
        if rec.get(f"{s}_unit") != unit or s not in rec:
            continue
        why = implausible(s, np.asarray(rec[s], np.float64), "after unit conversion")
        if why:
            col = rec.get(f"_{s}_columns", s)
            raise ReaderError(f"{where}: column {col}: {why}; the declared {word} unit is wrong")


def finish_recording(rec: dict[str, Any], where: str, plausible: bool = True) -> Recording:
    """The reader's filled mapping as a validated :class:`~jaxcal.recording.Recording`: units
    plausible (naming the file's column), time strictly increasing, then the conventions' checks."""
    if plausible:
        check_column_units(rec, where)
    rec.pop("_acc_columns", None)
    rec.pop("_gyr_columns", None)
    rec["t"] = _check_time(np.asarray(rec["t"], dtype=np.float64), where)
    return recording_from_dict(rec, where)


def _convert3(
    path: Path, header: list[str], rows: list[list[str]], names: Sequence[str], quantity: str,
    unit: str | None,
) -> tuple[np.ndarray, str]:
    """Three columns of one quantity, converted; returns (values, conventions unit)."""
    header_units = {unit_from_header(n) for n in names}
    header_units.discard(None)
    if len(header_units) > 1:
        raise ReaderError(f"{path}: columns {list(names)}: mixed units {sorted(header_units)}")
    hu = header_units.pop() if header_units else None
    if unit is None and hu is None:
        raise ReaderError(
            f"{path}: column {names[0]!r}: no {quantity} unit given and none in the header; "
            f"pass units={{'{quantity}': ...}}"
        )
    if unit is not None and hu is not None:
        fu, fh = unit_factor(quantity, unit, where=f"{path}: column {names[0]!r}"), unit_factor(
            quantity, hu, where=f"{path}: column {names[0]!r}")
        if fu != fh:
            raise ReaderError(
                f"{path}: column {names[0]!r}: the header says {hu!r} but units= says {unit!r}; "
                "ambiguous, fix one of them"
            )
    u = unit if unit is not None else hu
    factor = unit_factor(quantity, u, where=f"{path}: column {names[0]!r}")
    x = np.stack([_column(path, header, rows, n) for n in names], axis=-1)
    if factor is None:
        return _as_counts(x, f"{path}: column {names[0]!r}"), "LSB"
    return (x * factor), _CANONICAL[quantity]


# --------------------------------------------------------------------------------------- formats

def read_generic_csv(
    path: str | Path,
    columns: Mapping[str, str],
    units: Mapping[str, str] | None = None,
    *,
    fs: float | None = None,
    skip_rows: int = 0,
) -> Recording:
    """Any CSV with a header row, given a column mapping and units.

    Args:
        path: the CSV file.
        columns: conventions name -> CSV header name, for any of ``t``, ``acc_x..acc_z``,
            ``gyr_x..gyr_z``, ``mag_x..mag_z``, ``temp``. Without ``t``, ``fs`` is required and
            ``t = n / fs``.
        units: quantity -> unit for ``t`` (s, ms, us, ns), ``acc`` (g, mg, m/s^2, LSB), ``gyr``
            (rad/s, mrad/s, deg/s, LSB), ``mag`` (uT, gauss). A unit may instead be written in
            the header, ``Name (unit)``; where both exist they must agree.
        fs: nominal sample rate (Hz), stored as ``fs``.
        skip_rows: lines to skip before the header.

    Returns:
        The :class:`~jaxcal.recording.Recording` (``t`` in s, ``acc`` in g or LSB, ``gyr`` in rad/s
        or LSB, ``mag`` in uT, ``temp``, ``fs``).

    Raises:
        ReaderError: missing column, unknown/conflicting/implausible unit (names the column).
    """
    path = Path(path)
    units = dict(units or {})
    if fs is not None:
        fs = _positive_rate(fs, f"{path}: fs")
    if int(skip_rows) < 0:
        raise ReaderError(f"{path}: skip_rows must be at least 0, got {skip_rows}")
    header, rows = _read_table(path, int(skip_rows))
    rec: dict[str, Any] = {}
    if "t" in columns:
        tu = units.get("t") or unit_from_header(columns["t"])
        if tu is None:
            raise ReaderError(f"{path}: column {columns['t']!r}: no time unit given and none in the header")
        rec["t"] = _column(path, header, rows, columns["t"]) * unit_factor("t", tu, where=f"{path}: column {columns['t']!r}")
    elif fs is not None:
        rec["t"] = np.arange(len(rows)) / float(fs)
    else:
        raise ReaderError(f"{path}: no time column mapped ('t') and no fs given")
    for q in ("acc", "gyr", "mag"):
        names = [columns.get(f"{q}_{a}") for a in "xyz"]
        if all(n is None for n in names):
            continue
        if any(n is None for n in names):
            raise ReaderError(f"{path}: map all three of {q}_x, {q}_y, {q}_z")
        x, u = _convert3(path, header, rows, names, q, units.get(q))
        rec[q] = x
        if q != "mag":
            rec[f"{q}_unit"] = u
            rec[f"_{q}_columns"] = repr(names[0])
    if "acc" not in rec and "gyr" not in rec:
        raise ReaderError(f"{path}: map at least acc_x..acc_z or gyr_x..gyr_z")
    if "temp" in columns:
        rec["temp"] = _column(path, header, rows, columns["temp"])
    if fs is not None:
        rec["fs"] = float(fs)
    return finish_recording(rec, str(path))


def read_imu_tk(acc_path: str | Path, gyr_path: str | Path, *, time_unit: str = "s") -> Recording:
    """imu_tk ASCII: one whitespace-separated ``t x y z`` file per sensor, raw counts.

    Both files must share the time column (imu_tk's test data does). Values are kept as integer
    counts (LSB); the imu_tk test recordings are unsigned 16-bit ADC counts centred near 32768.

    Args:
        acc_path: the accelerometer's ``t x y z`` file.
        gyr_path: the gyroscope's ``t x y z`` file (same time column).
        time_unit: unit of the time column.
    """
    out = {key: _txyz_table(Path(p)) for key, p in (("acc", acc_path), ("gyr", gyr_path))}
    ta, tg = out["acc"][:, 0], out["gyr"][:, 0]
    if ta.shape != tg.shape or not np.allclose(ta, tg):
        raise ReaderError(f"{gyr_path}: column 't': time differs from {acc_path}; resample first")
    tf = unit_factor("t", time_unit, where=f"{acc_path}: column 't'")
    t = _check_time(ta * tf, f"{acc_path}: column 't'")
    rec = {
        "t": t,
        "acc": _as_counts(out["acc"][:, 1:], f"{acc_path}: columns 'x y z'"),
        "gyr": _as_counts(out["gyr"][:, 1:], f"{gyr_path}: columns 'x y z'"),
        "acc_unit": "LSB",
        "gyr_unit": "LSB",
        "fs": float(1.0 / np.median(np.diff(t))),
    }
    return finish_recording(rec, str(acc_path))


def _txyz_table(p: Path) -> np.ndarray:
    """An imu_tk file: whitespace-separated ``t x y z`` rows of numbers (``#`` comments skipped)."""
    rows: list[list[float]] = []
    for k, line in enumerate(_read_text(p).splitlines()):
        cells = line.split()
        if not cells or cells[0].startswith("#"):
            continue
        if len(cells) != 4:
            raise ReaderError(f"{p}: line {k + 1}: expected 4 columns 't x y z', found {len(cells)}")
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            raise ReaderError(f"{p}: line {k + 1}: expected numbers 't x y z', got {line.strip()[:40]!r}") from None
    if len(rows) < 2:
        raise ReaderError(f"{p}: {len(rows)} data lines; need at least 2 't x y z' samples")
    return np.asarray(rows, dtype=np.float64)


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
    fs = _positive_rate(fs, f"{path}: fs")
    header, rows = _read_table(path)
    idx_name = "n_samples" if "n_samples" in header else "samples" if "samples" in header else None
    if idx_name is None:
        raise ReaderError(f"{path}: no 'n_samples' or 'samples' index column; header has {header[:12]}")
    _need_rows(path, rows)
    n = _column(path, header, rows, idx_name)
    has_part = "part" in header
    if has_part:
        acc_unit = acc_unit or "a.u."
        gyr_unit = gyr_unit or "a.u."
    if acc_unit is None or gyr_unit is None:
        raise ReaderError(
            f"{path}: columns 'acc_x'/'gyr_x' carry no unit; pass acc_unit (e.g. 'm/s^2') and "
            "gyr_unit (e.g. 'deg/s') for this imucal session"
        )
    acc, au = _convert3(path, header, rows, ("acc_x", "acc_y", "acc_z"), "acc", acc_unit)
    gyr, gu = _convert3(path, header, rows, ("gyr_x", "gyr_y", "gyr_z"), "gyr", gyr_unit)
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


def _positive_rate(fs: Any, where: str) -> float:
    """A sample rate in Hz: a positive finite number."""
    try:
        f = float(fs)
    except (TypeError, ValueError):
        raise ReaderError(f"{where}: sample rate must be a number, got {fs!r}") from None
    if not (math.isfinite(f) and f > 0):
        raise ReaderError(f"{where}: sample rate must be positive and finite, got {fs!r}")
    return f


def _sections_json(path: Path) -> dict[str, tuple[float, float]]:
    """imucal's section list ``{"x_p": {"start": i, "end": j}, ...}`` as ``name -> (start, end)``."""
    try:
        spec = json.loads(_read_text(path))
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


def _quat_columns_xyzw_to_wxyz(q_xyzw: np.ndarray, where: str = "quaternion") -> np.ndarray:
    return unit_quaternions(np.concatenate([q_xyzw[:, 3:4], q_xyzw[:, :3]], axis=1), where)


def _slerp_to(t_src: np.ndarray, q_src: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    """Quaternion (scalar first) slerp of a pose track onto new times (held at the ends)."""
    q_src = q_src.copy()
    # make consecutive quaternions share a hemisphere
    for i in range(1, len(q_src)):
        if np.dot(q_src[i], q_src[i - 1]) < 0:
            q_src[i] = -q_src[i]
    j = np.clip(np.searchsorted(t_src, t_dst) - 1, 0, len(t_src) - 2)
    u = np.clip((t_dst - t_src[j]) / (t_src[j + 1] - t_src[j]), 0.0, 1.0)[:, None]
    q0, q1 = q_src[j], q_src[j + 1]
    d = np.clip(np.sum(q0 * q1, axis=1, keepdims=True), -1.0, 1.0)
    th = np.arccos(d)
    s = np.sin(th)
    small = s < 1e-8
    w0 = np.where(small, 1 - u, np.sin((1 - u) * th) / np.where(small, 1, s))
    w1 = np.where(small, u, np.sin(u * th) / np.where(small, 1, s))
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def attach_pose(rec: dict[str, Any], t_gt: np.ndarray, pos: np.ndarray, q_wxyz: np.ndarray,
                 max_gap: float, where: str = "pose") -> None:
    """Interpolate a pose track to the IMU times (linear / slerp, held at the ends).

    ``ref_valid`` (N,) bool marks IMU samples inside the track and not across a gap longer than
    ``max_gap`` s; elsewhere the pose is only the nearest held value. The original track is kept
    as ``gt_t``, ``gt_pos``, ``gt_quat``. The track's times must increase (``where`` names them).
    """
    t_gt = _check_time(np.asarray(t_gt, np.float64), where)
    if not np.all(np.isfinite(pos)):
        raise ReaderError(f"{where}: non-finite position")
    t = rec["t"]
    rec["pos_ref"] = np.stack([np.interp(t, t_gt, pos[:, k]) for k in range(3)], -1)
    rec["quat_ref"] = _slerp_to(t_gt, q_wxyz, t)
    j = np.clip(np.searchsorted(t_gt, t) - 1, 0, len(t_gt) - 2)
    gap = (t_gt[j + 1] - t_gt[j]) > max_gap
    rec["ref_valid"] = ~gap & (t >= t_gt[0]) & (t <= t_gt[-1])
    rec["gt_t"], rec["gt_pos"], rec["gt_quat"] = t_gt, pos, q_wxyz


def _exact_time(text: str) -> int | float:
    """An integer time stamp kept exact (ns since 1970 need 61 bits), else a float."""
    text = text.strip()
    try:
        return int(text)
    except ValueError:
        return float(text)


def _time_cells(path: Path, header: list[str], rows: list[list[str]]) -> list[int | float]:
    """The first column as exact time stamps (:func:`_exact_time`), finite."""
    out = []
    for i, r in enumerate(rows):
        try:
            x = _exact_time(r[0])
        except ValueError:
            raise ReaderError(f"{path}: column {header[0]!r} row {i} (line {i + 2}): expected a time stamp, "
                              f"got {r[0]!r}") from None
        if not math.isfinite(x):
            raise ReaderError(f"{path}: column {header[0]!r} row {i} (line {i + 2}): non-finite time stamp {r[0]!r}")
        out.append(x)
    return out


def unit_quaternions(q: np.ndarray, where: str) -> np.ndarray:
    """Quaternions (K, 4), finite and of unit norm (within 1 %), renormalised exactly."""
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(~np.isfinite(norm) | (np.abs(norm - 1.0) > 0.01))
    if bad.size:
        raise ReaderError(f"{where} row {int(bad[0])}: quaternion norm {norm[bad[0]]:.4g}, not a unit quaternion")
    return q / norm[:, None]


_EUROC_IMU = ("w_RS_S_x", "w_RS_S_y", "w_RS_S_z", "a_RS_S_x", "a_RS_S_y", "a_RS_S_z")
_EUROC_POSE = ("p_RS_R_x", "p_RS_R_y", "p_RS_R_z", "q_RS_w", "q_RS_x", "q_RS_y", "q_RS_z")


def _strip_units(header: list[str]) -> list[str]:
    return [_UNIT_IN_NAME.sub("", h).strip() for h in header]


def read_euroc(imu_path: str | Path, pose_path: str | Path | None = None, *, max_gap: float = 0.05) -> Recording:
    """EuRoC / ASL CSV: ``imu0/data.csv`` (+ ``vicon0/data.csv`` or ground-truth estimate).

    Header ``#timestamp [ns],w_RS_S_x [rad s^-1],...,a_RS_S_x [m s^-2],...``; the pose file has
    ``p_RS_R_x [m],...,q_RS_w [],q_RS_x [],...`` (quaternion **scalar first**, body to world).
    Time is converted from ns to s (relative times keep float64 precision: ``t`` counts from the
    first IMU sample, ``t0_ns`` keeps the offset). Poses are interpolated to IMU times
    (``pos_ref``, ``quat_ref``; ``ref_valid`` is False across gaps over ``max_gap`` s).

    Args:
        imu_path: the IMU CSV (``imu0/data.csv``).
        pose_path: optional pose CSV (``vicon0/data.csv`` or a ground-truth estimate); None: no pose.
        max_gap: longest pose spacing interpolated across (s).
    """
    imu_path = Path(imu_path)
    header, rows = _read_table(imu_path)
    names = _strip_units(header)
    _need_columns(imu_path, names, _EUROC_IMU, "an EuRoC / ASL (or TUM-VI) IMU CSV")
    _need_rows(imu_path, rows)
    tu = unit_from_header(header[0]) or "ns"
    t_int = _time_cells(imu_path, header, rows)  # exact integer ns: float64 cannot hold 1.4e18 + 1
    t0 = t_int[0]
    tf = unit_factor("t", tu, where=f"{imu_path}: column {header[0]!r}")
    t = np.array([x - t0 for x in t_int], dtype=np.float64) * tf
    hdr = dict(zip(names, header))
    gyr, gu = _convert3(imu_path, header, rows, [hdr[n] for n in _EUROC_IMU[:3]], "gyr", None)
    acc, au = _convert3(imu_path, header, rows, [hdr[n] for n in _EUROC_IMU[3:]], "acc", None)
    rec: dict[str, Any] = {"t": t, "acc": acc, "gyr": gyr, "acc_unit": au, "gyr_unit": gu,
                           "t0_ns": float(t0) * tf * 1e9,
                           "_acc_columns": repr(hdr[_EUROC_IMU[3]]), "_gyr_columns": repr(hdr[_EUROC_IMU[0]])}
    if pose_path is not None:
        pose_path = Path(pose_path)
        ph, prow = _read_table(pose_path)
        pn = _strip_units(ph)
        phdr = dict(zip(pn, ph))
        _need_columns(pose_path, pn, _EUROC_POSE, "an EuRoC / ASL pose CSV")
        _need_rows(pose_path, prow)
        ptu = unit_from_header(ph[0]) or "ns"
        ptf = unit_factor("t", ptu, where=f"{pose_path}: column {ph[0]!r}")
        tg = np.array([(x - t0) * tf if ptf == tf else x * ptf - t0 * tf for x in _time_cells(pose_path, ph, prow)],
                      dtype=np.float64)
        pos = np.stack([_column(pose_path, ph, prow, phdr[n]) for n in _EUROC_POSE[:3]], -1)
        q = np.stack([_column(pose_path, ph, prow, phdr[n]) for n in _EUROC_POSE[3:]], -1)
        attach_pose(rec, tg, pos, unit_quaternions(q, f"{pose_path}: columns 'q_RS_*'"), max_gap,
                     f"{pose_path}: column {ph[0]!r}")
    return finish_recording(rec, str(imu_path))


_TUMVI_IMU = ("angular_velocity.x", "angular_velocity.y", "angular_velocity.z",
              "linear_acceleration.x", "linear_acceleration.y", "linear_acceleration.z")
_TUMVI_GT = ("transform.translation.x", "transform.translation.y", "transform.translation.z",
             "transform.rotation.x", "transform.rotation.y", "transform.rotation.z", "transform.rotation.w")


def read_tumvi(imu_path: str | Path, gt_path: str | Path | None = None, *, max_gap: float = 0.05) -> Recording:
    """TUM-VI CSV (ROS message field names, as exported by Brossard et al.'s tools).

    IMU: ``Time`` (Unix s), ``angular_velocity.*`` (rad/s), ``linear_acceleration.*`` (m/s^2,
    specific force). Ground truth: ``transform.translation.*`` (m) and ``transform.rotation.*``
    in ROS order **x, y, z, w** (scalar last), re-ordered here to the conventions' scalar-first
    Hamilton ``[w, x, y, z]``. The original TUM-VI ``mav0/imu0/data.csv`` uses the EuRoC layout:
    it is read by :func:`read_euroc`. ``t`` counts from the first IMU sample (``t0`` keeps the
    Unix offset, so float64 keeps microsecond precision).

    Args:
        imu_path: the IMU CSV.
        gt_path: optional ground-truth CSV; None: no pose.
        max_gap: longest pose spacing interpolated across (s).
    """
    imu_path = Path(imu_path)
    header, rows = _read_table(imu_path)
    if "angular_velocity.x" not in header:
        return read_euroc(imu_path, gt_path, max_gap=max_gap)
    _need_columns(imu_path, header, ("Time",) + _TUMVI_IMU, "a TUM-VI IMU CSV")
    _need_rows(imu_path, rows)
    traw = _column(imu_path, header, rows, "Time")
    t0 = traw[0]
    gyr = np.stack([_column(imu_path, header, rows, n) for n in _TUMVI_IMU[:3]], -1)
    acc = np.stack([_column(imu_path, header, rows, n) for n in _TUMVI_IMU[3:]], -1) / G0
    rec: dict[str, Any] = {"t": traw - t0, "acc": acc, "gyr": gyr, "acc_unit": "g", "gyr_unit": "rad/s",
                           "t0": float(t0), "_acc_columns": "'linear_acceleration.x'",
                           "_gyr_columns": "'angular_velocity.x'"}
    if gt_path is not None:
        gt_path = Path(gt_path)
        gh, grows = _read_table(gt_path)
        _need_columns(gt_path, gh, ("Time",) + _TUMVI_GT, "a TUM-VI ground-truth CSV")
        _need_rows(gt_path, grows)
        tg = _column(gt_path, gh, grows, "Time") - t0
        pos = np.stack([_column(gt_path, gh, grows, n) for n in _TUMVI_GT[:3]], -1)
        q_xyzw = np.stack([_column(gt_path, gh, grows, n) for n in _TUMVI_GT[3:]], -1)
        attach_pose(rec, tg, pos, _quat_columns_xyzw_to_wxyz(q_xyzw, f"{gt_path}: columns 'transform.rotation.*'"),
                     max_gap, f"{gt_path}: column 'Time'")
    return finish_recording(rec, str(imu_path))


# The MPU-6050 datasheet's sensitivities at its default full scales (+-2 g, +-250 deg/s): the
# chip's own numbers (131 LSB/(deg/s), not 2**15 / 250), kept here as reader-specific values.
MPU6050_ACC_LSB_PER_G = ACC_LSB_PER_G
MPU6050_GYR_LSB_PER_RADS = GYR_LSB_PER_DPS * 180.0 / math.pi


def read_mpu6050(path: str | Path) -> Recording:
    """MPU-6050 Arduino log (tomisuarez2/ImuCalibration): ``key,value`` metadata lines, a header
    ``ax,ay,az,gx,gy,gz`` and signed 16-bit counts; no time column.

    ``t = n / Fs`` from the ``Fs`` metadata line (required). The datasheet scales of the default
    ranges (+-2 g: 16384 LSB/g; +-250 deg/s: 131 LSB/(deg/s)) are stored as ``acc_lsb_per_g`` and
    ``gyr_lsb_per_rads``; the other metadata lines as ``meta_<name>``.
    """
    path = Path(path)
    lines = _read_text(path).splitlines()
    meta: dict[str, float] = {}
    k = 0
    while k < len(lines) and not lines[k].strip().lower().startswith("ax"):
        parts = lines[k].split(",")
        if len(parts) != 2:
            raise ReaderError(f"{path}: line {k + 1}: expected 'name,value' metadata or the 'ax,...' header")
        try:
            meta[parts[0].strip()] = float(parts[1])
        except ValueError:
            raise ReaderError(f"{path}: line {k + 1}: metadata value {parts[1]!r} is not a number") from None
        k += 1
    if k == len(lines):
        raise ReaderError(f"{path}: no 'ax,ay,az,gx,gy,gz' header line")
    if "Fs" not in meta:
        raise ReaderError(f"{path}: no 'Fs' metadata line: the sample rate is unknown and there is no time column")
    header, rows = _read_table(path, skip=k)
    acc = _as_counts(np.stack([_column(path, header, rows, n) for n in ("ax", "ay", "az")], -1), f"{path}: column 'ax'")
    gyr = _as_counts(np.stack([_column(path, header, rows, n) for n in ("gx", "gy", "gz")], -1), f"{path}: column 'gx'")
    fs = _positive_rate(meta["Fs"], f"{path}: metadata 'Fs'")
    rec: dict[str, Any] = {
        "t": np.arange(len(rows)) / fs, "acc": acc, "gyr": gyr, "acc_unit": "LSB", "gyr_unit": "LSB",
        "fs": fs, "acc_lsb_per_g": MPU6050_ACC_LSB_PER_G, "gyr_lsb_per_rads": MPU6050_GYR_LSB_PER_RADS,
    }
    for name, v in meta.items():
        if name != "Fs":
            rec["meta_" + re.sub(r"\W+", "_", name.strip().lower())] = v
    return finish_recording(rec, str(path))


def read_fusion(path: str | Path) -> Recording:
    """x-io Fusion CSV: ``Time (s), Gyroscope X (deg/s), ..., Accelerometer X (g), ...,
    Magnetometer X (uT), ...`` with units in the header (converted explicitly; ``mag`` in uT).
    """
    path = Path(path)
    header, _ = _read_table(path)
    cols: dict[str, str] = {}
    for h in header:
        base = _UNIT_IN_NAME.sub("", h).strip().lower()
        for q, word in (("gyr", "gyroscope"), ("acc", "accelerometer"), ("mag", "magnetometer")):
            for a in "xyz":
                if base == f"{word} {a}":
                    cols[f"{q}_{a}"] = h
        if base == "time":
            cols["t"] = h
    if "t" not in cols:
        raise ReaderError(f"{path}: no 'Time (s)' column; header has {header}")
    return read_generic_csv(path, cols)


_BROAD_VARS = {"imu_acc": 3, "imu_gyr": 3, "opt_quat": 4, "opt_pos": 3}


def _mat_variable(path: Path, m: Mapping[str, Any], name: str, cols: int, n: int | None) -> np.ndarray:
    """MATLAB variable ``name`` as a float64 (N, cols) array of real numbers (N = ``n`` if given)."""
    if name not in m:
        have = sorted(k for k in m if not k.startswith("__"))
        raise ReaderError(f"{path}: variable {name!r} not found; not a BROAD trial file? it has {have[:12]}")
    a = np.asarray(m[name])
    if a.dtype.kind not in "iuf":
        raise ReaderError(f"{path}: variable {name!r}: expected real numbers, got dtype {a.dtype}")
    if a.ndim != 2 or a.shape[1] != cols or (n is not None and a.shape[0] != n):
        want = f"({'N' if n is None else n}, {cols})"
        raise ReaderError(f"{path}: variable {name!r}: expected shape {want}, got {a.shape}")
    return a.astype(np.float64)


def read_broad(path: str | Path) -> Recording:
    """BROAD trial file (Laidig et al. 2021, *Data* 6(7):72; ``data_mat/NN_<trial>.mat``, CC BY 4.0).

    A MATLAB 5 file (read with :func:`scipy.io.loadmat`) holding ``imu_acc`` (N, 3) m/s^2
    (specific force), ``imu_gyr`` (N, 3) rad/s, ``opt_quat`` (N, 4) Hamilton ``[w, x, y, z]``
    rotating IMU-frame vectors into ENU (body to world, z up: the conventions' order and
    direction, kept as is), ``opt_pos`` (N, 3) m, ``sampling_rate`` (Hz), and optionally
    ``imu_mag`` (N, 3) uT, ``movement`` (N, 1) 0/1 and the ``info`` text. There are no time
    stamps: ``t = k / sampling_rate``. The optical reference is already synchronised and
    expressed for the IMU frame by the dataset authors.

    Returns the :class:`~jaxcal.recording.Recording`: ``acc`` in g (m/s^2 / 9.80665), ``gyr`` in
    rad/s, ``pos_ref``, ``quat_ref`` (finite rows renormalised), ``fs``, ``ref_valid`` (N,) bool
    (rows where both ``opt_pos`` and ``opt_quat`` are finite) and, where the file has them, ``mag``
    (uT), ``extra["movement"]`` (N,) bool and ``extra["meta_info"]``. Reference gaps stay NaN
    (never filled); a row with any NaN is a gap and is made all NaN.

    Raises:
        ReaderError: not a readable MAT file, a missing variable, a wrong shape or dtype,
            non-finite IMU values, an infinite reference value or a non-unit quaternion (the
            message names the file and the variable).
    """
    path = Path(path)
    try:
        import scipy.io
    except ImportError:  # pragma: no cover - scipy is a dependency
        raise ReaderError(f"{path}: reading BROAD .mat files needs scipy") from None
    try:
        m = scipy.io.loadmat(path)
    except NotImplementedError:
        raise ReaderError(f"{path}: a MATLAB v7.3 (HDF5) file; BROAD's data_mat files are MATLAB 5, "
                          "use those") from None
    except Exception as e:  # scipy raises many types on a damaged or foreign file
        raise ReaderError(f"{path}: not a readable MATLAB .mat file ({type(e).__name__}: "
                          f"{' '.join(str(e).split())[:120]})") from None
    acc = _mat_variable(path, m, "imu_acc", 3, None)
    n = acc.shape[0]
    if n < 2:
        raise ReaderError(f"{path}: variable 'imu_acc': {n} samples; need at least 2")
    x = {"imu_acc": acc}
    for name, cols in list(_BROAD_VARS.items())[1:]:
        x[name] = _mat_variable(path, m, name, cols, n)
    if "sampling_rate" not in m:
        raise ReaderError(f"{path}: variable 'sampling_rate' not found; the sample rate is unknown "
                          "and the file has no time stamps")
    sr = np.asarray(m["sampling_rate"])
    if sr.size != 1 or sr.dtype.kind not in "iuf":
        raise ReaderError(f"{path}: variable 'sampling_rate': expected one number, got {sr.dtype} of shape {sr.shape}")
    fs = _positive_rate(sr.item(), f"{path}: variable 'sampling_rate'")
    for name in ("imu_acc", "imu_gyr"):
        bad = np.argwhere(~np.isfinite(x[name]))
        if bad.size:
            raise ReaderError(f"{path}: variable {name!r} row {int(bad[0][0])}: non-finite value")
    ref = {}
    for name in ("opt_pos", "opt_quat"):
        v = x[name].copy()
        big = np.argwhere(np.isinf(v))
        if big.size:
            raise ReaderError(f"{path}: variable {name!r} row {int(big[0][0])}: infinite value "
                              "(a reference gap is NaN)")
        v[np.isnan(v).any(axis=1)] = np.nan
        ref[name] = v
    q = ref["opt_quat"]
    ok = np.isfinite(q).all(axis=1)
    if ok.any():
        q[ok] = unit_quaternions(q[ok], f"{path}: variable 'opt_quat' (finite rows)")
    rec: dict[str, Any] = {
        "t": np.arange(n) / fs, "acc": x["imu_acc"] / G0, "gyr": x["imu_gyr"], "acc_unit": "g",
        "gyr_unit": "rad/s", "fs": fs, "pos_ref": ref["opt_pos"], "quat_ref": q,
        "ref_valid": ok & np.isfinite(ref["opt_pos"]).all(axis=1),
    }
    for s, name in (("acc", "imu_acc"), ("gyr", "imu_gyr")):
        why = implausible(s, rec[s], "after unit conversion")
        if why:
            raise ReaderError(f"{path}: variable {name!r}: {why}; BROAD stores m/s^2 and rad/s")
    if "imu_mag" in m:
        rec["mag"] = _mat_variable(path, m, "imu_mag", 3, n)
    if "movement" in m:
        mv = np.asarray(m["movement"])
        if mv.size != n or mv.dtype.kind not in "biuf" or not np.all((mv == 0) | (mv == 1)):
            raise ReaderError(f"{path}: variable 'movement': expected {n} flags of 0/1, "
                              f"got {mv.dtype} of shape {mv.shape}")
        rec["movement"] = mv.reshape(n).astype(bool)
    if "info" in m:
        info = np.asarray(m["info"])
        if info.dtype.kind == "U" and info.size == 1:
            rec["meta_info"] = str(info.item())
    return finish_recording(rec, str(path), plausible=False)


def read(format: str, files: Sequence[str | Path], **options: Any) -> Recording:
    """Read ``files`` in ``format`` into a validated :class:`jaxcal.recording.Recording`.

    Format-specific extras (``meta_*``, ``movement``, ``t0_ns``) go to ``Recording.extra``.

    Args:
        format: one of :data:`FORMATS`.
        files: ``imu_tk``: ``[acc_file, gyr_file]``; ``imucal``: ``[csv]`` or ``[csv, sections.json]``;
            ``euroc`` / ``tumvi``: ``[imu_csv]`` or ``[imu_csv, pose_csv]``; ``mpu6050`` / ``fusion``:
            ``[csv]``; ``broad``: ``[trial.mat]``; ``csv``: ``[csv]``.
        **options: the format's keyword options: ``imucal``: ``fs`` (required), ``acc_unit``,
            ``gyr_unit``; ``euroc`` / ``tumvi``: ``max_gap``; ``imu_tk``: ``time_unit``; ``csv``:
            ``columns`` (required), ``units``, ``fs``, ``skip_rows``.

    Raises:
        ReaderError: unknown format, wrong number of files, a missing file, or bad content (the
            message names the file, the column and the reason).
        RecordingError: the result breaks the conventions (:func:`jaxcal.recording.validate_recording`).
    """
    files = [Path(f) for f in files]
    for f in files:
        if not f.is_file():
            raise ReaderError(f"{f}: no such file")

    def want(lo: int, hi: int) -> None:
        if not lo <= len(files) <= hi:
            raise ReaderError(f"format {format!r} takes {lo}..{hi} files, got {len(files)}")

    if format == "imu_tk":
        want(2, 2)
        return read_imu_tk(files[0], files[1], **options)
    if format == "imucal":
        want(1, 2)
        if "fs" not in options:
            raise ReaderError(f"{files[0]}: imucal CSVs hold a sample index, not time: pass fs")
        return read_imucal(files[0], sections=files[1] if len(files) > 1 else None, **options)
    if format == "euroc":
        want(1, 2)
        return read_euroc(files[0], files[1] if len(files) > 1 else None, **options)
    if format == "tumvi":
        want(1, 2)
        return read_tumvi(files[0], files[1] if len(files) > 1 else None, **options)
    if format == "mpu6050":
        want(1, 1)
        return read_mpu6050(files[0])
    if format == "fusion":
        want(1, 1)
        return read_fusion(files[0])
    if format == "broad":
        want(1, 1)
        return read_broad(files[0], **options)
    if format == "csv":
        want(1, 1)
        if "columns" not in options:
            raise ReaderError(f"{files[0]}: the generic csv format needs a column mapping (columns=...)")
        return read_generic_csv(files[0], **options)
    raise ReaderError(f"unknown format {format!r}; expected one of {list(FORMATS)}")
