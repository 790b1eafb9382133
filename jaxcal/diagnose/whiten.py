"""Coloured-noise handling: autoregressive prewhitening of residuals and regressors.

Sensor noise is rarely white (bias random walk, flicker, vibration). Least-squares tests that
assume i.i.d. noise then call slow regressors (drift, temperature) significant far too often.
Each axis's residual is modelled in two stages:

1. a bias random walk under white noise (local-level model, random-walk to white variance ratio
   ``lam`` per sample; ``lam = 0``: none). The exact innovations of its Kalman filter with a
   diffuse initial level (:func:`ll_innovations`) whiten it; their steady state is the IMA(1,1)
   ``(1 - L) e_t = (1 - theta L) v_t``. ``lam`` is chosen by restricted maximum likelihood
   (:func:`reml_profile`) with the regressors that will be tested, pooled over the axes of a sensor
   and taken at the upper end of its profile interval (:func:`choose_lambda`): a short recording
   cannot tell a slow effect from a random walk, and tests must not assume it can;
2. AR(p) on what is left, ``v_t = sum_k a_k v_{t-k} + u_t``, order by BIC up to ``max_order``.

Applying both filters and dividing by ``sd(u)`` to the residual and to every regressor turns
generalised least squares into ordinary least squares with unit-variance noise, so ``delta RSS``
statistics are chi-square under the null. Rows within the filter's memory after a gap are
dropped (:func:`row_ok` with ``ARModel.memory``).
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np
from scipy.signal import lfilter

__all__ = [
    "ORDERS",
    "ARModel",
    "row_ok",
    "fill_index",
    "gap_ok",
    "LAMBDAS",
    "local_level_gains",
    "ll_innovations",
    "reml_profile",
    "usable_lambdas",
    "theta_of",
    "choose_lambda",
    "fit_ar",
    "apply_filter",
    "ljung_box",
]

ORDERS = (0, 1, 2, 4, 8, 16, 32, 64)


class ARModel(NamedTuple):
    """Per-axis noise filter: ``a`` (p,) AR coefficients, ``sigma`` innovation sd, ``order`` p,
    ``theta`` steady-state IMA coefficient (1.0: no random walk), ``memory`` samples a gap
    contaminates, ``lam`` random-walk to white variance ratio per sample (0: none)."""

    a: np.ndarray
    sigma: float
    order: int
    theta: float = 1.0
    memory: int = 0
    lam: float = 0.0


def _ima_memory(theta: float) -> int:
    if theta >= 1.0:
        return 0
    return int(min(np.ceil(np.log(1e-2) / np.log(theta)), 500))


def _lambda_memory(lam: float) -> int:
    """:func:`_ima_memory` of the random-walk level ``lam``."""
    return _ima_memory(theta_of(float(lam)))


def _lag_matrix(e: np.ndarray, p: int) -> np.ndarray:
    n = len(e)
    out = np.zeros((n, p))
    for k in range(1, p + 1):
        out[k:, k - 1] = e[:-k]
    return out


def _ar_by_bic(u: np.ndarray, rows: np.ndarray, orders: list[int]) -> tuple[np.ndarray, float, int]:
    """AR coefficients of ``u`` fitted on ``rows`` by least squares, order by BIC over ``orders``;
    returns ``(a (p,), residual sum of squares, p)``."""
    lag = _lag_matrix(u, orders[-1])[rows]
    y = u[rows]
    n = len(y)
    gram, rhs, yy = lag.T @ lag, lag.T @ y, float(y @ y)
    best = None
    for p in orders:
        if p == 0:
            a, rss = np.zeros(0), yy
        else:
            a = np.linalg.lstsq(gram[:p, :p] + (1e-12 * np.trace(gram[:p, :p]) / p + 1e-300) * np.eye(p), rhs[:p], rcond=None)[0]
            rss = yy - 2 * a @ rhs[:p] + a @ gram[:p, :p] @ a
        rss = max(rss, 1e-300)
        bic = n * np.log(rss / n) + p * np.log(n)
        if best is None or bic < best[0]:
            best = (bic, a, rss, p)
    return best[1], float(best[2]), int(best[3])


def row_ok(valid: np.ndarray, p: int) -> np.ndarray:
    """True at samples ``t`` whose whole filter window ``t-p .. t`` is valid.

    Args:
        valid: (N,) bool.
        p: filter order (window ``t-p .. t``).
    """
    c = np.concatenate([[0], np.cumsum(~np.asarray(valid, bool))])
    n = len(valid)
    lo = np.maximum(np.arange(n) - p, 0)
    return (c[np.arange(n) + 1] - c[lo]) == 0


def fill_index(valid: np.ndarray) -> np.ndarray:
    """Index of the sample that fills each position: itself if valid, else the last valid sample
    before it (the first valid one for leading positions). Filling by holding values makes the
    first difference zero across leading/trailing invalid stretches."""
    valid = np.asarray(valid, bool)
    idx = np.where(valid, np.arange(len(valid)), -1)
    idx = np.maximum.accumulate(idx)
    first = int(np.argmax(valid)) if valid.any() else 0
    return np.where(idx < 0, first, idx)


def gap_ok(valid: np.ndarray, memory: int) -> np.ndarray:
    """Valid samples not within ``memory`` samples after an interior gap (leading/trailing
    invalid stretches are not gaps: held values make them harmless).

    Args:
        valid: (N,) bool.
        memory: samples a gap contaminates (:attr:`ARModel.memory`).
    """
    valid = np.asarray(valid, bool)
    if not valid.any():
        return valid
    i0, i1 = int(np.argmax(valid)), len(valid) - int(np.argmax(valid[::-1]))
    inner = valid.copy()
    inner[:i0] = True
    inner[i1:] = True
    return valid & row_ok(inner, memory)


LAMBDAS = (0.0,) + tuple(float(x) for x in 10.0 ** np.arange(-11.0, -1.99, 0.5))


def _p_inf(lam: float) -> float:
    """Steady-state predicted level variance (units of the white variance) of the local-level model."""
    return 0.5 * (lam + np.sqrt(lam * lam + 4.0 * lam))


@lru_cache(maxsize=256)
def local_level_gains(lam: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Kalman gains ``K`` (n,) and innovation sd factors ``sf`` (n,) of the local-level model
    ``x_t = mu_t + e_t``, ``mu_t = mu_{t-1} + w_t`` (``var w / var e = lam``) with a diffuse
    initial level, in units of the white sd. Sample 0 only initialises the level (``sf[0] = inf``).

    ``lam = 0`` (no random walk) gives ``K_t = 1/(t+1)``, ``sf_t^2 = 1 + 1/t``: the recursive
    residuals of a constant mean. The gains converge to ``1 - theta`` of the IMA(1,1) form.

    Args:
        lam: random-walk to white variance ratio per sample.
        n: number of samples.
    """
    K = np.empty(n)
    F = np.empty(n)
    K[0], F[0] = 1.0, np.inf
    if lam == 0.0:
        t = np.arange(1, n, dtype=np.float64)
        K[1:] = 1.0 / (t + 1.0)
        F[1:] = 1.0 + 1.0 / t
        return K, np.sqrt(F)
    p_inf = _p_inf(lam)
    P = 1.0 + lam
    for t in range(1, n):
        F[t] = P + 1.0
        K[t] = P / F[t]
        P = P / F[t] + lam
        if abs(P - p_inf) < 1e-13 * p_inf:
            F[t + 1 :] = p_inf + 1.0
            K[t + 1 :] = p_inf / (p_inf + 1.0)
            break
    return K, np.sqrt(F)


