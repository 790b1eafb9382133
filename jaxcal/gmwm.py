"""GMWM: noise processes of a static log fitted jointly over all cluster times (Guerrier et al. 2013).

The slope-line reading (:func:`jaxcal.allan.fit_noise`) reads each parameter where its line is
supposed to dominate; when two processes overlap there, it is inconsistent (Guerrier, Molinari,
Stebler, IEEE SPL 2016). Here every candidate composite model is fitted to the overlapping Allan
variance (AVAR, twice the Haar wavelet variance) at the dyadic cluster sizes ``m = 1, 2, 4, ...``,
weighted by the inverse of the estimator's covariance, and the model is chosen by the wavelet
variance information criterion (WVIC: the objective plus ``penalty`` per parameter).

Processes, for a rate signal in unit ``u`` sampled at ``fs`` (each by the generalized covariance
``G(h)`` of its phase ``p_k = sum_{i<k} x_i``, h in samples, so every AVAR and covariance below is
exact in discrete time):

========  =====================================  ==================  ================================
name      parameter(s)                           AVAR(tau)           G(h)
========  =====================================  ==================  ================================
``WN``    ``N`` [u/sqrt(Hz)] white noise         ``N^2/tau``         ``-N^2 fs |h| / 2``
``QN``    ``Q`` [u s] quantisation (IEEE 952)    ``3 Q^2/tau^2``     ``(Q fs)^2 [h = 0]``
``BI``    ``B`` [u] bias instability (flicker)   ``(2 ln2/pi) B^2``  ``B^2 h^2 ln|h| / (2 pi)``
``RW``    ``K`` [u/s/sqrt(Hz)] random walk       ``~K^2 tau/3``      ``K^2 (|h|^3 - |h|) / (12 fs)``
``DR``    ``R`` [u/s] rate ramp (deterministic)  ``R^2 tau^2/2``     (mean of the differences)
``GM``    ``sigma_gm`` [u], ``tau_gm`` [s]       first-order Gauss-Markov (AR(1), ``phi = exp(-1/(fs tau_gm))``)
========  =====================================  ==================  ================================

``AVAR(m) = (6 G(0) - 8 G(m) + 2 G(2m)) / (2 m^2)``. The covariance of the AVAR estimates at two
cluster sizes (Gaussian data; :func:`avar_covariance`) is a sum over lags of the squared covariance of
the two second differences, each a 9-term sum of ``G``. Every parameter but ``tau_gm`` enters AVAR
linearly through its square, so a model is fitted by non-negative least squares, profiled over
``tau_gm`` when a Gauss-Markov term is in it. The selected model is refitted to ``log AVAR`` (each
estimate as a scaled chi-square: its skew and small-EDF bias at long cluster times accounted for),
and the intervals are Wald intervals on the log of each parameter.
"""

from __future__ import annotations

from itertools import combinations
from typing import NamedTuple

import numpy as np
from jaxtyping import Float, Int
from scipy.optimize import least_squares, minimize_scalar, nnls
from scipy.special import digamma, polygamma
from scipy.stats import norm

from jaxcal.allan import NoiseParams, overlapping_adev
from jaxcal.arrays import Array

__all__ = [
    "PROCESSES", "PARAMS", "CANDIDATES", "GmwmConfig", "GmwmFit", "dyadic_sizes", "model_avar",
    "avar_covariance", "fit_model", "fit_gmwm", "gmwm_axes", "predicted_halfwidth", "record_length",
    "noise_params", "record_advice", "advice_lines", "fit_json", "quantised_rate",
]

PROCESSES = ("WN", "QN", "BI", "RW", "DR", "GM")
"""The processes, in the order parameters are listed."""

PARAMS = {"WN": ("N",), "QN": ("Q",), "BI": ("B",), "RW": ("K",), "DR": ("R",), "GM": ("sigma_gm", "tau_gm")}
"""Parameter names of each process (units in the module docstring)."""

_BI = 2.0 * np.log(2.0) / np.pi

CANDIDATES = tuple(("WN",) + c for r in range(5) for c in combinations(("QN", "BI", "RW", "DR"), r)) + tuple(
    ("WN",) + c + ("GM",) for r in range(3) for c in combinations(("QN", "RW"), r))
