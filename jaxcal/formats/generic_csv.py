"""Any CSV with a header row, given a column mapping and units (``jaxcal import csv``)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from jaxcal import flags
from jaxcal.flags import Flag
from jaxcal.formats.base import SHARED_FLAGS, Format
from jaxcal.formats.table import ReaderError, column, convert3, finish_recording, positive_rate, read_table, unit_factor, unit_from_header
from jaxcal.recording import Recording

__all__ = ["FORMAT", "read_generic_csv"]


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
        fs = positive_rate(fs, f"{path}: --fs")
    if int(skip_rows) < 0:
        raise ReaderError(f"{path}: --skip-rows must be at least 0, got {skip_rows}")
    header, rows = read_table(path, int(skip_rows))
    rec: dict[str, Any] = {}
    if "t" in columns:
        tu = units.get("t") or unit_from_header(columns["t"])
        if tu is None:
            raise ReaderError(f"{path}: column {columns['t']!r}: no time unit given (--units t=s, ms, ...) and none in the header")
        rec["t"] = column(path, header, rows, columns["t"]) * unit_factor("t", tu, where=f"{path}: column {columns['t']!r}")
    elif fs is not None:
        rec["t"] = np.arange(len(rows)) / float(fs)
    else:
        raise ReaderError(f"{path}: no time column mapped ('t') and no --fs given (the sample rate)")
    for q in ("acc", "gyr", "mag"):
        names = [columns.get(f"{q}_{a}") for a in "xyz"]
        if all(n is None for n in names):
            continue
        if any(n is None for n in names):
            raise ReaderError(f"{path}: map all three of {q}_x, {q}_y, {q}_z")
        x, u = convert3(path, header, rows, names, q, units.get(q))
        rec[q] = x
        if q != "mag":
            rec[f"{q}_unit"] = u
            rec[f"_{q}_columns"] = repr(names[0])
    if "acc" not in rec and "gyr" not in rec:
        raise ReaderError(f"{path}: map at least acc_x..acc_z or gyr_x..gyr_z")
    if "temp" in columns:
        rec["temp"] = column(path, header, rows, columns["temp"])
    if fs is not None:
        rec["fs"] = float(fs)
    return finish_recording(rec, str(path))



def _read(files: list[Path], **options: Any) -> Recording:
    if "columns" not in options:
        raise ReaderError(f"{files[0]}: the generic csv format needs a column mapping (columns=...)")
    return read_generic_csv(files[0], **options)


FORMAT = Format("csv", "any CSV with a header row, given columns= (conventions name -> CSV column) and units",
                read=_read, read_help="generic; needs --columns",
                flags={"columns": Flag("--columns", flags.mapping, None,
                                       "csv: conventions name=CSV column, e.g. t=time,acc_x=ax,..."),
                       "units": Flag("--units", flags.mapping, None, "csv: quantity=unit, e.g. t=ms,acc=m/s^2,gyr=deg/s"),
                       "fs": SHARED_FLAGS["fs"],
                       "skip_rows": Flag("--skip-rows", flags.count(0, 10**9), None, "csv: lines to skip before the header")})
