"""Naming effects: regressors, coloured-noise-aware tests, forward selection, detectability.

For one sensor the model is linearised around the fitted baseline (all effect parameters zero,
except a coarse time offset when one was found): ``y ~ f0 + J_beta d_beta + J_theta theta``
with the Jacobians from JAX autodiff (:func:`jaxcal.diagnose.effects.regressors`). Residual and
regressors are prewhitened per axis (:mod:`jaxcal.diagnose.whiten`) and reduced to Gram
matrices per contiguous time block (default 8 blocks).

* **Test**: adding effect group ``g`` with ``p`` parameters lowers the whitened RSS by ``D``;
  under "effect absent" ``D ~ chi2(p)``. A group is a candidate when ``D`` passes
  ``chi2.isf(alpha / K, p)`` (Bonferroni over all ``K`` candidates of the recording) **and** it
  lowers the held-out RSS in leave-one-block-out cross-validation: for every block, parameters
  fitted on the other blocks predict that block, which the fit never saw.
* **Forward selection**: the passing candidate with the smallest p-value joins the model; repeat
  until none passes. Noise model and selection are iterated (AR refitted on the residual of the
  selected model) until the selected set is stable.
* **Minimum detectable size** (MDS): with Fisher information ``F_g`` of a group (whitened Gram
  after projecting out the baseline), the size of parameter component ``j`` detected with
  probability ``power`` at the test's level is ``sqrt(lambda*(p) / F_g[j, j])``, where
  ``lambda*`` is the non-centrality at which ``ncx2(p, lambda)`` exceeds the critical value with
  that probability.
* **Confounding**: the largest canonical correlation between two groups' whitened regressors
  (baseline projected out); above 0.95 the data cannot tell them apart.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from scipy import optimize, stats

from jaxcal.diagnose import effects as E
from jaxcal.diagnose.system import SelectConfig, SensorData, System, _solve, build_system, rss
from jaxcal.diagnose.whiten import ARModel, apply_filter, fill_index, gap_ok
from jaxcal.precision import float64

__all__ = [
    "SensorData",
    "SelectConfig",
    "linearize",
    "linearize_baseline",
    "fit_baseline",
    "System",
    "build_system",
    "rss",
    "group_columns",
    "candidates",
    "projected_information",
    "cross_gram",
    "attenuation",
    "block_score_inflation",
    "critical_value",
    "detectable_noncentrality",
    "minimum_detectable",
    "canonical_correlation",
    "coarse_lag",
    "Decision",
    "cv_rss",
    "forward_select",
    "heldout_rms_path",
    "saturation_plateau",
    "saturation_stat",
    "saturation_mds",
]


# ----------------------------------------------------------------------------- linearisation


@float64
def linearize(kind: str, sd: SensorData, beta: np.ndarray, theta: np.ndarray):
    """``(X (N, 3, B+P), z (N, 3))``: regressors [baseline | effects] and residual at (beta, theta).

    Args:
        kind: baseline, ``"diag"`` or ``"affine"`` (static in the compiled core).
        sd: the sensor's prepared data.
        beta: (B,) baseline parameters.
        theta: (P,) effect parameters (:data:`~jaxcal.diagnose.effects.LAYOUT`).
    """
    inp = E.as_jax(sd.inp)
    jb, jt, z = E.linearized(kind, sd.sensor, jnp.asarray(beta, jnp.float64), jnp.asarray(theta, jnp.float64), inp, jnp.asarray(sd.y, jnp.float64))
    return np.concatenate([np.asarray(jb), np.asarray(jt)], axis=2), np.asarray(z)


@float64
def linearize_baseline(kind: str, sd: SensorData, beta: np.ndarray, theta: np.ndarray):
    """Like :func:`linearize` but only the baseline columns ``(X (N, 3, B), z (N, 3))``.

    Args:
        kind: baseline, ``"diag"`` or ``"affine"`` (static in the compiled core).
        sd: the sensor's prepared data.
        beta: (B,) baseline parameters.
        theta: (P,) effect parameters, held fixed.
    """
    inp = E.as_jax(sd.inp)
    jb, z = E.linearized_baseline(kind, sd.sensor, jnp.asarray(beta, jnp.float64), jnp.asarray(theta, jnp.float64), inp, jnp.asarray(sd.y, jnp.float64))
    return np.asarray(jb), np.asarray(z)


def fit_baseline(kind: str, sd: SensorData, rows: np.ndarray) -> np.ndarray:
    """Ordinary least-squares baseline ``beta`` on ``rows`` (the baseline is linear in beta).

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sd: the sensor's prepared data.
        rows: (N,) bool, the rows fitted.
    """
    beta0 = E.identity_beta(kind)
    x, z = linearize(kind, sd, beta0, np.zeros(E.N_THETA[sd.sensor]))
    nb = E.N_BASE[kind]
    a = x[rows, :, :nb].reshape(-1, nb)
    d, *_ = np.linalg.lstsq(a, z[rows].reshape(-1), rcond=None)
    return beta0 + d


def group_columns(kind: str, sensor: str, name: str) -> list[int]:
    """Columns of effect ``name`` in the [baseline | theta] layout.

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sensor: ``"acc"`` or ``"gyr"``.
        name: effect name.
    """
    sl = E.slot(sensor, name)
    nb = E.N_BASE[kind]
    return list(range(nb + sl.start, nb + sl.start + sl.size))


def candidates(kind: str, sd: SensorData, exclude: tuple[str, ...] = ()) -> list[str]:
    """Smooth effects testable for this sensor and baseline (saturation is handled separately).

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sd: the sensor's prepared data.
        exclude: effects the mode does not test (``SelectConfig.exclude``).
    """
    out = []
    for sl in E.LAYOUT[sd.sensor]:
        if sl.name in exclude:
            continue
        if kind == "affine" and sl.name == "misalignment":
            continue  # absorbed by the affine baseline
        if sl.name.startswith("temperature") and not sd.has_temp:
            continue
        out.append(sl.name)
    return out


def projected_information(S: System, base: list[int], cols: list[int]) -> np.ndarray:
    """Fisher information of ``cols`` after projecting out ``base`` (whitened, all blocks).

    Args:
        S: the whitened system.
        base: columns projected out (the baseline).
        cols: the group's columns.
    """
    G = S.G_all
    gbb = G[np.ix_(base, base)]
    gbc = G[np.ix_(base, cols)]
    sol = np.linalg.lstsq(gbb, gbc, rcond=None)[0]
    return G[np.ix_(cols, cols)] - gbc.T @ sol


def cross_gram(x_ref: np.ndarray, x_meas: np.ndarray, ars: list[ARModel], rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whitened Gram ``X_ref^T X_ref`` and cross-Gram ``X_ref^T X_meas`` (Q, Q) of regressors
    (N, 3, Q) on the reference motion and on the sensors' measured signals, summed over axes.

    Args:
        x_ref: (N, 3, Q) regressors on the reference motion.
        x_meas: (N, 3, Q) the same regressors on the sensors' measured signals.
        ars: per-axis noise models (3).
        rows: (N,) bool, the rows used.
    """
    q = x_ref.shape[2]
    Grr, Grm = np.zeros((q, q)), np.zeros((q, q))
    fi = fill_index(rows)
    for i in range(3):
        ok = gap_ok(rows, ars[i].memory)
        xr = apply_filter(x_ref[fi, i, :], ars[i])[ok]
        xm = apply_filter(x_meas[fi, i, :], ars[i])[ok]
        Grr += xr.T @ xr
        Grm += xr.T @ xm
    return Grr, Grm