"""The models compared by default: white noise plus any of quantisation, flicker, random walk and rate
ramp (16), and white noise plus a Gauss-Markov term with any of quantisation and random walk (4; a
Gauss-Markov term stands in for bias instability, so the two are not combined)."""


class GmwmConfig(NamedTuple):
    """How :func:`fit_gmwm` fits and selects.

    Args:
        candidates: the models compared, each a tuple of process names; None: :data:`CANDIDATES`.
        penalty: WVIC penalty per parameter. The WVIC's asymptotic optimism is 2 per parameter, but with
            six candidate processes that admits a spurious one too often (``results/noise.md`` counts
            it); 6, near the 99 % point of chi-square(1), asks each added parameter to be significant.
        max_fraction: largest cluster size as a fraction of the samples (``m <= max_fraction N``).
        level: two-sided confidence level of the intervals.
        iterations: refits of each candidate with the covariance at its previous estimate (the first
            fit is weighted by ``1 / AVAR^2``).
        gm_grid: log-spaced ``tau_gm`` values tried before refining: from 2 samples to the largest
            cluster time / 8, so that the Gauss-Markov ADEV's peak (at 1.9 ``tau_gm``) lies about two
            octaves inside the cluster times (a longer one looks like a random walk over the observed
            range, a shorter one like white noise).
    """

    candidates: tuple | None = None
    penalty: float = 6.0
    max_fraction: float = 0.25
    level: float = 0.95
    iterations: int = 2
    gm_grid: int = 32


class GmwmFit(NamedTuple):
    """One axis: the selected model, its parameters with intervals, and what the selection saw.

    Attributes:
        model: the selected processes.
        names: parameter names, in ``PROCESSES`` order.
        value: (P,) estimates (units in the module docstring).
        lo: (P,) lower interval ends.
        hi: (P,) upper interval ends.
        se_log: (P,) standard error of the log of each estimate.
        wvic: ``{"WN+RW": criterion, ...}`` for every candidate.
        objective: the selected model's weighted misfit ``r' V^-1 r``.
        m: (T,) cluster sizes (samples).
        avar: (T,) measured AVAR.
        avar_model: (T,) the selected model's AVAR.
        avar_sd: (T,) standard deviation of the AVAR estimates under the model.
        n: samples in the log.
        fs: sample rate (Hz).
        level: confidence level.
    """

    model: tuple
    names: tuple
    value: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    se_log: np.ndarray
    wvic: dict
    objective: float
    m: np.ndarray
    avar: np.ndarray
    avar_model: np.ndarray
    avar_sd: np.ndarray
    n: int
    fs: float
    level: float

    def get(self, name: str) -> tuple[float, float, float]:
        """``(value, lo, hi)`` of one parameter, NaNs when its process was not selected."""
        if name in self.names:
            i = self.names.index(name)
            return float(self.value[i]), float(self.lo[i]), float(self.hi[i])
        return (np.nan, np.nan, np.nan)


def dyadic_sizes(n: int, max_fraction: float = 0.25) -> Int[np.ndarray, " T"]:
    """Cluster sizes ``1, 2, 4, ...`` up to ``max_fraction * n`` samples (at least 1)."""
    top = max(1, int(max_fraction * n))
    return 2 ** np.arange(int(np.floor(np.log2(top))) + 1)


def _ordered(model) -> tuple:
    return tuple(p for p in PROCESSES if p in model)


def _names(model) -> tuple:
    return tuple(name for p in _ordered(model) for name in PARAMS[p])


def _gm_g(h, tau_gm: float, fs: float):
    """``Var(sum of h consecutive samples) / sigma^2`` of an AR(1), h >= 0 real (expm1 keeps phi near 1 exact)."""
    a = 1.0 / (fs * tau_gm)
    omp = -np.expm1(-a)  # 1 - phi
    phi = 1.0 - omp
    return h + 2.0 * (h * phi * omp + phi * np.expm1(-a * h)) / omp**2


