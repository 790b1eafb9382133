"""What every file reader shares: :class:`ReaderError`, units, text tables, time stamps, and the
last step :func:`finish_recording` (a filled mapping -> a validated :class:`~jaxcal.recording.Recording`).

Units are never guessed silently: a unit is taken from the caller or from the header
(``Name (unit)`` / ``Name [unit]``), and an unknown, conflicting or implausible unit raises
:class:`ReaderError` naming the file, the column and the reason. A reader fills a ``dict`` and hands
it to :func:`jaxcal.recording.recording_from_dict` once (:func:`finish_recording`). File input only
(:func:`read_text`); no state.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.constants import G0, PHYS_UNIT, SENSORS
from jaxcal.recording import Recording, implausible, recording_from_dict

__all__ = [
    "ReaderError",
    "as_counts",
    "check_column_units",
    "check_time",
    "column",
    "convert3",
    "finish_recording",
    "need_columns",
    "need_rows",
    "positive_rate",
    "read_table",
    "read_text",
    "strip_units",
    "time_cells",
    "unit_factor",
    "unit_from_header",
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


UNIT_IN_NAME = re.compile(r"[\(\[]\s*([^\)\]]*?)\s*[\)\]]\s*$")


def unit_from_header(name: str) -> str | None:
    """The unit written in a column header as ``Name (unit)`` or ``Name [unit]``, else ``None``."""
    m = UNIT_IN_NAME.search(name)
    if not m or not m.group(1):
        return None
    return m.group(1)


def read_text(path: Path) -> str:
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


def read_table(path: Path, skip: int = 0) -> tuple[list[str], list[list[str]]]:
    lines = read_text(path).splitlines()[skip:]
    try:
        rows = list(csv.reader(io.StringIO("\n".join(lines))))
    except csv.Error as e:
        raise ReaderError(f"{path}: not a readable CSV ({e})") from None
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        raise ReaderError(f"{path}: no header line")
    header = [h.strip().lstrip("#").strip() for h in rows[0]]
    return header, rows[1:]


def need_rows(path: Path, rows: list[list[str]], n: int = 2) -> None:
    """Refuse a table with fewer than ``n`` data rows (e.g. a header and nothing else)."""
    if len(rows) < n:
        raise ReaderError(f"{path}: {len(rows)} data rows after the header; need at least {n}")


def need_columns(path: Path, header: list[str], names: Sequence[str], what: str) -> None:
    """Refuse a table lacking any of ``names`` (e.g. another format's CSV), naming the first missing."""
    missing = [n for n in names if n not in header]
    if missing:
        raise ReaderError(f"{path}: column {missing[0]!r} not found; not {what}? header has {header[:12]}")


def column(path: Path, header: list[str], rows: list[list[str]], name: str) -> np.ndarray:
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


def as_counts(x: np.ndarray, where: str) -> np.ndarray:
    """Raw counts as int32; they must be finite, integer-valued and fit 32 bits (never wrapped)."""
    if not np.all(np.isfinite(x)) or np.any(np.abs(x - np.round(x)) > 1e-6):
        raise ReaderError(f"{where}: unit says raw counts (LSB) but the values are not integers")
    big = np.argwhere(np.abs(x) > _COUNT_LIMIT)
    if big.size:
        raise ReaderError(f"{where} row {int(big[0][0])}: count {x[tuple(big[0])]:.6g} does not fit 32 bits; "
                          "these are not raw ADC counts")
    return np.round(x).astype(np.int32)


def check_time(t: np.ndarray, where: str) -> np.ndarray:
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
    rec["t"] = check_time(np.asarray(rec["t"], dtype=np.float64), where)
    return recording_from_dict(rec, where)


def convert3(
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
    x = np.stack([column(path, header, rows, n) for n in names], axis=-1)
    if factor is None:
        return as_counts(x, f"{path}: column {names[0]!r}"), "LSB"
    return (x * factor), _CANONICAL[quantity]


def positive_rate(fs: Any, where: str) -> float:
    """A sample rate in Hz: a positive finite number."""
    try:
        f = float(fs)
    except (TypeError, ValueError):
        raise ReaderError(f"{where}: sample rate must be a number, got {fs!r}") from None
    if not (math.isfinite(f) and f > 0):
        raise ReaderError(f"{where}: sample rate must be positive and finite, got {fs!r}")
    return f


def _exact_time(text: str) -> int | float:
    """An integer time stamp kept exact (ns since 1970 need 61 bits), else a float."""
    text = text.strip()
    try:
        return int(text)
    except ValueError:
        return float(text)


def time_cells(path: Path, header: list[str], rows: list[list[str]]) -> list[int | float]:
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



def strip_units(header: list[str]) -> list[str]:
    return [UNIT_IN_NAME.sub("", h).strip() for h in header]