def attenuation(Grr: np.ndarray, Grm: np.ndarray, base: list[int], cols: list[int]) -> np.ndarray:
    """Errors-in-variables attenuation of the regressors ``cols`` (per component, in (0, 1]).

    When the reference motion is derived from a noisy source (a mocap pose differentiated twice),
    a regressor built from it is ``X = X_true + X_noise`` and the Fisher information ``X^T X``
    counts the noise as information; the test's real noncentrality is smaller by ``a^2`` with
    ``a = X_true^T X_true / X^T X``. ``X_true^T X_true`` is estimated without knowing ``X_true``
    from the same regressors evaluated on the sensors' own measured signals, whose noise is
    independent of the reference's (:func:`cross_gram` gives ``Grr``, ``Grm``):
    ``a_j = [F_rm^T F_rr^-1 F_rm]_jj / [F_rr]_jj`` under the square root, with ``F_rr``/``F_rm``
    the (cross-)information of ``cols`` after projecting out the baseline ``base``.

    Args:
        Grr, Grm: Gram and cross-Gram from :func:`cross_gram`.
        base: baseline columns (projected out).
        cols: the group's columns.
    """
    gbb = Grr[np.ix_(base, base)]
    sol = np.linalg.lstsq(gbb, np.concatenate([Grr[np.ix_(base, cols)], Grm[np.ix_(base, cols)]], 1), rcond=None)[0]
    Frr = Grr[np.ix_(cols, cols)] - Grr[np.ix_(cols, base)] @ sol[:, : len(cols)]
    Frm = Grm[np.ix_(cols, cols)] - Grr[np.ix_(cols, base)] @ sol[:, len(cols) :]
    feff = Frm.T @ np.linalg.lstsq(Frr, Frm, rcond=None)[0]
    d = np.clip(np.diag(Frr), 1e-300, None)
    return np.clip(np.sqrt(np.clip(np.diag(feff), 0.0, None) / d), 0.05, 1.0)