def _unit_gencov(proc: str, h, fs: float, tau_gm: float = 1.0):
    """``G(h)`` of one process with unit variance parameter (``N = Q = B = K = sigma_gm = 1``)."""
    h = np.abs(np.asarray(h, np.float64))
    if proc == "WN":
        return -0.5 * fs * h
    if proc == "QN":
        return fs**2 * (h < 0.5)
    if proc == "BI":
        return np.where(h > 0, h**2 * np.log(np.maximum(h, 1e-300)), 0.0) / (2.0 * np.pi)
    if proc == "RW":
        return (h**3 - h) / (12.0 * fs)
    if proc == "GM":
        return -0.5 * _gm_g(h, tau_gm, fs)
    return np.zeros_like(h)  # DR: deterministic, no covariance


def _unit_avar(proc: str, m, fs: float, tau_gm: float = 1.0):
    m = np.asarray(m, np.float64)
    if proc == "DR":
        return 0.5 * (m / fs) ** 2  # x_k = (R / fs) k: differences of adjacent means R m / fs
    g = lambda h: _unit_gencov(proc, h, fs, tau_gm)  # noqa: E731
    return (6.0 * g(0.0) - 8.0 * g(m) + 2.0 * g(2.0 * m)) / (2.0 * m**2)


def _variances(model, p: dict) -> tuple[tuple, np.ndarray, float]:
    """The processes with a variance parameter, their squared parameters, and tau_gm."""
    key = {"WN": "N", "QN": "Q", "BI": "B", "RW": "K", "DR": "R", "GM": "sigma_gm"}
    procs = _ordered(model)
    return procs, np.array([p[key[q]] ** 2 for q in procs]), float(p.get("tau_gm", 1.0))


def _design(model, m, fs: float, tau_gm: float) -> Float[np.ndarray, "T P"]:
    return np.stack([_unit_avar(q, m, fs, tau_gm) for q in _ordered(model)], axis=1)


def model_avar(model, p: dict, m: Int[Array, " T"], fs: float) -> Float[np.ndarray, " T"]:
    """AVAR of a composite model at cluster sizes ``m`` (exact in discrete time; flicker: exactly constant).

    Args:
        model: process names.
        p: parameters by name (``PARAMS``).
        m: cluster sizes (samples).
        fs: sample rate (Hz).
    """
    procs, v, tau_gm = _variances(model, p)
    return _design(procs, m, fs, tau_gm) @ v


