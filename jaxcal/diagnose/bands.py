"""One effect estimated in separate frequency bands: does the recording agree with itself?

A constant effect (a time offset, a lever arm) predicts the same parameter in every frequency band
of the motion. Where the residual holds physics the model lacks, the bands disagree: without a
reference, the translational acceleration of a hand-held recording correlates with the rotation
and pulls each band's estimate its own way, and an accelerometer and a gyroscope behind different
on-chip low-pass filters are offset by a delay that depends on frequency. The model's own standard
error cannot see either (it treats the residual as noise); the spread of the band estimates can.

:func:`band_estimates` regresses the band-passed residual on the band-passed regressors (all
columns, so the baseline stays profiled out) in each band, with a cluster-robust (time-block)
covariance; :func:`random_effects` pools the bands per parameter (DerSimonian-Laird) into an
estimate whose standard error includes the between-band variance ``tau2``. With one consistent
effect ``tau2`` is ~0 and the pooled standard error is the bands' combined one; with a misspecified
model it grows with the disagreement. Pure numpy/scipy; ``results/field_diagnose.md`` measures it on
BROAD, whose mocap says what the reference-free mode should find.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.signal import butter, sosfiltfilt

__all__ = ["BAND_EDGES_HZ", "BandCheck", "band_pass", "band_estimates", "random_effects", "band_check"]

BAND_EDGES_HZ = (0.2, 1.0, 2.0, 4.0, 8.0, 16.0)  # octave-ish bands of hand motion


class BandCheck(NamedTuple):
    """Per-band estimates of some parameters and their pooled (random-effects) value.

    ``bands``: (B, 2) edges (Hz) of the bands used; ``est``/``se``: (B, P) each band's estimate and
    cluster-robust standard error; ``pooled``/``pooled_se``: (P,) the random-effects estimate and its
    standard error; ``tau2``: (P,) between-band variance; ``q``: (P,) Cochran's Q; ``dof``: bands - 1.
    """

    bands: np.ndarray
    est: np.ndarray
    se: np.ndarray
    pooled: np.ndarray
    pooled_se: np.ndarray
    tau2: np.ndarray
    q: np.ndarray
    dof: int


def band_pass(x: np.ndarray, lo: float, hi: float, dt: float) -> np.ndarray:
    """Zero-phase 4th-order Butterworth band-pass of ``x`` along axis 0 (uniform samples ``dt`` s).

    Zero phase matters: a filter delay would itself read as a time offset.
    """
    sos = butter(4, [lo, hi], btype="bandpass", fs=1.0 / dt, output="sos")
    return sosfiltfilt(sos, x, axis=0)


def _cluster_cov(X: np.ndarray, r: np.ndarray, block: np.ndarray) -> np.ndarray:
    """``H^-1 (K/(K-1) sum_k g_k g_k^T) H^-1`` with ``g_k`` the score of block ``k`` (rows of ``X``)."""
    H = X.T @ X
    Hi = np.linalg.pinv(H)
    ks = np.unique(block)
    g = np.stack([X[block == k].T @ r[block == k] for k in ks])
    g = g - g.mean(0)
    kk = len(ks)
    return Hi @ (g.T @ g) @ Hi * (kk / max(kk - 1, 1))


def band_estimates(X: np.ndarray, z: np.ndarray, rows: np.ndarray, block: np.ndarray, dt: float, cols: list[int],
                   edges: tuple[float, ...] = BAND_EDGES_HZ, min_blocks: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each band's update of the parameters ``cols`` from the residual ``z`` (B, P), its standard error,
    and the bands used.

    Args:
        X: (N, 3, Q) regressors of every parameter at the current estimate, on uniform time samples.
        z: (N, 3) residual at the current estimate.
        rows: (N,) bool, the rows that count (the band-pass runs over all samples first).
        block: (N,) int time block of each row, for the cluster-robust covariance.
        dt: sample period (s).
        cols: the columns whose estimates are compared.
        edges: band edges (Hz); bands reaching the Nyquist frequency are dropped.
        min_blocks: bands need rows in at least this many blocks.

    Returns:
        ``(est (B, P), se (B, P), bands (B, 2))``; ``est`` is the update (add the current estimate).
    """
    n, _, q = X.shape
    nyq = 0.5 / dt
    est, se, used = [], [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        if hi >= 0.95 * nyq:
            break
        Xb = band_pass(X.reshape(n, -1), lo, hi, dt).reshape(n, 3, q)[rows].reshape(-1, q)
        zb = band_pass(z, lo, hi, dt)[rows].reshape(-1)
        bb = np.repeat(np.asarray(block)[rows], 3)
        if len(np.unique(bb)) < min_blocks:
            continue
        beta, *_ = np.linalg.lstsq(Xb, zb, rcond=None)
        cov = _cluster_cov(Xb, zb - Xb @ beta, bb)
        est.append(beta[cols])
        se.append(np.sqrt(np.maximum(np.diag(cov)[cols], 0.0)))
        used.append((lo, hi))
    return np.asarray(est, float).reshape(-1, len(cols)), np.asarray(se, float).reshape(-1, len(cols)), np.asarray(used, float).reshape(-1, 2)


def random_effects(est: np.ndarray, se: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """DerSimonian-Laird pooling per column: ``(pooled, pooled_se, tau2, Q)``.

    Args:
        est: (B, P) estimates; se: (B, P) their standard errors (non-finite or 0: band left out).
    """
    est, se = np.atleast_2d(est), np.atleast_2d(se)
    p = est.shape[1]
    out = np.full((4, p), np.nan)
    for j in range(p):
        ok = np.isfinite(est[:, j]) & np.isfinite(se[:, j]) & (se[:, j] > 0)
        if ok.sum() == 0:
            continue
        y, v = est[ok, j], se[ok, j] ** 2
        w = 1.0 / v
        ybar = np.sum(w * y) / np.sum(w)
        q = float(np.sum(w * (y - ybar) ** 2))
        c = np.sum(w) - np.sum(w**2) / np.sum(w)
        tau2 = max(0.0, (q - (ok.sum() - 1)) / c) if c > 0 else 0.0
        ws = 1.0 / (v + tau2)
        out[:, j] = (np.sum(ws * y) / np.sum(ws), np.sqrt(1.0 / np.sum(ws)), tau2, q)
    return out[0], out[1], out[2], out[3]


def band_check(X: np.ndarray, z: np.ndarray, rows: np.ndarray, block: np.ndarray, dt: float, cols: list[int],
               current: np.ndarray, edges: tuple[float, ...] = BAND_EDGES_HZ) -> BandCheck:
    """:func:`band_estimates` then :func:`random_effects`, as estimates (``current`` + update).

    Args:
        X, z, rows, block, dt, cols, edges: as :func:`band_estimates`.
        current: (P,) the current estimate of the parameters ``cols``.
    """
    est, se, bands = band_estimates(X, z, rows, block, dt, cols, edges)
    est = est + np.asarray(current, float)[None, :]
    pooled, pooled_se, tau2, q = random_effects(est, se)
    return BandCheck(bands, est, se, pooled, pooled_se, tau2, q, max(len(bands) - 1, 0))