def block_score_inflation(S: System, base: list[int], cols: list[int], cur: list[int], th: np.ndarray) -> np.ndarray:
    """Per component of ``cols``: sqrt(block-robust / model-based variance of its score), at least 1.

    The score of a candidate at the current fit (columns ``cur``, solution ``th``) is
    ``X_c^T r`` with the baseline projected out; its model-based variance is the Fisher information.
    Summed block by block (the cross-validation blocks), its spread across blocks estimates the
    variance the data really show (cluster-robust), which misspecification on real data (reference
    errors, unmodelled colour) makes larger. With ``K`` blocks the ratio has about ``K - 1``
    degrees of freedom: a coarse, conservative factor for detectable sizes, not a test.

    Args:
        S: the whitened system.
        base: baseline columns (projected out).
        cols: the candidate's columns.
        cur: columns of the current fit.
        th: its solution on ``cur``.
    """
    G, g = S.G, S.g
    sc = g[:, cols] - G[:, cols][:, :, cur] @ th
    sb = g[:, base] - G[:, base][:, :, cur] @ th
    Ga = S.G_all
    proj = np.linalg.lstsq(Ga[np.ix_(base, base)], Ga[np.ix_(base, cols)], rcond=None)[0]
    sv = sc - sb @ proj
    k = sv.shape[0]
    sv = sv - sv.mean(0)
    v = np.sum(sv * sv, 0) * k / max(k - 1, 1)
    f = np.clip(np.diag(projected_information(S, base, cols)), 1e-300, None)
    return np.sqrt(np.clip(v / f, 1.0, None))


@lru_cache(maxsize=None)
def critical_value(level: float, dof: int) -> float:
    """Chi-square critical value at ``level``.

    Args:
        level: test level (upper-tail probability).
        dof: degrees of freedom.
    """
    return float(stats.chi2.isf(level, dof))


@lru_cache(maxsize=None)
def detectable_noncentrality(level: float, dof: int, power: float) -> float:
    """Non-centrality ``lambda*`` with ``P(ncx2(dof, lambda*) > crit) = power``.

    Args:
        level: test level.
        dof: degrees of freedom.
        power: detection probability.
    """
    crit = critical_value(level, dof)
    return float(optimize.brentq(lambda lam: stats.ncx2.sf(crit, dof, lam) - power, 1e-6, 1e4))


