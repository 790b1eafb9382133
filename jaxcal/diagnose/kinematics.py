"""Reference motion for the diagnosis: rates, angular acceleration and specific force.

From ``gyr_ref`` the angular acceleration is a smoothed derivative. From a reference pose
(``pos_ref``, ``quat_ref``, e.g. motion capture) everything is derived with one Gaussian kernel
``h`` of width ``sigma`` seconds: body rate from consecutive relative rotations, then ``h * w``;
world acceleration as ``h'' * p`` (second derivative of the smoothed position); angular
acceleration as ``h' * w``. Because differentiation amplifies mocap noise the derived reference is
band-limited, so the sensor outputs must be smoothed by the same ``h`` before they are compared
(:func:`smooth`); after smoothing, samples are decimated so that the residual noise stays nearly
white. Samples within the kernel support of a pose gap (NaN) are flagged invalid.

Conventions: quaternions Hamilton ``[w, x, y, z]`` body to world, ``R(t+dt) = R(t) Exp(w dt)``;
specific force ``f = R^T (a / g0 + e_z)`` in g (at rest z up it reads ``+1`` on z).
"""

from __future__ import annotations

import numpy as np

from jaxcal.constants import G0
from jaxcal.rotation import log_so3, matrix_from_quat

__all__ = [
    "FIRST_STAGE_SIGMA",
    "gaussian_kernels",
    "smooth",
    "derivative",
    "derivative5",
    "lever_force",
    "reference_from_pose",
    "reference_gap_mask",
]

FIRST_STAGE_SIGMA = 0.015  # s: world-frame kernel of the specific force before rotation (see reference_from_pose)


