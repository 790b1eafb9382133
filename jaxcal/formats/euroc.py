"""EuRoC / ASL CSV (``imu0/data.csv`` + ``vicon0/data.csv`` or a ground-truth estimate); the original
TUM-VI ``mav0`` files have this layout too."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.formats.base import Format
from jaxcal.formats.pose import attach_pose, unit_quaternions
from jaxcal.formats.table import (
    column,
    convert3,
    finish_recording,
    need_columns,
    need_rows,
    read_table,
    strip_units,
    time_cells,
    unit_factor,
    unit_from_header,
)
from jaxcal.recording import Recording

__all__ = ["FORMAT", "read_euroc"]


_EUROC_IMU = ("w_RS_S_x", "w_RS_S_y", "w_RS_S_z", "a_RS_S_x", "a_RS_S_y", "a_RS_S_z")
_EUROC_POSE = ("p_RS_R_x", "p_RS_R_y", "p_RS_R_z", "q_RS_w", "q_RS_x", "q_RS_y", "q_RS_z")


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
    header, rows = read_table(imu_path)
    names = strip_units(header)
    need_columns(imu_path, names, _EUROC_IMU, "an EuRoC / ASL (or TUM-VI) IMU CSV")
    need_rows(imu_path, rows)
    tu = unit_from_header(header[0]) or "ns"
    t_int = time_cells(imu_path, header, rows)  # exact integer ns: float64 cannot hold 1.4e18 + 1
    t0 = t_int[0]
    tf = unit_factor("t", tu, where=f"{imu_path}: column {header[0]!r}")
    t = np.array([x - t0 for x in t_int], dtype=np.float64) * tf
    hdr = dict(zip(names, header))
    gyr, gu = convert3(imu_path, header, rows, [hdr[n] for n in _EUROC_IMU[:3]], "gyr", None)
    acc, au = convert3(imu_path, header, rows, [hdr[n] for n in _EUROC_IMU[3:]], "acc", None)
    rec: dict[str, Any] = {"t": t, "acc": acc, "gyr": gyr, "acc_unit": au, "gyr_unit": gu,
                           "t0_ns": float(t0) * tf * 1e9,
                           "_acc_columns": repr(hdr[_EUROC_IMU[3]]), "_gyr_columns": repr(hdr[_EUROC_IMU[0]])}
    if pose_path is not None:
        pose_path = Path(pose_path)
        ph, prow = read_table(pose_path)
        pn = strip_units(ph)
        phdr = dict(zip(pn, ph))
        need_columns(pose_path, pn, _EUROC_POSE, "an EuRoC / ASL pose CSV")
        need_rows(pose_path, prow)
        ptu = unit_from_header(ph[0]) or "ns"
        ptf = unit_factor("t", ptu, where=f"{pose_path}: column {ph[0]!r}")
        tg = np.array([(x - t0) * tf if ptf == tf else x * ptf - t0 * tf for x in time_cells(pose_path, ph, prow)],
                      dtype=np.float64)
        pos = np.stack([column(pose_path, ph, prow, phdr[n]) for n in _EUROC_POSE[:3]], -1)
        q = np.stack([column(pose_path, ph, prow, phdr[n]) for n in _EUROC_POSE[3:]], -1)
        attach_pose(rec, tg, pos, unit_quaternions(q, f"{pose_path}: columns 'q_RS_*'"), max_gap,
                     f"{pose_path}: column {ph[0]!r}")
    return finish_recording(rec, str(imu_path))



def _read(files: list[Path], **options: Any) -> Recording:
    return read_euroc(files[0], files[1] if len(files) > 1 else None, **options)


FORMAT = Format("euroc", "EuRoC / ASL CSV: imu0/data.csv [and a pose CSV]", read=_read, files=(1, 2),
                read_help="IMU CSV [pose CSV]")
