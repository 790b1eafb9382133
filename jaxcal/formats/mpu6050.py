"""MPU-6050 Arduino logs (tomisuarez2/ImuCalibration): ``key,value`` metadata, then signed 16-bit counts."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.constants import ACC_LSB_PER_G, GYR_LSB_PER_DPS
from jaxcal.formats.base import Format
from jaxcal.formats.table import ReaderError, as_counts, column, finish_recording, positive_rate, read_table, read_text
from jaxcal.recording import Recording

__all__ = ["FORMAT", "MPU6050_ACC_LSB_PER_G", "MPU6050_GYR_LSB_PER_RADS", "read_mpu6050"]


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
    lines = read_text(path).splitlines()
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
    header, rows = read_table(path, skip=k)
    acc = as_counts(np.stack([column(path, header, rows, n) for n in ("ax", "ay", "az")], -1), f"{path}: column 'ax'")
    gyr = as_counts(np.stack([column(path, header, rows, n) for n in ("gx", "gy", "gz")], -1), f"{path}: column 'gx'")
    fs = positive_rate(meta["Fs"], f"{path}: metadata 'Fs'")
    rec: dict[str, Any] = {
        "t": np.arange(len(rows)) / fs, "acc": acc, "gyr": gyr, "acc_unit": "LSB", "gyr_unit": "LSB",
        "fs": fs, "acc_lsb_per_g": MPU6050_ACC_LSB_PER_G, "gyr_lsb_per_rads": MPU6050_GYR_LSB_PER_RADS,
    }
    for name, v in meta.items():
        if name != "Fs":
            rec["meta_" + re.sub(r"\W+", "_", name.strip().lower())] = v
    return finish_recording(rec, str(path))



def _read(files: list[Path], **options: Any) -> Recording:
    return read_mpu6050(files[0])  # takes no options (and ignores any, as it always has)


FORMAT = Format("mpu6050", "MPU-6050 Arduino log (tomisuarez2/ImuCalibration), raw counts", read=_read)
