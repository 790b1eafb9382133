"""TUM-VI CSV with ROS message field names (as exported by Brossard et al.'s tools)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.constants import G0
from jaxcal.formats.base import Format
from jaxcal.formats.euroc import read_euroc
from jaxcal.formats.pose import attach_pose, quat_xyzw_to_wxyz
from jaxcal.formats.table import column, finish_recording, need_columns, need_rows, read_table
from jaxcal.recording import Recording

__all__ = ["FORMAT", "read_tumvi"]


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
    header, rows = read_table(imu_path)
    if "angular_velocity.x" not in header:
        return read_euroc(imu_path, gt_path, max_gap=max_gap)
    need_columns(imu_path, header, ("Time",) + _TUMVI_IMU, "a TUM-VI IMU CSV")
    need_rows(imu_path, rows)
    traw = column(imu_path, header, rows, "Time")
    t0 = traw[0]
    gyr = np.stack([column(imu_path, header, rows, n) for n in _TUMVI_IMU[:3]], -1)
    acc = np.stack([column(imu_path, header, rows, n) for n in _TUMVI_IMU[3:]], -1) / G0
    rec: dict[str, Any] = {"t": traw - t0, "acc": acc, "gyr": gyr, "acc_unit": "g", "gyr_unit": "rad/s",
                           "t0": float(t0), "_acc_columns": "'linear_acceleration.x'",
                           "_gyr_columns": "'angular_velocity.x'"}
    if gt_path is not None:
        gt_path = Path(gt_path)
        gh, grows = read_table(gt_path)
        need_columns(gt_path, gh, ("Time",) + _TUMVI_GT, "a TUM-VI ground-truth CSV")
        need_rows(gt_path, grows)
        tg = column(gt_path, gh, grows, "Time") - t0
        pos = np.stack([column(gt_path, gh, grows, n) for n in _TUMVI_GT[:3]], -1)
        q_xyzw = np.stack([column(gt_path, gh, grows, n) for n in _TUMVI_GT[3:]], -1)
        attach_pose(rec, tg, pos, quat_xyzw_to_wxyz(q_xyzw, f"{gt_path}: columns 'transform.rotation.*'"),
                     max_gap, f"{gt_path}: column 'Time'")
    return finish_recording(rec, str(imu_path))



def _read(files: list[Path], **options: Any) -> Recording:
    return read_tumvi(files[0], files[1] if len(files) > 1 else None, **options)


FORMAT = Format("tumvi", "TUM-VI CSV (ROS field names, or the EuRoC layout) [and a ground-truth CSV]", read=_read,
                files=(1, 2), read_help="IMU CSV [pose CSV]")