def ll_innovations(x: np.ndarray, lam: float) -> np.ndarray:
    """Standardised innovations of the diffuse local-level filter along axis 0 (row 0 is 0).

    The level recursion ``m_{t+1} = (1 - K_t) m_t + K_t x_t`` (``m_1 = x_0``) is evaluated in closed
    form (cumulative products) while the gain still varies, then by ``lfilter`` once it is constant.

    Args:
        x: (N, ...) series, filtered along axis 0.
        lam: random-walk to white variance ratio per sample.
    """
    x = np.asarray(x, np.float64)
    n = x.shape[0]
    K, sf = local_level_gains(float(lam), n)
    shp = (n,) + (1,) * (x.ndim - 1)
    m = np.empty_like(x)
    m[0] = 0.0
    if n == 1:
        return np.zeros_like(x)
    # head: t = 1 .. tc-1 with varying K (tc: first index of the constant gain, or n)
    kc = K[-1]
    same = np.isclose(K, kc, rtol=1e-12, atol=0.0)
    same[:2] = False
    tc = n if lam == 0.0 or not same.any() else int(np.argmax(same))
    a = 1.0 - K[1:tc]
    A = np.cumprod(a)  # A_t = prod_{s=1..t} a_s, t = 1..tc-1
    csum = np.cumsum((K[1:tc] / A).reshape((-1,) + (1,) * (x.ndim - 1)) * x[1:tc], axis=0)
    m[1] = x[0]
    if tc > 2:
        m[2:tc] = A[:-1].reshape((-1,) + shp[1:]) * (x[0] + csum[:-1])
    if tc < n:
        m_tc = A[-1] * (x[0] + csum[-1]) if tc > 1 else x[0]
        c = 1.0 - kc
        zi = (c * np.asarray(m_tc))[None]
        out, _ = lfilter([kc], [1.0, -c], x[tc:-1], axis=0, zi=zi) if tc < n - 1 else (np.zeros((0,) + x.shape[1:]), None)
        m[tc] = m_tc
        m[tc + 1 :] = out
    v = (x - m) / sf.reshape(shp)
    v[0] = 0.0
    return v