def gaussian_kernels(sigma: float, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discrete Gaussian smoother and its first/second derivative kernels (support +-4 sigma).

    The smoother sums to 1, the first-derivative kernel maps ``t`` to 1 and the second maps
    ``t^2/2`` to 1 exactly (moment-corrected), so polynomials up to degree 2 are differentiated
    without bias.

    Args:
        sigma: kernel width (s).
        dt: sample interval (s).
    """
    half = max(1, int(np.ceil(4.0 * sigma / dt)))
    tk = np.arange(-half, half + 1) * dt
    g = np.exp(-0.5 * (tk / sigma) ** 2)
    h0 = g / g.sum()
    h1 = -tk * g
    h1 = h1 / np.sum(h1 * (-tk))  # (h1 * x)(t) = sum h1[k] x(t - tk): maps x = t to 1
    h2 = (tk**2 / sigma**2 - 1.0) * g
    h2 = h2 - h2.sum() * h0  # kill the constant response
    h2 = h2 / np.sum(h2 * tk**2 / 2.0)
    return h0, h1, h2


def _conv(x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``(h * x)(t) = sum_k h[k] x(t - t_k)`` along axis 0 with edge padding ('same' size)."""
    half = (len(h) - 1) // 2
    xp = np.concatenate([np.repeat(x[:1], half, 0), x, np.repeat(x[-1:], half, 0)], axis=0)
    out = np.stack([np.convolve(xp[:, c], h, mode="valid") for c in range(x.shape[1])], axis=1)
    return out


def smooth(x: np.ndarray, sigma: float, dt: float) -> np.ndarray:
    """Gaussian smoothing of an (N, C) signal (the same kernel as the pose derivatives).

    Args:
        x: (N, C) signal.
        sigma: kernel width (s).
        dt: sample interval (s).
    """
    return _conv(np.asarray(x, np.float64), gaussian_kernels(sigma, dt)[0])


def derivative(x: np.ndarray, sigma: float, dt: float) -> np.ndarray:
    """Smoothed first time derivative of an (N, C) signal (per second).

    Args:
        x: (N, C) signal.
        sigma: kernel width (s).
        dt: sample interval (s).
    """
    return _conv(np.asarray(x, np.float64), gaussian_kernels(sigma, dt)[1])


def derivative5(x: np.ndarray, dt: float) -> np.ndarray:
    """Five-point central difference (error O(dt^4)) of an (N, C) signal; one-sided at the ends.

    Args:
        x: (N, C) signal.
        dt: sample interval (s).
    """
    x = np.asarray(x, np.float64)
    d = np.gradient(x, dt, axis=0)
    d[2:-2] = (x[:-4] - 8 * x[1:-3] + 8 * x[3:-1] - x[4:]) / (12 * dt)
    return d


def lever_force(w: np.ndarray, wdot: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The specific force (g) a point at ``r`` (m) from the centre of rotation adds:
    ``(dw/dt x r + w x (w x r)) / g0`` (the numpy twin of the ``lever_arm`` step of
    :mod:`jaxcal.diagnose.vocabulary`).

    Args:
        w: (N, 3) body rate (rad/s).
        wdot: (N, 3) angular acceleration (rad/s^2).
        r: (3,) lever arm (m).
    """
    return (np.cross(wdot, r) + np.cross(w, np.cross(w, r))) / G0


def _gap_mask(bad: np.ndarray, half: int) -> np.ndarray:
    """True where no bad sample lies within ``half`` samples."""
    k = np.ones(2 * half + 1)
    return np.convolve(bad.astype(float), k, mode="same") == 0


def reference_from_pose(
    t: np.ndarray, pos: np.ndarray, quat: np.ndarray, sigma: float
) -> dict[str, np.ndarray]:
    """Body rate, angular acceleration and specific force from a pose track, smoothed by ``sigma`` s.

    Args:
        t: (N,) uniform sample times (s).
        pos: (N, 3) reference-point position in the world frame (m), NaN in gaps.
        quat: (N, 4) attitude, Hamilton ``[w, x, y, z]``, body to world, NaN in gaps.
        sigma: Gaussian kernel width (s).

    Returns:
        ``{"gyr_ref": (N, 3) rad/s, "wdot_ref": (N, 3) rad/s^2, "acc_ref": (N, 3) g,
        "valid": (N,) bool}`` with ``valid`` False within the kernel support of a gap.
    """
    t = np.asarray(t, np.float64)
    dt = float(np.median(np.diff(t)))
    pos = np.asarray(pos, np.float64)
    quat = np.asarray(quat, np.float64)
    bad = ~(np.isfinite(pos).all(1) & np.isfinite(quat).all(1))
    idx = np.arange(len(t))
    good = ~bad
    if good.sum() < 3:
        raise ValueError("pose reference has fewer than 3 finite samples")
    pos_f = np.stack([np.interp(idx, idx[good], pos[good, c]) for c in range(3)], 1)
    q = quat.copy()
    q[bad] = np.nan
    # nearest good quaternion fills gaps (those samples are flagged invalid anyway)
    near = np.searchsorted(idx[good], idx).clip(0, good.sum() - 1)
    q = np.where(bad[:, None], quat[good][near], quat)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    # hemisphere continuity
    sgn = np.sign(np.sum(q[1:] * q[:-1], axis=1))
    sgn = np.concatenate([[1.0], np.cumprod(np.where(sgn == 0, 1.0, sgn))])
    q = q * sgn[:, None]
    r = np.asarray(matrix_from_quat(q))
    rel = np.einsum("nji,njk->nik", r[:-1], r[1:])  # R_n^T R_{n+1}
    w_mid = np.asarray(log_so3(rel)) / dt  # rate at t_n + dt/2
    w = np.empty_like(pos_f)
    w[1:-1] = 0.5 * (w_mid[1:] + w_mid[:-1])
    w[0], w[-1] = w_mid[0], w_mid[-1]
    h0, h1, h2 = gaussian_kernels(sigma, dt)
    half = (len(h0) - 1) // 2
    w_s = _conv(w, h0)
    wdot = _conv(w, h1)
    # specific force in two stages, so that it is smoothed in the body frame like the sensor's
    # output: the world acceleration with a short kernel (sigma1), rotated into the body frame
    # sample by sample, then the rest of the smoothing (sigma2, sigma1^2 + sigma2^2 = sigma^2) in
    # the body frame. Smoothing in the world frame and rotating afterwards differs from what the
    # sensor's smoothed output holds by about sigma^2 w x da/dt, a rotation-correlated error that
    # a lever arm would absorb (5 cm at sigma = 90 ms on hand-held motion).
    s1 = min(sigma, FIRST_STAGE_SIGMA)
    g1, _, g1_2 = gaussian_kernels(s1, dt)
    a_world = _conv(pos_f, g1_2)
    f1 = _conv(r[:, 2, :], g1) + np.einsum("nji,nj->ni", r, a_world / G0)
    s2 = float(np.sqrt(max(sigma**2 - s1**2, 0.0)))
    stage2 = (lambda x: _conv(x, gaussian_kernels(s2, dt)[0])) if s2 > 0.25 * dt else (lambda x: x)
    f = stage2(f1)
    # the centripetal operator [w]x[w]x = w w^T - |w|^2 I, smoothed as a product in the same two stages
    w1 = _conv(w, g1)
    ww = stage2((w1[:, :, None] * w1[:, None, :]).reshape(-1, 9))
    ww = ww.reshape(-1, 3, 3)
    ww = ww - np.trace(ww, axis1=1, axis2=2)[:, None, None] * np.eye(3)
    half = max(half, int(np.ceil(4.0 * (s1 + s2) / dt)))  # support of the two-stage kernel
    valid = _gap_mask(bad, half + 1)
    valid[: half + 1] = False
    valid[-half - 1 :] = False
    return {"gyr_ref": w_s, "wdot_ref": wdot, "acc_ref": f, "ww_ref": ww, "valid": valid}


def reference_gap_mask(t: np.ndarray, t_track: np.ndarray, max_gap: float = 1.5, max_dist: float = 1.1) -> np.ndarray:
    """(N,) bool: True where a reference interpolated from a track sampled at ``t_track`` is
    trustworthy at the times ``t``.

    False outside the track, inside a gap between track samples longer than ``max_gap`` x the
    track's median interval, or farther than ``max_dist`` x that interval from the nearest track
    sample. A slerp across a missing mocap sample at fast rotation is wrong by much more than the
    mocap noise, and a derivative of it is worse; readers interpolate over short gaps (they keep the
    track as ``gt_t``), so diagnosis re-marks them from the track's own times.

    Args:
        t: (N,) query times (s).
        t_track: (M,) times of the track's samples (s).
        max_gap: longest trusted gap, in median track intervals.
        max_dist: farthest trusted distance from a track sample, in median track intervals.
    """
    t = np.asarray(t, np.float64)
    tt = np.asarray(t_track, np.float64)
    if len(tt) < 2:
        return np.zeros(len(t), bool)
    d = float(np.median(np.diff(tt)))
    j = np.clip(np.searchsorted(tt, t), 1, len(tt) - 1)
    dist = np.minimum(np.abs(tt[j] - t), np.abs(tt[j - 1] - t))
    ok = ((tt[j] - tt[j - 1]) <= max_gap * d) & (dist <= max_dist * d)
    return ok & (t >= tt[0]) & (t <= tt[-1])