def minimum_detectable(F: np.ndarray, level: float, power: float) -> tuple[np.ndarray, float]:
    """Per-component MDS ``sqrt(lambda*/F_jj)`` and the worst-direction MDS ``sqrt(lambda*/min eig F)``.

    Args:
        F: (p, p) Fisher information of the group.
        level: test level.
        power: detection probability.
    """
    p = F.shape[0]
    lam = detectable_noncentrality(level, p, power)
    d = np.clip(np.diag(F), 1e-300, None)
    ev = max(float(np.linalg.eigvalsh(F).min()), 1e-300)
    return np.sqrt(lam / d), float(np.sqrt(lam / ev))


def canonical_correlation(S: System, base: list[int], a: list[int], b: list[int]) -> float:
    """Largest canonical correlation between two groups' regressors, baseline projected out.

    Args:
        S: the whitened system.
        base: baseline columns (projected out).
        a, b: the two groups' columns.
    """
    F = projected_information(S, base, a + b)
    na = len(a)
    faa, fbb, fab = F[:na, :na], F[na:, na:], F[:na, na:]

    def inv_sqrt(m):
        w, v = np.linalg.eigh(m)
        w = np.clip(w, w.max() * 1e-12 + 1e-300, None)
        return (v / np.sqrt(w)) @ v.T

    m = inv_sqrt(faa) @ fab @ inv_sqrt(fbb)
    return float(np.clip(np.linalg.svd(m, compute_uv=False).max(), 0.0, 1.0))


# ----------------------------------------------------------------------------- coarse time offset


def coarse_lag(y: np.ndarray, x: np.ndarray, rows: np.ndarray, max_lag: int) -> int:
    """Integer lag ``l`` (samples) maximising the explained variance of ``y(t)`` by ``x(t - l)``.

    Cross-correlations for every lag at once by FFT (zero-padded); the score sums over axes
    ``c_i(l)^2 / |x_i|^2`` (the variance a per-axis scale explains).

    Args:
        y: (N, C) sensor output.
        x: (N, C) reference input.
        rows: (N,) bool, valid rows.
        max_lag: largest ``|l|`` tried (samples).
    """
    n = len(y)
    yc = np.where(rows[:, None], y - y[rows].mean(0), 0.0)
    xc = np.where(rows[:, None], x - x[rows].mean(0), 0.0)
    m = 1 << int(np.ceil(np.log2(2 * n)))
    fy = np.fft.rfft(yc, m, axis=0)
    fx = np.fft.rfft(xc, m, axis=0)
    cc = np.fft.irfft(fy * np.conj(fx), m, axis=0)  # cc[l] = sum_t y(t) x(t - l)
    lags = np.concatenate([np.arange(0, max_lag + 1), np.arange(-max_lag, 0)])
    c = cc[lags % m]
    score = np.sum(c**2 / (np.sum(xc**2, 0) + 1e-300), axis=1)
    return int(lags[int(np.argmax(score))])


# ----------------------------------------------------------------------------- selection


class Decision(NamedTuple):
    """Outcome of testing one candidate at the step it was last considered."""

    name: str
    stat: float
    dof: int
    log10_p: float
    heldout_gain: float  # whitened held-out RSS decrease (>0: better)
    selected: bool
    reason: str
    heldout_rms_change: float = float("nan")  # physical held-out RMS after minus before (<0: better)


def cv_rss(S: System, cols: list[int], whitened: bool = True, fit: str = "gls", bias_cols: list[int] | None = None) -> float:
    """Leave-one-block-out held-out RSS: block ``k`` predicted by the fit on all other blocks.

    Args:
        S: the system, per block.
        cols: the columns in the model.
        whitened: score the whitened (True) or physical residual.
        fit: ``"gls"`` fits on the whitened normal equations (the noise model's estimate), ``"ols"``
            on the physical ones (least squares on the very RSS that the physical score measures).
        bias_cols: with a ``gls`` fit scored on the physical residual, these bias columns are
            re-levelled on the training blocks (:func:`_relevel`), as the final fit is.
    """
    if fit not in ("gls", "ols"):
        raise ValueError(f"fit must be 'gls' or 'ols', got {fit!r}")
    G, g, zz = (S.G, S.g, S.zz) if whitened else (S.Gu, S.gu, S.zzu)
    Gf, gf = (S.G, S.g) if fit == "gls" else (S.Gu, S.gu)
    Gw, gw = Gf.sum(0), gf.sum(0)
    Guw, guw = S.Gu.sum(0), S.gu.sum(0)
    relevel = (not whitened) and fit == "gls" and bias_cols is not None
    tot = 0.0
    for k in range(S.G.shape[0]):
        th = _solve(Gw - Gf[k], gw - gf[k], cols)
        if relevel:
            th = _relevel(Guw - S.Gu[k], guw - S.gu[k], cols, th, bias_cols)
        tot += rss(G[k], g[k], float(zz[k]), cols, th)
    return tot