def _logdet_gram(a: np.ndarray) -> tuple[float, int]:
    """log det of the Gram of the non-degenerate columns of ``a`` (scale-normalised) and their count."""
    nrm = np.sqrt(np.sum(a * a, 0))
    keep = nrm > 1e-9 * max(float(nrm.max()), 1e-300) if a.shape[1] else np.zeros(0, bool)
    if not keep.any():
        return 0.0, 0
    ak = a[:, keep] / nrm[keep]
    sign, ld = np.linalg.slogdet(ak.T @ ak)
    return float(ld + 2.0 * np.sum(np.log(nrm[keep]))), int(keep.sum())


MIN_KEEP = 0.5
"""The least share of the usable rows a random-walk level may leave (:func:`usable_lambdas`)."""


def usable_lambdas(valid: np.ndarray, lams=LAMBDAS, max_order: int = 16, min_keep: float = MIN_KEEP) -> np.ndarray:
    """Which random-walk levels leave at least ``min_keep`` of the usable rows to fit and test on.

    The filters run through a gap on held values, so the rows within their memory after every
    interior gap are dropped (:func:`gap_ok`; about ``log 0.01 / log theta`` samples: 469 at
    ``lam = 1e-4``). A reference with a dropout every few seconds (motion capture losing markers)
    then leaves, for a small ``lam``, only the stretch before the first gap, often a rest: the noise model and every
    test built on it would see that stretch alone (on a stressed BROAD trial it was a 4 mrad/s rest
    noise against 0.14 rad/s over the motion, and the joint refit lost the gyroscope's whole scale).
    Such levels are not offered; ``lam = 0`` (no random-walk stage, no memory) always is.

    Args:
        valid: (N,) bool, usable samples.
        lams: the random-walk levels.
        max_order: the largest AR order (its taps add to the memory).
        min_keep: the least share of ``valid``'s rows a level must keep.

    Returns:
        (len(lams),) bool.
    """
    valid = np.asarray(valid, bool)
    n = max(int(valid.sum()), 1)
    mems = [_lambda_memory(lam) for lam in lams]
    keep = {m: gap_ok(valid, m + max_order).sum() / n for m in set(mems)}
    return np.array([lam == 0.0 or keep[m] >= min_keep for lam, m in zip(lams, mems)])