def _pair_nodes(m: int, n: int, km: int, kn: int, tau_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lags, weights and spike flags whose weighted sum is a sum over all integer lags in the pair's support.

    Between breakpoints the summand is smooth: pieces up to 64 lags are enumerated; longer ones are
    integrated (8-point Gauss-Legendre: exact for the polynomial processes, degree 7) with the Euler-Maclaurin
    end correction ``sum_{a<l<b} f = integral - (f(a) + f(b)) / 2 + O(f' / L)``, whose end nodes carry
    flag 0 (there a quantisation spike, at a lag of exactly 0, must not count again). With a
    Gauss-Markov term (``tau_s`` its correlation time in samples, else 0) the pieces are also cut at
    ``tau_s`` x 0.5, 2, 8 from each breakpoint, and the support grows by ``32 tau_s``.
    """
    tail = int(np.ceil(32.0 * tau_s))
    lo, hi = max(-2 * n - tail, -km), min(2 * m + tail, kn)
    base = np.array(sorted({a - b for a in (0, m, 2 * m) for b in (0, n, 2 * n)}), np.float64)
    bps = np.concatenate([base, [lo, hi, 0, kn - km]])
    if tau_s > 0:
        steps = np.round(tau_s * np.array([0.5, 2.0, 8.0]))
        bps = np.concatenate([bps, (base[:, None] + np.concatenate([steps, -steps])[None, :]).ravel()])
    bps = np.unique(bps[(bps >= lo) & (bps <= hi)])
    span = np.diff(bps)
    short = span <= 64
    a, cnt = bps[:-1][short] + 1.0, (span[short] - 1).astype(np.int64)
    inner = np.repeat(a - np.cumsum(cnt) + cnt, cnt) + np.arange(cnt.sum())  # the integers strictly inside
    a, L = bps[:-1][~short], span[~short]
    gl = (a[:, None] + L[:, None] * _GL_X[None, :]).ravel()
    ends = np.concatenate([a, a + L])
    lags = np.concatenate([bps, inner, gl, ends])
    wts = np.concatenate([np.ones(bps.size + inner.size), (L[:, None] * _GL_W[None, :]).ravel(), np.full(ends.size, -0.5)])
    flags = np.concatenate([np.ones(bps.size + inner.size + gl.size), np.zeros(ends.size)])
    return lags, wts, flags


_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_GL_X, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W


class _Lags(NamedTuple):
    """Every cluster-size pair's lag nodes, concatenated (:func:`_pair_nodes`), with what :func:`_cov` needs."""

    m: np.ndarray
    k: np.ndarray
    fs: float
    tau_gm: float
    pair: np.ndarray
    lag: np.ndarray
    weight: np.ndarray
    spike: np.ndarray
    unit: dict


def _lags(m, n_samples: int, fs: float, procs, tau_gm: float = 1.0) -> _Lags:
    """The nodes of all pairs (Gauss-Markov breakpoints when ``GM`` is in ``procs``), and per process the
    unit-variance covariance ``c`` of the two differences of means at each node (a 9-term sum of ``G``)."""
    m = np.asarray(m, np.int64)
    k = n_samples + 1 - 2 * m
    ii, jj = np.triu_indices(m.size)
    nodes = [_pair_nodes(int(m[i]), int(m[j]), int(k[i]), int(k[j]), fs * tau_gm if "GM" in procs else 0.0)
             for i, j in zip(ii, jj)]
    pair = np.repeat(np.arange(ii.size), [nd[0].size for nd in nodes])
    lag, wts, spike = (np.concatenate([nd[q] for nd in nodes]) for q in range(3))
    mi, mj, ki, kj = (a[pair].astype(np.float64) for a in (m[ii], m[jj], k[ii], k[jj]))
    wts = wts * np.maximum(0.0, np.minimum(ki, kj - lag) - np.maximum(0.0, -lag))  # pairs (k, l) sharing the lag
    unit = {}
    for q in procs:
        c = np.zeros_like(lag)
        for a, ca in ((0.0, 1.0), (1.0, -2.0), (2.0, 1.0)):
            for b, cb in ((0.0, 1.0), (1.0, -2.0), (2.0, 1.0)):
                c += ca * cb * _unit_gencov(q, lag + b * mj - a * mi, fs, tau_gm)
        unit[q] = c * (spike if q == "QN" else 1.0) / (mi * mj)
    return _Lags(m, k, fs, tau_gm, pair, lag, wts, spike, unit)


def _cov(lg: _Lags, model, p: dict) -> np.ndarray:
    """The covariance of :func:`avar_covariance` from precomputed nodes (``lg.unit`` must hold the model's processes)."""
    procs, v, _ = _variances(model, p)
    c = sum(vq * lg.unit[q] for q, vq in zip(procs, v) if q != "DR")
    T = lg.m.size
    ii, jj = np.triu_indices(T)
    s2 = np.bincount(lg.pair, lg.weight * c * c, ii.size)
    s1 = np.bincount(lg.pair, lg.weight * c, ii.size)
    mu = p["R"] * lg.m / lg.fs if "DR" in procs else np.zeros(T)
    k = lg.k
    out = np.empty((T, T))
    out[ii, jj] = s2 / (2.0 * k[ii] * k[jj]) + mu[ii] * mu[jj] * s1 / (k[ii] * k[jj])
    out[jj, ii] = out[ii, jj]
    return out


def avar_covariance(model, p: dict, m: Int[Array, " T"], n_samples: int, fs: float) -> Float[np.ndarray, "T T"]:
    """Covariance of the overlapping AVAR estimates at cluster sizes ``m`` of an ``n_samples`` log (Gaussian model).

    ``A_m = sum_k d_{m,k}^2 / (2 K_m)`` with ``d`` the differences of adjacent means and
    ``K_m = n + 1 - 2m`` terms; for Gaussian ``d``, ``Cov(A_m, A_n) = sum_{k,l} (2 c^2 + 4 mu_m mu_n c)
    / (4 K_m K_n)``, ``c`` the covariance of ``d_{m,k}`` and ``d_{n,l}`` (a function of ``l - k``, so
    the double sum is a sum over lags weighted by how many pairs share the lag; ``c`` is a 9-term sum
    of ``G``) and ``mu`` the rate ramp's mean difference. A Gauss-Markov term's exponential tail is
    followed for 32 ``tau_gm``.

    Args:
        model: process names.
        p: parameters by name.
        m: cluster sizes (samples).
        n_samples: samples in the log.
        fs: sample rate (Hz).
    """
    return _cov(_lags(m, n_samples, fs, _ordered(model), float(p.get("tau_gm", 1.0))), model, p)


def _whiten(V: np.ndarray) -> np.ndarray:
    """``W`` with ``W' W = V^-1``: through the correlation matrix, its eigenvalues floored at 1e-12 (a
    random walk makes neighbouring cluster sizes nearly collinear)."""
    d = np.sqrt(np.diag(V))
    lam, U = np.linalg.eigh(V / np.outer(d, d))
    lam = np.maximum(lam, 1e-12 * lam.max())
    return (U / np.sqrt(lam)).T / d[None, :]


def _to_params(model, v: np.ndarray, tau_gm: float) -> dict:
    key = {"WN": "N", "QN": "Q", "BI": "B", "RW": "K", "DR": "R", "GM": "sigma_gm"}
    p = {key[q]: float(np.sqrt(max(vi, 0.0))) for q, vi in zip(_ordered(model), v)}
    if "GM" in model:
        p["tau_gm"] = float(tau_gm)
    return p


def fit_model(model, avar: Float[Array, " T"], m: Int[Array, " T"], fs: float, W: Float[Array, "T T"],
              n_samples: int, gm_grid: int = 32) -> tuple[dict, float]:
    """One model fitted to measured AVAR: ``min_{v >= 0} |W (avar - D(tau_gm) v)|^2`` (NNLS), profiled over ``tau_gm``.

    Args:
        model: process names.
        avar: measured AVAR at cluster sizes ``m``.
        m: cluster sizes (samples).
        fs: sample rate (Hz).
        W: whitening matrix (``W' W`` the weight).
        n_samples: samples in the log.
        gm_grid: ``tau_gm`` grid size.

    Returns:
        ``(params, objective)``; a parameter driven to zero by the bound is 0.
    """
    y = W @ np.asarray(avar, np.float64)

    def solve(tau_gm: float) -> tuple[np.ndarray, float]:
        A = W @ _design(model, m, fs, tau_gm)
        scale = np.linalg.norm(A, axis=0)
        v, r = nnls(A / scale, y)
        return v / scale, r**2

    if "GM" not in model:
        v, obj = solve(1.0)
        return _to_params(model, v, 1.0), obj
    grid = np.geomspace(*_gm_range(m, fs), gm_grid)
    objs = [solve(t)[1] for t in grid]
    i = int(np.argmin(objs))
    lo, hi = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, gm_grid - 1)])
    best = minimize_scalar(lambda lt: solve(np.exp(lt))[1], bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    tau = float(np.exp(best.x)) if best.fun < objs[i] else float(grid[i])
    v, obj = solve(tau)
    return _to_params(model, v, tau), obj


def _gm_range(m, fs: float) -> tuple[float, float]:
    return 2.0 / fs, max(m[-1] / 8.0, 4.0) / fs


def _log_jacobian(model, p: dict, m, fs: float) -> np.ndarray:
    """``d AVAR / d log(parameter)``, (T, P) in ``_names(model)`` order."""
    procs, v, tau_gm = _variances(model, p)
    D = _design(procs, m, fs, tau_gm)
    cols = []
    for j, q in enumerate(procs):
        cols.append(2.0 * v[j] * D[:, j])
        if q == "GM":
            h = 1e-4
            up, dn = (_unit_avar("GM", m, fs, tau_gm * np.exp(s)) for s in (h, -h))
            cols.append(v[j] * (up - dn) / (2.0 * h))
    return np.stack(cols, axis=1)


def _covariance_of(base: _Lags, model, p: dict, n: int) -> np.ndarray:
    if "GM" in model:  # its nodes depend on tau_gm
        return avar_covariance(model, p, base.m, n, base.fs)
    return _cov(base, model, p)


def _fit_axis(avar: np.ndarray, m: np.ndarray, fs: float, n: int, config: GmwmConfig) -> GmwmFit:
    base = _lags(m, n, fs, ("WN", "QN", "BI", "RW"))
    W0 = np.diag(1.0 / avar)
    crit, fits = {}, {}
    for mod in config.candidates or CANDIDATES:
        p, _ = fit_model(mod, avar, m, fs, W0, n, config.gm_grid)
        for _ in range(config.iterations):  # weight: the covariance at the model's own previous estimate
            if any(p[k] <= 0.0 for k in p):
                break
            V = _covariance_of(base, mod, p, n)
            p, obj = fit_model(mod, avar, m, fs, _whiten(V), n, config.gm_grid)
        if any(p[k] <= 0.0 for k in p):  # a process at its bound: the smaller model holds this fit
            continue
        fits[mod] = (p, obj)
        crit["+".join(_ordered(mod))] = obj + config.penalty * len(_names(mod))
    best = min(fits, key=lambda mod: crit["+".join(_ordered(mod))])
    p, V, cov = _refine_log(best, fits[best][0], avar, m, fs, base, n)
    names, se = _names(best), np.sqrt(np.maximum(np.diag(cov), 0.0))
    val, z = np.array([p[k] for k in names]), norm.ppf(0.5 + config.level / 2.0)
    wide = np.exp(np.minimum(z * se, 700.0))  # an undetermined parameter: (0, inf)
    return GmwmFit(_ordered(best), names, val, val / wide, np.where(np.isfinite(se), val * wide, np.inf), se, crit, float(fits[best][1]),
                   m, avar, model_avar(best, p, m, fs), np.sqrt(np.diag(V)), n, fs, config.level)


def _log_moments(model, p: dict, m, fs: float, V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean shift and covariance of ``log A_m``: each AVAR estimate as ``nu chi2_k / k`` with ``k = 2 nu^2 / V_mm``
    (``E log = log nu + psi(k/2) + log(2/k)``, ``Var log = psi'(k/2)``), correlated as the AVARs are."""
    nu = model_avar(model, p, m, fs)
    k = 2.0 * nu**2 / np.diag(V)
    sd = np.sqrt(np.diag(V))
    s = np.sqrt(polygamma(1, k / 2.0))
    return digamma(k / 2.0) + np.log(2.0 / k), V / np.outer(sd, sd) * np.outer(s, s)


def _refine_log(model, p: dict, avar, m, fs: float, base: _Lags, n: int, rounds: int = 2):
    """The selected model refitted to ``log AVAR`` (skew and the small-EDF bias at long cluster times
    accounted for, :func:`_log_moments`), weighted by the covariance at the previous estimate.

    Returns ``(params, V, cov)``: the AVAR covariance at the estimate and the covariance of the log
    parameters, ``(L' C^-1 L)^-1`` with ``L = d log AVAR / d log parameter``.
    """
    names = _names(model)
    th = np.log([p[k] for k in names])
    bounds = [th - 5.0, th + 5.0]  # within e^5 of the NNLS estimate, tau_gm within the grid's range
    if "GM" in model:
        bounds[0][-1], bounds[1][-1] = np.log(_gm_range(m, fs))
    th, y = np.clip(th, *bounds), np.log(avar)
    for _ in range(rounds):
        V = _covariance_of(base, model, p, n)
        shift, C = _log_moments(model, p, m, fs, V)
        W = _whiten(C)

        def resid(t, W=W, shift=shift):
            q = dict(zip(names, np.exp(t)))
            return W @ (y - np.log(model_avar(model, q, m, fs)) - shift)

        def jac(t, W=W):
            q = dict(zip(names, np.exp(t)))
            return -W @ (_log_jacobian(model, q, m, fs) / model_avar(model, q, m, fs)[:, None])

        th = least_squares(resid, th, jac, bounds=bounds).x
        p = dict(zip(names, np.exp(th)))
    V = _covariance_of(base, model, p, n)
    return p, V, _log_param_cov(model, p, m, fs, V)


def _log_param_cov(model, p: dict, m, fs: float, V: np.ndarray) -> np.ndarray:
    """Covariance of the log parameters, ``(L' C^-1 L)^-1``, ``L = d log AVAR / d log parameter``."""
    _, C = _log_moments(model, p, m, fs, V)
    L = _log_jacobian(model, p, m, fs) / model_avar(model, p, m, fs)[:, None]
    F = L.T @ np.linalg.solve(C, L)
    return np.linalg.inv(F) if np.linalg.cond(F) < 1e14 else np.full(F.shape, np.inf)  # else undetermined


def gmwm_axes(x: Float[Array, "N C"], fs: float, config: GmwmConfig = GmwmConfig()) -> tuple[GmwmFit, ...]:
    """:func:`fit_gmwm` on each column of a static rate log (any unit ``u``)."""
    x = np.asarray(x, np.float64).reshape(np.shape(x)[0], -1)
    m = dyadic_sizes(x.shape[0], config.max_fraction)
    res = overlapping_adev(x, fs, taus=m / fs)
    return tuple(fit_gmwm(res.adev[:, c] ** 2, res.m, fs, x.shape[0], config) for c in range(x.shape[1]))


def fit_gmwm(avar: Float[Array, " T"], m: Int[Array, " T"], fs: float, n_samples: int,
             config: GmwmConfig = GmwmConfig()) -> GmwmFit:
    """Select and fit a composite noise model to one axis's AVAR (:func:`jaxcal.allan.overlapping_adev` squared).

    Steps: each candidate is fitted with weights ``1/AVAR^2``, then (``config.iterations`` times) with
    the inverse covariance at its previous estimate (a continuously updated GMWM: each objective is
    then a chi-square of ``T - p`` degrees of freedom under its own model), and scored by
    ``WVIC = objective + penalty * parameters``; candidates with a parameter at zero are dropped (the
    smaller model holds that fit). The selected model is refitted to ``log AVAR``
    (:func:`_refine_log`); its intervals are Wald intervals on the log scale.

    Args:
        avar: measured AVAR at cluster sizes ``m``.
        m: cluster sizes (samples), e.g. :func:`dyadic_sizes`.
        fs: sample rate (Hz).
        n_samples: samples in the log.
        config: :class:`GmwmConfig`.
    """
    avar = np.asarray(avar, np.float64)
    if not np.all(np.isfinite(avar)) or np.any(avar <= 0.0):
        raise ValueError("the Allan variance must be finite and positive at every cluster size (a constant log?)")
    return _fit_axis(avar, np.asarray(m, np.int64), fs, n_samples, config)


def predicted_halfwidth(fit: GmwmFit, name: str, n_samples: int, max_fraction: float = 0.25) -> float:
    """Relative half-width (upper end / estimate - 1) of a parameter's interval on a log of ``n_samples``
    with the same noise: the fitted model's covariance and Jacobian at that length's dyadic sizes."""
    m = dyadic_sizes(n_samples, max_fraction)
    p = dict(zip(fit.names, fit.value))
    cov = _log_param_cov(fit.model, p, m, fit.fs, avar_covariance(fit.model, p, m, n_samples, fit.fs))
    z = norm.ppf(0.5 + fit.level / 2.0)
    return float(np.expm1(z * np.sqrt(cov[fit.names.index(name), fit.names.index(name)])))


def record_length(fit: GmwmFit, name: str, target: float, max_fraction: float = 0.25) -> float:
    """Seconds of static log that would give ``name``'s interval a relative half-width of ``target``.

    Secant iterations on ``log(halfwidth)`` against ``log(samples)`` (:func:`predicted_halfwidth`; near a
    straight line of slope -1/2), started from this log's length; NaN when the parameter was not selected
    or has no finite interval.
    """
    x0, x1 = np.log(fit.n), np.log(fit.n) + 1.0
    y0, y1 = (np.log(predicted_halfwidth(fit, name, int(np.exp(x)), max_fraction) / target) if name in fit.names else np.nan
              for x in (x0, x1))
    for _ in range(8):
        if not np.isfinite(y0 + y1):  # not selected, or not determined by this model's cluster times
            return float("nan")
        slope = (y1 - y0) / (x1 - x0) if abs(x1 - x0) > 1e-9 else -0.5
        step = -y1 / (slope if slope < -0.05 else -0.5)
        x0, y0 = x1, y1
        x1 = float(np.clip(x1 + step, np.log(64), np.log(fit.n) + 12.0))
        y1 = np.log(predicted_halfwidth(fit, name, int(np.exp(x1)), max_fraction) / target)
        if abs(y1) < 0.01:
            break
    return float(np.exp(x1) / fit.fs)


def noise_params(fits) -> NoiseParams:
    """N, B (flicker), K with intervals from per-axis fits, as :func:`jaxcal.allan.fit_noise` returns them:
    NaN where the process was not selected; ``tau_*`` NaN (every cluster time was used)."""
    cols = {k: np.array([f.get(k) for f in fits]).T for k in ("N", "B", "K")}
    nan = np.full(len(fits), np.nan)
    return NoiseParams(*cols["N"], *cols["B"], *cols["K"], nan, nan, nan, fits[0].level)


def record_advice(fit: GmwmFit, target: float) -> dict:
    """How long to record: the relative half-width (upper end / estimate - 1) this log gave N and K, and
    the seconds of static log a half-width of ``target`` would need (:func:`record_length`)."""
    width = {k: float(fit.get(k)[2] / fit.get(k)[0] - 1.0) for k in ("N", "K") if k in fit.names}
    return {"target_halfwidth": float(target), "halfwidth": width,
            "seconds_for_target": {k: record_length(fit, k, target) for k in width}}


def advice_lines(s: str, advice: list) -> list[str]:
    """One line each for N and K: the widest half-width over the axes' :func:`record_advice`, and the record
    length its target needs (``s`` names the sensor)."""
    out = []
    for k in ("N", "K"):
        got = [(a["halfwidth"][k], a["seconds_for_target"][k]) for a in advice if k in a["halfwidth"]]
        if got:
            w, sec = max(got)
            out.append(f"{s}: {k}'s interval reaches +{100 * w:.3g} % (widest axis); +-{100 * advice[0]['target_halfwidth']:.3g} % "
                       f"would need about {sec / 3600:.3g} h of static log (GMWM prediction)")
    return out


def fit_json(fit: GmwmFit, advice: dict | None = None) -> dict:
    """One axis's fit as plain JSON (NaN and infinity as null): model, parameters with intervals, WVIC per
    candidate, the AVAR fitted and its model, and ``advice`` (:func:`record_advice`) as ``record_length``."""
    fl = lambda v: float(v) if np.isfinite(v) else None  # noqa: E731
    pars = {k: {"value": fl(v), "interval": [fl(a), fl(b)]} for k, v, a, b in zip(fit.names, fit.value, fit.lo, fit.hi)}
    out = {"model": "+".join(fit.model), "parameters": pars, "wvic": dict(fit.wvic), "objective": fl(fit.objective),
           "taus_s": [float(v) for v in fit.m / fit.fs], "avar": [float(v) for v in fit.avar],
           "avar_model": [float(v) for v in fit.avar_model], "avar_sd": [float(v) for v in fit.avar_sd]}
    if advice is not None:
        out["record_length"] = {"target_halfwidth": advice["target_halfwidth"],
                                "halfwidth": {k: fl(v) for k, v in advice["halfwidth"].items()},
                                "seconds_for_target": {k: fl(v) for k, v in advice["seconds_for_target"].items()}}
    return out


def quantised_rate(rng: np.random.Generator, x: Float[Array, "N C"], fs: float, Q: float) -> Float[np.ndarray, "N C"]:
    """A rate log whose integral (angle, velocity) is quantised, IEEE 952's quantisation noise ``3 Q^2 / tau^2``.

    The running integral ``sum x / fs`` (started at a random offset) is rounded to the step
    ``sqrt(12) Q`` and differenced back to a rate: the rounding errors are near uniform and independent.

    Args:
        rng: numpy random generator.
        x: (N, C) rate samples.
        fs: sample rate (Hz).
        Q: quantisation coefficient [u s].
    """
    step = np.sqrt(12.0) * Q
    x = np.asarray(x, np.float64)
    ang = np.concatenate([rng.uniform(0.0, step, (1, x.shape[1])), np.cumsum(x, axis=0) / fs], axis=0)
    ang[1:] += ang[0]
    return np.diff(step * np.round(ang / step), axis=0) * fs