def _relevel(Gu: np.ndarray, gu: np.ndarray, cols: list[int], th: np.ndarray, bias_cols: list[int]) -> np.ndarray:
    """Re-level a noise-model fit: each bias column set to the plain mean of the physical residual
    of its axis (one exact coordinate step: bias columns are per-axis indicators, so they are
    mutually orthogonal). A random-walk noise model's whitening annihilates a constant, so its fit
    cannot see the bias; the final fit re-levels the same way (``diagnose_sensor``)."""
    th = th.copy()
    for b in bias_cols:
        j = cols.index(b)
        d = Gu[b, b]
        if d > 0:
            th[j] += (gu[b] - Gu[b, cols] @ th) / d
    return th


def forward_select(S: System, kind: str, sensor: str, cands: list[str], preselected: list[str], level: float):
    """Greedy forward selection on a :class:`System`.

    A candidate joins only when three verdicts agree: the whitened chi-square test passes at
    ``level``, the whitened held-out RSS falls, and the **physical** held-out RMS (the number the
    report prints, :func:`heldout_rms_path`) falls. Where the whitened verdicts and the physical
    score disagree, the noise model and the data disagree; the candidate is not named and its
    decision says so.

    Args:
        S: the whitened system.
        kind: baseline, ``"diag"`` or ``"affine"``.
        sensor: ``"acc"`` or ``"gyr"``.
        cands: candidate effect names.
        preselected: effects in the model from the start (e.g. a coarse time offset).
        level: test level (Bonferroni-corrected).

    Returns:
        ``(selected names in order, decisions {name: Decision}, solution on all blocks, cols)``.
    """
    nb = E.N_BASE[kind]
    Ga, ga, zza = S.G_all, S.g_all, S.zz_all
    n_phys = max(float(S.nu.sum()), 1.0)
    cols = list(range(nb))
    for n in preselected:
        cols += group_columns(kind, sensor, n)
    th = _solve(Ga, ga, cols)
    cur = rss(Ga, ga, zza, cols, th)
    cur_cv = cv_rss(S, cols)
    bias = list(range(nb - 3, nb))
    cur_phys = float(np.sqrt(max(cv_rss(S, cols, whitened=False, bias_cols=bias), 0.0) / n_phys))
    selected = list(preselected)
    decisions: dict[str, Decision] = {}
    remaining = [c for c in cands if c not in selected]
    while remaining:
        best = None
        for c in remaining:
            gc = group_columns(kind, sensor, c)
            cc = cols + gc
            t2 = _solve(Ga, ga, cc)
            stat = cur - rss(Ga, ga, zza, cc, t2)
            dof = len(gc)
            lp = float(stats.chi2.logsf(max(stat, 0.0), dof) / np.log(10))
            sig = lp < np.log10(level)
            gain = cur_cv - cv_rss(S, cc) if sig else float("nan")
            phys = float(np.sqrt(max(cv_rss(S, cc, whitened=False, bias_cols=bias), 0.0) / n_phys)) if sig else float("nan")
            dphys = phys - cur_phys
            ok = sig and gain > 0 and dphys < 0
            if not sig:
                reason = "not significant"
            elif gain <= 0:
                reason = "no held-out improvement"
            elif not dphys < 0:
                reason = (f"whitened test passes but the physical held-out rms does not fall ({cur_phys:.5g} -> {phys:.5g}): "
                          "the noise model and the data disagree, so it is not named")
            else:
                reason = "selected"
            decisions[c] = Decision(c, float(stat), dof, lp, float(gain), False, reason, dphys)
            if ok and (best is None or lp < best[1]):
                best = (c, lp, cc, t2, cur_cv - gain, phys)
        if best is None:
            break
        c, _, cols, th, cur_cv, cur_phys = best
        decisions[c] = decisions[c]._replace(selected=True)
        cur = rss(Ga, ga, zza, cols, th)
        selected.append(c)
        remaining.remove(c)
    return selected, decisions, th, cols


