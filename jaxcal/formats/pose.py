"""Reference pose tracks of the readers: unit quaternions (scalar first), ROS order ``x, y, z, w``
re-ordered, and :func:`attach_pose` (a track interpolated to the IMU times: linear in position,
:func:`jaxcal.rotation.slerp_pairs` in attitude)."""

from __future__ import annotations

from typing import Any

import numpy as np

from jaxcal.formats.table import ReaderError, check_time
from jaxcal.rotation import slerp_pairs

__all__ = ["attach_pose", "quat_xyzw_to_wxyz", "unit_quaternions"]


def quat_xyzw_to_wxyz(q_xyzw: np.ndarray, where: str = "quaternion") -> np.ndarray:
    """ROS-order quaternions ``[x, y, z, w]`` as the conventions' ``[w, x, y, z]``, checked unit (:func:`unit_quaternions`)."""
    return unit_quaternions(np.concatenate([q_xyzw[:, 3:4], q_xyzw[:, :3]], axis=1), where)


def _slerp_to(t_src: np.ndarray, q_src: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    """Quaternion (scalar first) slerp of a pose track onto new times (held at the ends)."""
    q_src = q_src.copy()
    # make consecutive quaternions share a hemisphere
    for i in range(1, len(q_src)):
        if np.dot(q_src[i], q_src[i - 1]) < 0:
            q_src[i] = -q_src[i]
    j = np.clip(np.searchsorted(t_src, t_dst) - 1, 0, len(t_src) - 2)
    u = np.clip((t_dst - t_src[j]) / (t_src[j + 1] - t_src[j]), 0.0, 1.0)
    return slerp_pairs(q_src[j], q_src[j + 1], u)


def attach_pose(rec: dict[str, Any], t_gt: np.ndarray, pos: np.ndarray, q_wxyz: np.ndarray,
                 max_gap: float, where: str = "pose") -> None:
    """Interpolate a pose track to the IMU times (linear / slerp, held at the ends).

    ``ref_valid`` (N,) bool marks IMU samples inside the track and not across a gap longer than
    ``max_gap`` s; elsewhere the pose is only the nearest held value. The original track is kept
    as ``gt_t``, ``gt_pos``, ``gt_quat``. The track's times must increase (``where`` names them).
    """
    t_gt = check_time(np.asarray(t_gt, np.float64), where)
    if not np.all(np.isfinite(pos)):
        raise ReaderError(f"{where}: non-finite position")
    t = rec["t"]
    rec["pos_ref"] = np.stack([np.interp(t, t_gt, pos[:, k]) for k in range(3)], -1)
    rec["quat_ref"] = _slerp_to(t_gt, q_wxyz, t)
    j = np.clip(np.searchsorted(t_gt, t) - 1, 0, len(t_gt) - 2)
    gap = (t_gt[j + 1] - t_gt[j]) > max_gap
    rec["ref_valid"] = ~gap & (t >= t_gt[0]) & (t <= t_gt[-1])
    rec["gt_t"], rec["gt_pos"], rec["gt_quat"] = t_gt, pos, q_wxyz


def unit_quaternions(q: np.ndarray, where: str) -> np.ndarray:
    """Quaternions (K, 4), finite and of unit norm (within 1 %), renormalised exactly."""
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(~np.isfinite(norm) | (np.abs(norm - 1.0) > 0.01))
    if bad.size:
        raise ReaderError(f"{where} row {int(bad[0])}: quaternion norm {norm[bad[0]]:.4g}, not a unit quaternion")
    return q / norm[:, None]

