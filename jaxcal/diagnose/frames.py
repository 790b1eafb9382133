"""Frames of a mocap rig: the rotation an ``affine`` baseline absorbs, split from what is left.

With ``--baseline affine`` the 3x3 matrix ``S`` of ``y = S u + b`` maps reference-frame inputs
``u`` to the sensor's output, so it holds the rotation between the mocap body and the IMU as well
as the sensor's scale and non-orthogonality. The polar decomposition ``S = R P`` (``R`` a
rotation, ``P`` symmetric positive definite) separates them: ``R`` rotates reference-frame
vectors into the IMU frame, so ``R_ref_imu = R^T`` in the conventions' naming (it rotates IMU-frame
vectors into the reference body frame); ``P - I`` is scale (diagonal) and non-orthogonality
(off-diagonal). Intervals come from the refit's covariance of ``S`` by the delta method
(finite-difference Jacobian of the polar rotation's rotation vector).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

__all__ = ["polar", "rotation_split", "lever_arm_frames"]


def polar(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, P)`` with ``S = R P``, ``R`` proper orthogonal (det +1), ``P`` symmetric."""
    u, sv, vt = np.linalg.svd(np.asarray(S, np.float64))
    d = np.ones(3)
    d[2] = np.sign(np.linalg.det(u @ vt)) or 1.0
    R = (u * d) @ vt
    return R, R.T @ S


def _rotvec(S: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(polar(S)[0]).as_rotvec()


def rotation_split(S: np.ndarray, cov_S: np.ndarray | None = None) -> dict:
    """The rotation in an affine baseline matrix ``S`` (3, 3) and what is left, with intervals.

    Args:
        S: baseline matrix (output = S input + b), row-major.
        cov_S: (9, 9) covariance of ``S.ravel()`` (None: no intervals).

    Returns:
        ``R_ref_imu`` (3x3, rotates IMU-frame vectors into the reference frame), ``rotation_deg``
        (its angle), ``rotvec_imu_ref_deg`` (rotation vector of ``R = R_ref_imu^T``, deg) with
        ``*_stderr``, ``scale`` (diagonal of ``P``), ``non_orthogonality_rad`` (off-diagonal of
        ``P``, the upper triangle ``[p01, p02, p12]``).
    """
    S = np.asarray(S, np.float64).reshape(3, 3)
    R, P = polar(S)
    rv = _rotvec(S)
    out = {"R_ref_imu": R.T.tolist(), "rotation_deg": float(np.degrees(np.linalg.norm(rv))),
           "rotvec_imu_ref_deg": np.degrees(rv).tolist(), "scale": np.diag(P).tolist(),
           "non_orthogonality_rad": [float(P[0, 1]), float(P[0, 2]), float(P[1, 2])]}
    if cov_S is not None:
        h = 1e-7
        J = np.zeros((3, 9))
        for k in range(9):
            e = np.zeros(9)
            e[k] = h
            J[:, k] = (_rotvec(S + e.reshape(3, 3)) - _rotvec(S - e.reshape(3, 3))) / (2 * h)
        c = J @ np.asarray(cov_S) @ J.T
        se = np.sqrt(np.clip(np.diag(c), 0.0, None))
        n = np.linalg.norm(rv)
        u = rv / n if n > 0 else np.zeros(3)
        se_ang = float(np.sqrt(max(u @ c @ u, 0.0))) if n > 0 else float(np.sqrt(np.trace(c) / 3))
        out.update({"rotvec_imu_ref_deg_stderr": np.degrees(se).tolist(), "rotation_deg_stderr": float(np.degrees(se_ang))})
    return out


def lever_arm_frames(r_ref: npt.ArrayLike, se_ref: npt.ArrayLike, R_ref_imu: npt.ArrayLike) -> dict:
    """The lever arm (IMU position relative to the reference point) in the reference body frame
    (as estimated) and in the IMU frame (``R_ref_imu^T r``), with standard errors.

    Args:
        r_ref: (3,) lever arm in the reference body frame (m).
        se_ref: (3,) its standard errors (m).
        R_ref_imu: (3, 3) rotates IMU-frame vectors into the reference body frame.
    """
    r_ref = np.asarray(r_ref, np.float64)
    Rt = np.asarray(R_ref_imu, np.float64).T
    se_imu = np.sqrt((Rt**2) @ (np.asarray(se_ref, np.float64) ** 2))
    return {"r_ref_frame_m": r_ref.tolist(), "r_ref_frame_stderr_m": np.asarray(se_ref).tolist(),
            "r_imu_frame_m": (Rt @ r_ref).tolist(), "r_imu_frame_stderr_m": se_imu.tolist(),
            "norm_m": float(np.linalg.norm(r_ref))}
