"""Coloured-noise handling: autoregressive prewhitening of residuals and regressors.

Sensor noise is rarely white (bias random walk, flicker, vibration). Least-squares tests that
assume i.i.d. noise then call slow regressors (drift, temperature) significant far too often.
Each axis's residual is modelled in two stages:

1. a bias random walk under white noise (local-level model), whose innovations form an IMA(1,1)
   process: ``(1 - L) e_t = (1 - th L) v_t``. ``th`` (1 = no random walk) is chosen by
   conditional least squares on a grid plus BIC; the filter ``(1 - L) / (1 - th L)`` (with the
   first difference started at zero) removes the random walk;
2. AR(p) on what is left, ``v_t = sum_k a_k v_{t-k} + u_t``, order by BIC up to ``max_order``.

Applying both filters and dividing by ``sd(u)`` to the residual and to every regressor turns
generalised least squares into ordinary least squares with unit-variance noise, so ``delta RSS``
statistics are chi-square under the null. Rows within the filter's memory after a gap are
dropped (:func:`row_ok` with ``ARModel.memory``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.signal import lfilter

ORDERS = (0, 1, 2, 4, 8, 16, 32, 64)


THETAS = (1.0, 0.9995, 0.999, 0.998, 0.995, 0.99, 0.98, 0.95, 0.9, 0.8)


class ARModel(NamedTuple):
    """Per-axis noise filter: ``a`` (p,) AR coefficients, ``sigma`` innovation sd, ``order`` p,
    ``theta`` IMA coefficient (1.0: no random walk), ``memory`` samples a gap contaminates."""

    a: np.ndarray
    sigma: float
    order: int
    theta: float = 1.0
    memory: int = 0


def _ima(x: np.ndarray, theta: float) -> np.ndarray:
    """``(1 - L) / (1 - theta L)`` along axis 0, first difference started at zero."""
    if theta >= 1.0:
        return x
    d = np.diff(x, axis=0, prepend=x[:1])
    return lfilter([1.0], [1.0, -theta], d, axis=0)


def _ima_memory(theta: float) -> int:
    if theta >= 1.0:
        return 0
    return int(min(np.ceil(np.log(1e-2) / np.log(theta)), 500))


def _lag_matrix(e: np.ndarray, p: int) -> np.ndarray:
    n = len(e)
    out = np.zeros((n, p))
    for k in range(1, p + 1):
        out[k:, k - 1] = e[:-k]
    return out


def row_ok(valid: np.ndarray, p: int) -> np.ndarray:
    """True at samples ``t`` whose whole filter window ``t-p .. t`` is valid."""
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
    invalid stretches are not gaps: held values make them harmless)."""
    valid = np.asarray(valid, bool)
    if not valid.any():
        return valid
    i0, i1 = int(np.argmax(valid)), len(valid) - int(np.argmax(valid[::-1]))
    inner = valid.copy()
    inner[:i0] = True
    inner[i1:] = True
    return valid & row_ok(inner, memory)


def _ima_theta(x: np.ndarray) -> float:
    """IMA(1,1) coefficient of the local-level model fitted to the Allan variance of ``x``."""
    n = len(x)
    if n < 200:
        return 1.0
    cs = np.concatenate([[0.0], np.cumsum(x - x.mean())])
    ms, av = [], []
    m = 1
    while 4 * m <= n // 2:
        d = cs[2 * m :] - 2 * cs[m:-m] + cs[: -2 * m]
        av.append(np.mean(d * d) / (2.0 * m * m))
        ms.append(m)
        m *= 2
    ms, av = np.array(ms, float), np.array(av)
    A = np.stack([1.0 / ms, ms / 3.0], 1) / av[:, None]
    r, q = np.linalg.lstsq(A, np.ones_like(av), rcond=None)[0]
    if not (q > 0 and r > 0) or q * ms[-1] / 3.0 < 0.25 * r / ms[-1]:
        return 1.0  # no random walk, or one far below the white level even at the longest averaging time
    lam = q / r
    return float(np.clip(1.0 + lam / 2.0 - np.sqrt(lam + lam * lam / 4.0), 0.0, 0.99995))


def fit_ar(e: np.ndarray, valid: np.ndarray, max_order: int = 64, max_theta: float = 1.0) -> ARModel:
    """Fit AR(p) to one residual axis by least squares, ``p`` chosen by BIC.

    Args:
        e: (N,) residual (physical units).
        valid: (N,) bool, samples that may be used (filter windows must lie inside).
        max_order: largest order tried.
        max_theta: upper bound on the IMA coefficient (pass the baseline residual's value so a
            slow effect fitted in an earlier pass cannot hide a random walk that mimics it).
    """
    e = np.asarray(e, np.float64)
    # stage 1: random walk under white noise. Its Allan variance at averaging m samples is
    # r/m + q m/3 (r: white variance, q: random-walk increment variance per sample); fit (r, q)
    # by weighted least squares on octave-spaced m, then theta of the equivalent IMA(1,1).
    ev = e[fill_index(valid)]
    ok = gap_ok(valid, 64)
    theta = min(_ima_theta(ev[ok]), max_theta)
    best_th = (0.0, theta)
    theta = 1.0 if best_th is None else best_th[1]
    mem = _ima_memory(theta)
    valid = gap_ok(valid, mem) if theta < 1 else valid
    e = _ima(ev, theta)
    orders = [p for p in ORDERS if p <= max_order]
    pmax = orders[-1]
    rows = gap_ok(valid, pmax)
    lag = _lag_matrix(e, pmax)[rows]
    y = e[rows]
    n = len(y)
    if n < 4 * pmax + 10:
        return ARModel(np.zeros(0), float(np.std(e[valid]) + 1e-30), 0, theta, mem)
    gram = lag.T @ lag
    rhs = lag.T @ y
    yy = float(y @ y)
    best = None
    for p in orders:
        if p == 0:
            a = np.zeros(0)
            rss = yy
        else:
            a = np.linalg.lstsq(gram[:p, :p] + (1e-12 * np.trace(gram[:p, :p]) / p + 1e-300) * np.eye(p), rhs[:p], rcond=None)[0]
            rss = yy - 2 * a @ rhs[:p] + a @ gram[:p, :p] @ a
        rss = max(rss, 1e-300)
        bic = n * np.log(rss / n) + p * np.log(n)
        if best is None or bic < best[0]:
            best = (bic, a, np.sqrt(rss / max(n - p, 1)), p)
    return ARModel(best[1], float(best[2]), int(best[3]), theta, mem + int(best[3]))


def apply_filter(x: np.ndarray, ar: ARModel) -> np.ndarray:
    """Whiten an (N, ...) array along axis 0: IMA stage, then ``(v_t - sum_k a_k v_{t-k}) / sigma``."""
    b = np.concatenate([[1.0], -ar.a])
    return lfilter(b, 1.0, _ima(np.asarray(x, np.float64), ar.theta), axis=0) / ar.sigma


def ljung_box(u: np.ndarray, lags: int = 20) -> float:
    """Ljung-Box Q statistic of a residual series (chi2 with ``lags`` dof if white)."""
    u = np.asarray(u, np.float64) - np.mean(u)
    n = len(u)
    den = float(u @ u) + 1e-300
    q = 0.0
    for k in range(1, lags + 1):
        rho = float(u[k:] @ u[:-k]) / den
        q += rho * rho / (n - k)
    return float(n * (n + 2) * q)
