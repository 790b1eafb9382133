"""x-io Technologies' Fusion CSV (units in the header)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jaxcal.formats.base import Format
from jaxcal.formats.generic_csv import read_generic_csv
from jaxcal.formats.table import UNIT_IN_NAME, ReaderError, read_table
from jaxcal.recording import Recording

__all__ = ["FORMAT", "read_fusion"]


def read_fusion(path: str | Path) -> Recording:
    """x-io Fusion CSV: ``Time (s), Gyroscope X (deg/s), ..., Accelerometer X (g), ...,
    Magnetometer X (uT), ...`` with units in the header (converted explicitly; ``mag`` in uT).
    """
    path = Path(path)
    header, _ = read_table(path)
    cols: dict[str, str] = {}
    for h in header:
        base = UNIT_IN_NAME.sub("", h).strip().lower()
        for q, word in (("gyr", "gyroscope"), ("acc", "accelerometer"), ("mag", "magnetometer")):
            for a in "xyz":
                if base == f"{word} {a}":
                    cols[f"{q}_{a}"] = h
        if base == "time":
            cols["t"] = h
    if "t" not in cols:
        raise ReaderError(f"{path}: no 'Time (s)' column; header has {header}")
    return read_generic_csv(path, cols)



def _read(files: list[Path], **options: Any) -> Recording:
    return read_fusion(files[0])  # takes no options (and ignores any, as it always has)


FORMAT = Format("fusion", "x-io Fusion CSV, units in the header", read=_read, read_help="x-io")
