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
model it grows with the disagreement. :func:`pool_named` applies it to the named effects of a
joint refit (the reference-free mode's time offset and lever arm): each interval widens by the
between-band spread, ``se^2 + tau2``, so an estimate that the bands contradict is neither named
with false confidence nor hidden (``results/field_diagnose.md`` measures it on BROAD, whose mocap
says what the reference-free mode should find). Host-side numpy/scipy, plus one forward-mode
Jacobian of the model (:func:`jaxcal.diagnose.effects.regressors`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from scipy.signal import butter, sosfiltfilt

from jaxcal.diagnose import effects as E
from jaxcal.diagnose.refit import RefitResult, scaled_inv
from jaxcal.precision import float64

__all__ = ["BAND_EDGES_HZ", "BandCheck", "band_pass", "band_estimates", "random_effects", "band_check", "time_clusters",
           "candidate_spread", "widen_information", "pool_named"]

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


def _inflate(fit: RefitResult, idx: np.ndarray, se_new: np.ndarray) -> RefitResult:
    """``fit`` with the standard errors of theta entries ``idx`` raised to ``se_new`` (the
    covariance's rows and columns scaled alike, so its correlations stay)."""
    se = np.asarray(fit.se_theta, float).copy()
    scale = np.ones(len(fit.beta) + len(se))
    old = se[idx]
    scale[len(fit.beta) + idx] = np.divide(se_new, old, out=np.ones_like(se_new), where=old > 0)
    se[idx] = se_new
    cov = None if fit.cov is None else fit.cov * scale[:, None] * scale[None, :]
    return fit._replace(se_theta=se, cov=cov)


def time_clusters(inp: E.Inputs, cluster_s: float = 2.0) -> np.ndarray:
    """(N,) ids of contiguous ``cluster_s``-second time clusters (see :func:`pool_named`)."""
    tc = np.asarray(inp.tc, float)
    return np.floor((tc - tc[0]) / cluster_s).astype(int)


def candidate_spread(x: np.ndarray, z: np.ndarray, rows: np.ndarray, inp: E.Inputs, base: list[int], cols: list[int],
                     edges: tuple[float, ...] = BAND_EDGES_HZ, cluster_s: float = 2.0) -> np.ndarray:
    """(len(cols),) between-band variance ``tau2`` of a candidate effect before it is named: its
    columns ``cols`` and the baseline's ``base`` of the linearised regressors ``x`` (N, 3, Q),
    band by band against the baseline residual ``z`` (N, 3). It is what :func:`pool_named` would
    add to the candidate's interval, so a minimum detectable size counts it too
    (:func:`widen_information`). Zeros where fewer than two bands have data."""
    X = np.asarray(x, float)[:, :, list(base) + list(cols)]
    z = np.asarray(z, float)
    ok = np.asarray(rows, bool) & np.isfinite(X).all((1, 2)) & np.isfinite(z).all(1)
    X, z = np.where(np.isfinite(X), X, 0.0), np.where(np.isfinite(z), z, 0.0)
    nb = len(base)
    bc = band_check(X, z, ok, time_clusters(inp, cluster_s), float(inp.dt), list(range(nb, nb + len(cols))), np.zeros(len(cols)), edges)
    return np.zeros(len(cols)) if bc.dof < 1 else np.nan_to_num(bc.tau2)


def widen_information(F: np.ndarray, tau2: np.ndarray) -> np.ndarray:
    """The Fisher information ``(F^-1 + diag(tau2))^-1``: a group's information once the between-band
    variance is in its covariance, as :func:`pool_named` puts it into the interval."""
    tau2 = np.asarray(tau2, float)
    if not np.any(tau2 > 0):
        return F
    return scaled_inv(scaled_inv(F) + np.diag(tau2))


@float64
def pool_named(kind: str, sensor: str, inp: E.Inputs, rows: np.ndarray, fit: RefitResult, order: list[str],
               pool: tuple[str, ...], edges: tuple[float, ...] = BAND_EDGES_HZ, cluster_s: float = 2.0) -> tuple[RefitResult, dict]:
    """Widen the intervals of the named effects in ``pool`` by their between-band variance.

    The regressors of the baseline and every named effect at the refit's estimate (forward-mode
    Jacobian of the model) and the refit's physical residual go through :func:`band_check`; each
    pooled parameter's standard error becomes ``sqrt(se^2 + tau2)``. With one consistent effect
    ``tau2`` is ~0 and nothing changes; where the bands disagree the interval covers their spread.

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sensor: ``"acc"`` or ``"gyr"``.
        inp: the reference signals (uniform samples).
        rows: (N,) bool, the fit rows.
        fit: the joint refit of the baseline and ``order``.
        order: the named effects.
        pool: the effects whose intervals are pooled over bands.
        edges: band edges (Hz).
        cluster_s: length (s) of the contiguous time clusters of the band errors. Many short
            clusters, not the few cross-validation folds: a cluster-robust error from ~5 clusters
            is itself so uncertain that chance disagreement between bands reads as heterogeneity
            (measured on a simulated constant delay: 5 fold clusters doubled its interval).

    Returns:
        ``(fit with widened se_theta / cov, {effect: {"bands_hz", "est", "se", "pooled", "pooled_se",
        "tau2", "q", "se_refit"}})``; unchanged and ``{}`` where nothing in ``order`` is pooled or
        fewer than two bands have data.
    """
    names = [n for n in order if n in pool]
    if not names:
        return fit, {}
    # the compiled linearisation of the selection stage (its residual is not used here: the refit's is)
    jb, jt, _ = E.linearized(kind, sensor, jnp.asarray(fit.beta, jnp.float64), jnp.asarray(fit.theta, jnp.float64), E.as_jax(inp),
                             jnp.zeros(np.shape(fit.resid), jnp.float64))
    active = np.flatnonzero(E.effect_mask(sensor, order) > 0)
    X = np.concatenate([np.asarray(jb), np.asarray(jt)[:, :, active]], axis=2)
    z = np.asarray(fit.resid, float)
    ok = np.asarray(rows, bool) & np.isfinite(X).all((1, 2)) & np.isfinite(z).all(1)
    X, z = np.where(np.isfinite(X), X, 0.0), np.where(np.isfinite(z), z, 0.0)
    nb = X.shape[2] - len(active)
    pos = {int(q): nb + k for k, q in enumerate(active)}
    idx = np.concatenate([np.arange(E.slot(sensor, n).start, E.slot(sensor, n).start + E.slot(sensor, n).size) for n in names])
    bc = band_check(X, z, ok, time_clusters(inp, cluster_s), float(inp.dt), [pos[int(q)] for q in idx], np.asarray(fit.theta, float)[idx], edges)
    if bc.dof < 1:
        return fit, {}
    tau2 = np.nan_to_num(bc.tau2)
    se_refit = np.asarray(fit.se_theta, float)[idx]
    out, info, k = _inflate(fit, idx, np.sqrt(se_refit**2 + tau2)), {}, 0
    for n in names:
        m = E.slot(sensor, n).size
        sl = slice(k, k + m)
        info[n] = {"bands_hz": bc.bands.tolist(), "est": bc.est[:, sl].tolist(), "se": bc.se[:, sl].tolist(),
                   "pooled": bc.pooled[sl].tolist(), "pooled_se": bc.pooled_se[sl].tolist(), "tau2": tau2[sl].tolist(),
                   "q": bc.q[sl].tolist(), "se_refit": se_refit[sl].tolist()}
        k += m
    return out, info