def reml_profile(e: np.ndarray, valid: np.ndarray, X: np.ndarray | None = None, lams=LAMBDAS, max_order: int = 16) -> np.ndarray:
    """Restricted log-likelihood profile of the random-walk level of a residual, one per ``lams``.

    For each ``lam`` (random-walk to white variance ratio per sample) the residual ``e`` (N,) and
    the regressors ``X`` (N, Q) it will be tested against are passed through the exact diffuse
    local-level filter (:func:`ll_innovations`), then an AR(p) (order by BIC up to
    ``max_order``) on the generalised-least-squares residual; the restricted log-likelihood is
    ``-1/2 [(m - k) log(RSS / (m - k)) + sum log F_t + log det(X_w^T X_w) + p log m]``.
    The ``log det`` term is what keeps slow regressors (drift, temperature) from absorbing a
    random walk and shrinking its estimate, which made ordinary (or residual-based) estimates
    call drift significant on pure random-walk noise. Returns (len(lams),); all ``-inf`` when
    there are too few rows, and ``-inf`` at the levels :func:`usable_lambdas` does not offer (the
    profile is then computed on the rows the longest offered memory leaves).

    Args:
        e: (N,) residual.
        valid: (N,) bool, usable samples.
        X: (N, Q) regressors to be tested; None: none.
        lams: random-walk levels of the profile.
        max_order: largest AR order.
    """
    e = np.asarray(e, np.float64)
    n = len(e)
    fi = fill_index(valid)
    ev = e[fi]
    Xv = np.zeros((n, 0)) if X is None else np.asarray(X, np.float64)[fi]
    nrm = np.sqrt(np.sum(Xv * Xv, 0))
    Xv = Xv[:, nrm > 1e-12 * max(float(nrm.max()) if nrm.size else 0.0, 1e-300)]
    offered = usable_lambdas(valid, lams, max_order)
    # the rows every offered level keeps (without dense gaps: the memory cap, 500 samples)
    mem = max(_lambda_memory(lam) for lam, ok in zip(lams, offered) if ok)
    rows = gap_ok(valid, mem + max_order) & (np.arange(n) > max_order)
    if rows.sum() < 4 * (max_order + Xv.shape[1]) + 50:
        return np.full(len(lams), -np.inf)
    orders = [p for p in ORDERS if p <= max_order]
    prof = np.full(len(lams), -np.inf)
    for j, lam in enumerate(lams):
        if not offered[j]:
            continue
        _, sf = local_level_gains(float(lam), n)
        ew = ll_innovations(ev, lam)
        Xw = ll_innovations(Xv, lam) if Xv.shape[1] else Xv
        # GLS residual under the random-walk stage alone, then its AR order
        if Xw.shape[1]:
            b = np.linalg.lstsq(Xw[rows], ew[rows], rcond=None)[0]
            u = ew - Xw @ b
        else:
            u = ew
        a_ar, _, _ = _ar_by_bic(u, rows, orders)
        taps = np.concatenate([[1.0], -a_ar])
        e2 = lfilter(taps, 1.0, ew)[rows]
        X2 = lfilter(taps, 1.0, Xw, axis=0)[rows] if Xw.shape[1] else np.zeros((int(rows.sum()), 0))
        if X2.shape[1]:
            b2 = np.linalg.lstsq(X2, e2, rcond=None)[0]
            rss2 = float(np.sum((e2 - X2 @ b2) ** 2))
        else:
            rss2 = float(e2 @ e2)
        ld, k = _logdet_gram(X2) if X2.shape[1] else (0.0, 0)
        m = len(e2)
        ll = -0.5 * ((m - k) * np.log(max(rss2, 1e-300) / (m - k)) + 2.0 * np.sum(np.log(sf[rows])) + ld + len(a_ar) * np.log(m))
        prof[j] = ll
    return prof


def theta_of(lam: float) -> float:
    """IMA(1,1) coefficient ``1 - K_inf`` of the local-level model with ratio ``lam`` (1 for 0)."""
    if lam <= 0:
        return 1.0
    p = _p_inf(lam)
    return float(1.0 - p / (p + 1.0))