def heldout_rms_path(S: System, kind: str, sensor: str, order: list[str], fit: str = "gls") -> list[float]:
    """Cross-validated held-out RMS (physical units) as the effects of ``order`` are added;
    parameters fitted by ``fit`` (see :func:`cv_rss`; a ``gls`` fit has its biases re-levelled on
    the training blocks' physical residual, as the final fit has).

    Args:
        S: the whitened system.
        kind: baseline, ``"diag"`` or ``"affine"``.
        sensor: ``"acc"`` or ``"gyr"``.
        order: effect names, in the order they join.
        fit: ``"gls"`` or ``"ols"`` (:func:`cv_rss`).
    """
    nb = E.N_BASE[kind]
    cols = list(range(nb))
    out = []
    n = max(float(S.nu.sum()), 1.0)
    for k in range(len(order) + 1):
        if k > 0:
            cols = cols + group_columns(kind, sensor, order[k - 1])
        out.append(float(np.sqrt(max(cv_rss(S, cols, whitened=False, fit=fit, bias_cols=list(range(nb - 3, nb))), 0.0) / n)))
    return out


# ----------------------------------------------------------------------------- saturation


def saturation_plateau(raw: np.ndarray | None) -> tuple[float, np.ndarray] | None:
    """``(limit, plateau mask (N,))`` if at least 2 samples sit exactly at ``max |raw|``."""
    if raw is None:
        return None
    lim = float(np.max(np.abs(raw)))
    mask = np.any(np.abs(raw) >= lim, axis=1)
    if mask.sum() < 2:
        return None
    return lim, mask


def saturation_stat(sd: SensorData, pred: np.ndarray, resid: np.ndarray, ars: list[ARModel], rows: np.ndarray, limit: float) -> float:
    """Whitened RSS decrease when the prediction (physical) is clipped at ``+-limit`` LSB.

    Args:
        sd: the sensor's prepared data.
        pred: (N, 3) model prediction (physical units).
        resid: (N, 3) residual of that prediction.
        ars: per-axis noise models (3).
        rows: (N,) bool, the rows used.
        limit: clipping level (LSB).
    """
    pred_raw = pred * sd.spec_scale + sd.spec_bias
    delta = (pred_raw - np.clip(pred_raw, -limit, limit)) / sd.spec_scale
    tot = 0.0
    fi = fill_index(rows)
    for i in range(3):
        ok = gap_ok(rows, ars[i].memory)
        a = apply_filter(resid[fi, i], ars[i])[ok]
        b = apply_filter((resid[:, i] + delta[:, i])[fi], ars[i])[ok]
        tot += float(a @ a - b @ b)
    return tot


def saturation_mds(sd: SensorData, pred: np.ndarray, ars: list[ARModel], rows: np.ndarray, level: float, power: float) -> float:
    """Clipping depth (LSB below the predicted peak) detectable with ``power`` (white approximation).

    Args:
        sd: the sensor's prepared data.
        pred: (N, 3) model prediction (physical units).
        ars: per-axis noise models (3).
        rows: (N,) bool, the rows used.
        level: test level.
        power: detection probability.
    """
    lam = detectable_noncentrality(level, 1, power)
    pred_raw = pred * sd.spec_scale + sd.spec_bias
    peak = float(np.max(np.abs(pred_raw[rows])))
    sig = np.array([a.sigma for a in ars])

    def nc(depth):
        ex = np.clip(np.abs(pred_raw[rows]) - (peak - depth), 0.0, None) / sd.spec_scale / sig
        return float(np.sum(ex**2))

    if nc(peak) < lam:
        return float("inf")
    return float(optimize.brentq(lambda d: nc(d) - lam, 0.0, peak))
