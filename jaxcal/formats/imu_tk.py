"""imu_tk's ASCII files: one whitespace-separated ``t x y z`` file per sensor, raw counts."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.flags import Flag
from jaxcal.formats.base import Format
from jaxcal.formats.table import ReaderError, as_counts, check_time, finish_recording, read_text, unit_factor
from jaxcal.recording import Recording

__all__ = ["FORMAT", "read_imu_tk"]


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
    t = check_time(ta * tf, f"{acc_path}: column 't'")
    rec = {
        "t": t,
        "acc": as_counts(out["acc"][:, 1:], f"{acc_path}: columns 'x y z'"),
        "gyr": as_counts(out["gyr"][:, 1:], f"{gyr_path}: columns 'x y z'"),
        "acc_unit": "LSB",
        "gyr_unit": "LSB",
        "fs": float(1.0 / np.median(np.diff(t))),
    }
    return finish_recording(rec, str(acc_path))


def _txyz_table(p: Path) -> np.ndarray:
    """An imu_tk file: whitespace-separated ``t x y z`` rows of numbers (``#`` comments skipped)."""
    rows: list[list[float]] = []
    for k, line in enumerate(read_text(p).splitlines()):
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



def _read(files: list[Path], **options: Any) -> Recording:
    return read_imu_tk(files[0], files[1], **options)


FORMAT = Format("imu_tk", "imu_tk ASCII: an accelerometer and a gyroscope 't x y z' file, raw counts", read=_read,
                files=(2, 2), read_help="ACC GYR files",
                flags={"time_unit": Flag("--time-unit", str, None, "time unit of the files (imu_tk; default s)")})
