"""Coloured-noise handling: autoregressive prewhitening of residuals and regressors.

Sensor noise is rarely white (bias random walk, flicker, vibration). Least-squares tests that
assume i.i.d. noise then call slow regressors (drift, temperature) significant far too often.
Here each axis's residual is modelled as AR(p), ``e_t = sum_k a_k e_{t-k} + u_t`` with white
``u``; the order is chosen by BIC on a ladder up to ``max_order`` (long orders approximate a random
walk under white noise). Applying the filter ``A(z) = 1 - sum a_k z^-k`` and dividing by ``sd(u)``
to the residual and to every regressor turns generalised least squares into ordinary least
squares with unit-variance noise, so ``delta RSS`` statistics are chi-square under the null.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.signal import lfilter

ORDERS = (0, 1, 2, 4, 8, 16, 32, 64)


class ARModel(NamedTuple):
    """Per-axis AR filter: ``a`` (p,) coefficients, ``sigma`` innovation sd, ``order`` p."""

    a: np.ndarray
    sigma: float
    order: int


def _lag_matrix(e: np.ndarray, p: int) -> np.ndarray:
    n = len(e)
    out = np.zeros((n, p))
    for k in range(1, p + 1):
        out[k:, k - 1] = e[:-k]
    return out


def row_ok(valid: np.ndarray, p: int) -> np.ndarray:
    """True at samples ``t`` whose whole filter window ``t-p .. t`` is valid."""
    bad = (~valid).astype(float)
    return lfilter(np.ones(p + 1), 1.0, bad) == 0


def fit_ar(e: np.ndarray, valid: np.ndarray, max_order: int = 64) -> ARModel:
    """Fit AR(p) to one residual axis by least squares, ``p`` chosen by BIC.

    Args:
        e: (N,) residual (physical units).
        valid: (N,) bool, samples that may be used (filter windows must lie inside).
        max_order: largest order tried.
    """
    e = np.asarray(e, np.float64)
    orders = [p for p in ORDERS if p <= max_order]
    pmax = orders[-1]
    rows = row_ok(valid, pmax)
    lag = _lag_matrix(np.where(valid, e, 0.0), pmax)[rows]
    y = e[rows]
    n = len(y)
    if n < 4 * pmax + 10:
        return ARModel(np.zeros(0), float(np.std(e[valid]) + 1e-30), 0)
    gram = lag.T @ lag
    rhs = lag.T @ y
    yy = float(y @ y)
    best = None
    for p in orders:
        if p == 0:
            a = np.zeros(0)
            rss = yy
        else:
            a = np.linalg.solve(gram[:p, :p] + 1e-12 * np.trace(gram[:p, :p]) / p * np.eye(p), rhs[:p])
            rss = yy - 2 * a @ rhs[:p] + a @ gram[:p, :p] @ a
        rss = max(rss, 1e-300)
        bic = n * np.log(rss / n) + p * np.log(n)
        if best is None or bic < best[0]:
            best = (bic, a, np.sqrt(rss / max(n - p, 1)), p)
    return ARModel(best[1], float(best[2]), int(best[3]))


def apply_filter(x: np.ndarray, ar: ARModel) -> np.ndarray:
    """Whiten an (N, ...) array along axis 0: ``(x_t - sum_k a_k x_{t-k}) / sigma``."""
    b = np.concatenate([[1.0], -ar.a])
    return lfilter(b, 1.0, np.asarray(x, np.float64), axis=0) / ar.sigma


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