def choose_lambda(profiles: list[np.ndarray], lams=LAMBDAS, pooled: bool = True, slack: float = 0.0) -> list[float]:
    """Random-walk level per axis from REML profiles (:func:`reml_profile`).

    ``pooled``: one level for all axes of a sensor (profiles summed: three times the information
    when the axes share a noise process). ``slack > 0``: the largest ``lam`` whose profile is
    within ``slack`` of the maximum (the upper end of a profile-likelihood interval; 1.92 is
    about 95 %), a conservative choice for tests of slow effects that a random walk can mimic
    (Berger-Boos: the p-value is maximised over the plausible noise levels).

    Args:
        profiles: per-axis profiles from :func:`reml_profile`, each (len(lams),).
        lams: the levels they were evaluated at.
        pooled: one level for all axes (see above).
        slack: log-likelihood slack (see above); 0 takes the maximum.
    """
    lams = np.asarray(lams)

    def pick(pr):
        if not np.isfinite(pr).any():
            return 0.0
        ok = pr >= np.max(pr) - slack
        return float(lams[ok].max()) if slack > 0 else float(lams[int(np.argmax(pr))])

    if pooled:
        lam = pick(np.sum(profiles, axis=0))
        return [lam] * len(profiles)
    return [pick(p) for p in profiles]


def fit_ar(e: np.ndarray, valid: np.ndarray, max_order: int = 64, X: np.ndarray | None = None, lam: float | None = None) -> ARModel:
    """Noise model of one residual axis: random-walk stage by REML, then AR(p) with ``p`` by BIC.

    Args:
        e: (N,) residual (physical units).
        valid: (N,) bool, samples that may be used (filter windows must lie inside).
        max_order: largest AR order tried.
        X: (N, Q) regressors the residual will be tested against (baseline and candidate
            effects), used by the restricted likelihood of :func:`reml_profile`.
        lam: random-walk level (see :func:`choose_lambda`); estimated from ``e`` alone if None.
    """
    e = np.asarray(e, np.float64)
    ev = e[fill_index(valid)]
    if lam is None:
        lam = choose_lambda([reml_profile(e, valid, X)])[0]
    theta = theta_of(lam)
    mem = _ima_memory(theta)
    valid = gap_ok(valid, mem) if theta < 1 else valid
    e = _stage1(ev, lam)
    orders = [p for p in ORDERS if p <= max_order]
    pmax = orders[-1]
    rows = gap_ok(valid, pmax)
    n = int(rows.sum())
    if n < 4 * pmax + 10:
        return ARModel(np.zeros(0), float(np.std(e[valid]) + 1e-30), 0, theta, mem, lam)
    a, rss, p = _ar_by_bic(e, rows, orders)
    return ARModel(a, float(np.sqrt(rss / max(n - p, 1))), p, theta, mem + p, lam)


def _stage1(x: np.ndarray, lam: float) -> np.ndarray:
    """Random-walk stage: exact diffuse local-level innovations for ``lam > 0``, identity for 0."""
    return ll_innovations(x, lam) if lam > 0 else np.asarray(x, np.float64)


def apply_filter(x: np.ndarray, ar: ARModel) -> np.ndarray:
    """Whiten an (N, ...) array along axis 0: random-walk stage (:func:`ll_innovations`), then
    ``(v_t - sum_k a_k v_{t-k}) / sigma``.

    Args:
        x: (N, ...) array, filtered along axis 0.
        ar: the axis's noise model.
    """
    b = np.concatenate([[1.0], -ar.a])
    return lfilter(b, 1.0, _stage1(x, ar.lam), axis=0) / ar.sigma


def ljung_box(u: np.ndarray, lags: int = 20) -> float:
    """Ljung-Box Q statistic of a residual series (chi2 with ``lags`` dof if white).

    Args:
        u: (N,) residual series.
        lags: autocorrelation lags summed.
    """
    u = np.asarray(u, np.float64) - np.mean(u)
    n = len(u)
    den = float(u @ u) + 1e-300
    q = 0.0
    for k in range(1, lags + 1):
        rho = float(u[k:] @ u[:-k]) / den
        q += rho * rho / (n - k)
    return float(n * (n + 2) * q)
