"""Stages 2-6 of the diagnosis of one sensor, each a pure function with a typed hand-off.

The stages (CONVENTIONS.md "Discrepancy vocabulary"; both modes run them, a mode only chooses the
residual through the :class:`~jaxcal.diagnose.prepare.Prepared` it builds):

1. :func:`coarse_offset` -> :class:`Offset`: the coarse time-offset search and its
   likelihood-ratio check, the candidates and what enters the selection preselected;
2. :func:`linearise` -> :class:`Linearised`: the baseline fit at that offset and the regressors of
   every candidate (autodiff, :mod:`~jaxcal.diagnose.select`);
3. :func:`select_effects` -> :class:`Selection`: the noise model, saturation, forward selection;
4. :func:`detectability` -> :class:`Detectability`: minimum detectable sizes, excitation and
   confounding warnings;
5. :func:`name_effects` -> :class:`Named`: the promise enforced (every named effect lowers the
   printed held-out rms and lies in its plausible range) and the joint refit with intervals.

:func:`sensor_pass` runs them once from a :class:`Start`; it answers :class:`Relinearise` (a time
offset was named far from the linearisation point: run again linearised there), :class:`Retrim` (a
clock skew was named that moves the ends past the reference's: run again without those rows,
linearised at that skew), :class:`Unskew` (that skew then did not keep the promise: run again
linearised at zero) or :class:`DropOffset` (the time offset did not keep the promise: run again
without it), and :func:`diagnose_sensor` follows those answers (each at most once: five passes at
most; no recursion).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from jaxcal.diagnose import effects as E
from jaxcal.diagnose.band_pool import candidate_spread, pool_named, widen_information
from jaxcal.diagnose.handoffs import (
    Detectability,
    DropOffset,
    Linearised,
    Named,
    Relinearise,
    Retrim,
    Selection,
    SensorResult,
    Unskew,
)
from jaxcal.diagnose.locate import breakdown
from jaxcal.diagnose.offset import Offset, Start, baseline_resid, coarse_offset, edge_rows, theta_with_tau
from jaxcal.diagnose.refit import RefitResult, refit
from jaxcal.diagnose.select import (
    Decision,
    SelectConfig,
    SensorData,
    attenuation,
    block_score_inflation,
    build_system,
    canonical_correlation,
    cross_gram,
    detectable_noncentrality,
    forward_select,
    group_columns,
    heldout_rms_path,
    linearize,
    linearize_baseline,
    minimum_detectable,
    projected_information,
    saturation_mds,
    saturation_plateau,
    saturation_stat,
)
from jaxcal.diagnose.whiten import ARModel, choose_lambda, fit_ar, reml_profile

__all__ = [
    "SensorResult",
    "UNIT_OF",
    "FORCED",
    "Start",
    "Offset",
    "Linearised",
    "Selection",
    "Detectability",
    "Named",
    "Relinearise",
    "DropOffset",
    "coarse_offset",
    "linearise",
    "select_effects",
    "detectability",
    "name_effects",
    "sensor_pass",
    "diagnose_sensor",
]


UNIT_OF = {"acc": "g", "gyr": "rad/s"}
FORCED = "estimated on request (jaxcal align), not a test"


def _demote(d: Decision | None, why: str, name: str = "") -> Decision:
    """A selected decision turned into a rejection with the reason ``why``."""
    if d is None:
        return Decision(name, float("nan"), 0, float("nan"), float("nan"), False, why)
    return d._replace(selected=False, reason=why)


def _where(resid: np.ndarray, rows: np.ndarray, sd: SensorData, dt: float) -> str:
    """Where a baseline residual lives, in words (axis, regime, frequency band; :func:`breakdown`)."""
    tc = np.asarray(sd.inp.tc)
    b = breakdown(resid, rows, tc - tc[0], np.asarray(sd.inp.w), np.asarray(sd.inp.wdot), None, dt)
    w = b["where"]
    ax = int(np.argmax(b["axis"]))
    txt = f"mostly on axis {'xyz'[ax]} (rms {_fmt3(b['axis'])})"
    if w["breakdown"] is not None:
        txt += f", in the {w['breakdown']} bin {w['bin']} ({w['rms_ratio']:.2f}x the overall rms)"
    return txt + f", and in the {w['band_hz'][0]:g}-{w['band_hz'][1]:g} Hz band ({w['band_excess']:.2f}x its white share)"


def _fmt3(v) -> str:
    return "[" + ", ".join(f"{float(x):.3g}" for x in v) + "]"


# ----------------------------------------------------------------------------- stages


def linearise(kind: str, sd: SensorData, tau_lin: float, edge_shift: float = 0.0, skew_lin: float = 0.0) -> Linearised:
    """Stage 2: the baseline fitted at the time offset ``tau_lin`` (and clock skew ``skew_lin``) on
    the rows its shift (and a named clock skew's ``edge_shift``) leaves trustworthy, and the
    regressors of every effect there.

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sd: the sensor's prepared data.
        tau_lin: the linearisation offset (s).
        edge_shift: a clock skew's shift of the ends (s, :class:`Retrim`).
        skew_lin: the linearisation clock skew (ppm, :class:`Retrim`).
    """
    fit_rows = edge_rows(sd.valid, tau_lin, float(sd.inp.dt), edge_shift)
    theta_lin = theta_with_tau(sd.sensor, tau_lin, skew_lin)
    _, beta = baseline_resid(kind, sd, theta_lin, fit_rows)
    x, z = linearize(kind, sd, beta, theta_lin)
    return Linearised(fit_rows, theta_lin, beta, x, z)


def _noise_model(kind: str, sensor: str, cfg: SelectConfig, lin: Linearised, cands: list[str], rows: np.ndarray) -> list[ARModel]:
    """The noise model per axis from the residual of the largest model (baseline + every candidate,
    plain least squares): a concealed effect left in the residual would otherwise be learnt as
    "coloured noise" by the AR/random-walk filter and whitened away (estimates shrink towards zero).
    A random walk is more than any candidate regressor, so what is left still shows it."""
    x, z = lin.x, lin.z
    cs = list(range(E.N_BASE[kind])) + [j for c in cands for j in group_columns(kind, sensor, c)]
    a_ = x[rows][:, :, cs].reshape(-1, len(cs))
    sol = np.linalg.lstsq(a_, z[rows].reshape(-1), rcond=None)[0]
    r_full = z - x[:, :, cs] @ sol
    profs = [reml_profile(r_full[:, i], rows, X=x[:, i, cs]) for i in range(3)]
    lams = choose_lambda(profs, pooled=cfg.rw_pooled, slack=cfg.rw_slack) if cfg.random_walk else [0.0] * 3
    return [fit_ar(r_full[:, i], rows, cfg.max_ar_order, lam=lams[i]) for i in range(3)]


def select_effects(kind: str, sd: SensorData, cfg: SelectConfig, level: float, off: Offset, lin: Linearised,
                   start: Start, force: tuple[str, ...] = ()) -> Selection:
    """Stage 3: noise model, saturation test and forward selection, iterated until the names
    settle (``cfg.max_passes``).

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sd: the sensor's prepared data.
        cfg: test level and search settings.
        level: the test level.
        off: stage 1.
        lin: stage 2.
        start: where this pass starts (a relinearised pass keeps the earlier decision).
        force: effects estimated whatever the tests say.
    """
    s, x, z, nb = sd.sensor, lin.x, lin.z, E.N_BASE[kind]
    fit_rows = lin.fit_rows
    plateau = saturation_plateau(sd.raw)
    sat_info = None
    prev = None
    ars_fixed = _noise_model(kind, s, cfg, lin, off.candidates, fit_rows)
    for it in range(cfg.max_passes):
        ars = ars_fixed
        if plateau is not None and it == 0:
            lim, pmask = plateau
            # predict the plateau from a baseline fitted without it: clipped samples pull a fit that
            # includes them towards the limit and hide the clipping they are evidence of
            r_np, _ = baseline_resid(kind, sd, lin.theta_lin, fit_rows & ~pmask)
            st = saturation_stat(sd, sd.y - r_np, r_np, ars, fit_rows, lim)
            lp = float(stats.chi2.logsf(max(st, 0.0), 1) / np.log(10))
            sel = lp < np.log10(level)
            sat_info = {"limit": lim, "n_clipped": int(pmask.sum()), "stat": st, "log10_p": lp, "selected": bool(sel)}
            if sel:
                fit_rows = fit_rows & ~pmask
                ars = ars_fixed
        S = build_system(x, z, ars, fit_rows, sd.block)
        selected, decisions, th, cols = forward_select(S, kind, s, off.candidates, off.preselected, level)
        full = np.zeros(x.shape[2])
        full[cols] = th
        resid = z - x @ full
        # re-level: biases the whitening cannot see (random-walk noise model) from the plain mean
        off_ = resid[fit_rows].mean(0)
        resid = resid - off_
        full[nb - 3 : nb] += off_  # the bias columns of both baselines
        if prev == selected:
            break
        prev = selected
    if off.coarse is not None:
        decisions["time_offset"] = Decision("time_offset", off.coarse[0], 1, off.coarse[1], float("nan"), True, "selected (coarse search)")
    for c in force:
        if c in off.preselected and c not in decisions and c in off.candidates:
            decisions[c] = Decision(c, float("nan"), len(group_columns(kind, s, c)), float("nan"), float("nan"), True,
                                    FORCED)
    if start.relin is not None:
        d = start.relin[1]
        decisions["time_offset"] = d._replace(reason=d.reason + f"; model relinearised at the refit offset {off.tau_lin * 1e3:.2f} ms and the other effects reselected")
    if off.skew_lin is not None:
        d = start.skew_lin[1]
        decisions["clock_skew"] = d._replace(reason=d.reason + f"; model relinearised at the refit clock skew {off.skew_lin:.2f} ppm and the other effects reselected")
    return Selection(ars, S, selected, decisions, th, cols, full, resid, fit_rows, sat_info)


def detectability(kind: str, sd: SensorData, cfg: SelectConfig, level: float, off: Offset, lin: Linearised,
                  sel: Selection, meas: E.Inputs | None = None) -> Detectability:
    """Stage 4: per candidate, relative to the baseline, the minimum detectable size (scaled by
    the attenuation of a pose-derived reference and the block-robust inflation when ``meas`` is
    given; for the effects of ``cfg.band_pool``, with the between-band variance that naming it
    would add to its interval, :func:`~jaxcal.diagnose.band_pool.candidate_spread`), "not
    excited" and "not testable" warnings, and the confounded pairs.

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sd: the sensor's prepared data.
        cfg: test level and search settings.
        level: the test level.
        off: stage 1.
        lin: stage 2.
        sel: stage 3.
        meas: the reference inputs from the sensors' own outputs
            (:func:`~jaxcal.diagnose.prepare.measured_inputs`); None: no attenuation.
    """
    s, S, nb, fit_rows = sd.sensor, sel.system, E.N_BASE[kind], sel.fit_rows
    cands = off.candidates
    warnings: list[str] = []
    base = list(range(nb))
    mds = {}
    grams = None if meas is None else cross_gram(lin.x, linearize(kind, sd._replace(inp=meas), lin.beta, lin.theta_lin)[0], sel.ars, fit_rows)
    for c in cands:
        F = projected_information(S, base, group_columns(kind, s, c))
        att = None
        if grams is not None:
            att = attenuation(*grams, base, group_columns(kind, s, c))
            infl = block_score_inflation(S, base, group_columns(kind, s, c), sel.cols, sel.th)
            F = F * (att / infl)[:, None] * (att / infl)[None, :]
            warnings += _attenuation_warnings(s, c, att, infl)
        spread = candidate_spread(lin.x, lin.z, fit_rows, sd.inp, base, group_columns(kind, s, c)) if c in cfg.band_pool else None
        if spread is not None:
            F = widen_information(F, spread)
        comp, worst = minimum_detectable(F, level, cfg.power)
        mds[c] = {"components": comp.tolist(), "worst": worst, "min": float(comp.min()), "fisher": F.tolist(),
                  "lambda_star": detectable_noncentrality(level, F.shape[0], cfg.power)}
        if spread is not None:
            mds[c]["between_band_var"] = spread.tolist()
        if att is not None:
            mds[c]["attenuation"] = att.tolist()
            mds[c]["block_inflation"] = infl.tolist()
        if c.startswith("temperature") and np.ptp(np.asarray(sd.inp.dT)[fit_rows]) == 0:
            warnings.append(  # a constant temp channel is no temperature channel: no size to report
                f"{s} {c}: not testable - the recording has no temperature channel that changes (temp is constant); "
                f"needs {E.EXCITE[c]}"
            )
        elif (c, s) in E.PLAUSIBLE and float(np.median(comp)) > E.PLAUSIBLE[(c, s)]:
            warnings.append(
                f"{s} {c}: not excited - smallest detectable size {float(np.median(comp)):.3g} {E.UNITS[(c, s)]} "
                f"exceeds a plausible {E.PLAUSIBLE[(c, s)]:.3g}; needs {E.EXCITE[c]}"
            )
    if sel.saturation is not None or sd.raw is not None:
        pred = sd.y - sel.resid
        mds["saturation"] = {"depth_lsb": saturation_mds(sd, pred, sel.ars, fit_rows, level, cfg.power),
                             "predicted_peak_lsb": float(np.max(np.abs((pred * sd.spec_scale + sd.spec_bias)[fit_rows])))}
    confounded: dict[str, list[str]] = {}
    for i, a in enumerate(cands):
        for b in cands[i + 1 :]:
            rho = canonical_correlation(S, base, group_columns(kind, s, a), group_columns(kind, s, b))
            if rho > cfg.confound_threshold:
                confounded.setdefault(a, []).append(b)
                confounded.setdefault(b, []).append(a)
                hint = E.EXCITE.get(a, "") if a.startswith("temperature") or b.startswith("temperature") else E.EXCITE.get(b, "")
                if {a, b} == {"temperature_bias", "bias_drift"}:
                    hint = "the temperature changes monotonically with time, so a temperature coefficient and a bias drift look alike; a heat-and-cool cycle separates them"
                warnings.append(f"{s}: {a} and {b} are confounded in this recording (canonical correlation {rho:.3f}); the data cannot tell them apart - {hint}")
    decisions = dict(sel.decisions)
    for c in confounded:
        if c in decisions:
            decisions[c] = decisions[c]._replace(reason=decisions[c].reason + f"; confounded with {', '.join(confounded[c])}")
    return Detectability(mds, warnings, decisions)


def _attenuation_warnings(s: str, c: str, att: np.ndarray, infl: np.ndarray) -> list[str]:
    """Warnings of a pose-derived reference: a score that varies between blocks more than the noise
    model allows, and a regressor diluted by the reference's noise."""
    out = []
    if float(infl.max()) > 1.5:
        out.append(
            f"{s} {c}: its score varies between time blocks {float(infl.max()):.1f}x more than the noise model allows "
            "(real-data misspecification); detectable sizes are scaled by this block-robust factor"
        )
    if float(att.min()) < 0.7:
        out.append(
            f"{s} {c}: its regressor comes from the pose-derived reference, whose noise dilutes it (attenuation "
            f"{float(att.min()):.2f}-{float(att.max()):.2f}); detectable sizes are scaled by 1/attenuation (the joint "
            "refit, run to convergence, is not diluted)"
        )
    return out


def _at_point(sensor: str, theta_lin: np.ndarray) -> list[str]:
    """The effects a linearisation point holds away from zero (a time offset, a clock skew), in the
    order they enter the selection (:func:`~jaxcal.diagnose.offset.coarse_offset`)."""
    out = []
    for n in ("time_offset", "clock_skew"):
        try:
            sl = E.slot(sensor, n)
        except KeyError:
            continue
        if np.any(theta_lin[sl.start : sl.start + sl.size] != 0.0):
            out.append(n)
    return out


def _restart(name: str, decision: Decision | None, why: str, warn: str) -> DropOffset | Unskew:
    """The answer when an effect of the linearisation point (:func:`_at_point`) is demoted, however
    (its held-out step, an implausible estimate, its frequency bands): the model holds that effect
    whatever is fitted, so the pass starts again without it: a time offset answers
    :class:`DropOffset` (reported with ``why`` and ``warn``), a clock skew :class:`Unskew` (the next
    pass, linearised at 0, decides and reports it)."""
    return DropOffset(_demote(decision, why, name), warn) if name == "time_offset" else Unskew()


def _drop(name: str, point: list[str], order: list[str], decisions: dict, warnings: list[str], why: str,
          warn: str) -> DropOffset | Unskew | None:
    """Stage 5's one answer to an effect that breaks the promise: an effect of the linearisation
    point (``point``) restarts the pass (:func:`_restart`); any other leaves ``order``, its decision
    is demoted with ``why`` and ``warn`` joins ``warnings`` (in place), and ``None`` says go on."""
    if name in point:
        return _restart(name, decisions.get(name), why, warn)
    order.remove(name)
    decisions[name] = _demote(decisions.get(name), why, name)
    warnings.append(warn)
    return None


def _heldout_paths(kind: str, sd: SensorData, sel: Selection, theta_lin: np.ndarray, order: list[str]) -> tuple[list[float], list[float]]:
    """The held-out rms (GLS and OLS fits) as the effects of ``order`` are added one by one. The
    system is linearised at ``theta_lin``, so it holds the point's effects (a time offset, a clock
    skew; first in ``order``) whatever columns are fitted: the steps before all of them are in are
    taken from the model linearised at the point without the ones not yet added (the baseline at
    zero first)."""
    s, S = sd.sensor, sel.system
    path = heldout_rms_path(S, kind, s, order)
    path_ols = heldout_rms_path(S, kind, s, order, fit="ols")
    point = _at_point(s, theta_lin)
    # the point's effects come first (preselected); demoting one restarts the pass (:func:`_restart`)
    assert order[: len(point)] == point, (order, point)
    for k in range(len(point)):
        theta_k = theta_lin.copy()
        for n in point[k:]:
            sl = E.slot(s, n)
            theta_k[sl.start : sl.start + sl.size] = 0.0
        # linearised at the baseline fitted there: a random-walk noise model annihilates the bias
        # columns, so starting from unit scale / zero bias would leave the whole bias in the residual
        _, beta_k = baseline_resid(kind, sd, theta_k, sel.fit_rows)
        xk, zk = linearize_baseline(kind, sd, beta_k, theta_k) if k == 0 else linearize(kind, sd, beta_k, theta_k)
        Sk = build_system(xk, zk, sel.ars, sel.fit_rows, sd.block)
        path[k] = heldout_rms_path(Sk, kind, s, order[:k])[-1]
        path_ols[k] = heldout_rms_path(Sk, kind, s, order[:k], fit="ols")[-1]
    return path, path_ols


def _band_weak(s: str, final_all: RefitResult, info: dict, force: tuple[str, ...], level: float) -> list[str]:
    """The pooled effects (not forced) whose Wald test fails at ``level`` once their intervals
    include the between-band variance."""
    out = []
    for n in info:
        sl = E.slot(s, n)
        th = np.asarray(final_all.theta[sl.start : sl.start + sl.size], float)
        se = np.asarray(final_all.se_theta[sl.start : sl.start + sl.size], float)
        stat = float(np.sum((th / np.maximum(se, 1e-300)) ** 2))
        if n not in force and stats.chi2.sf(stat, sl.size) > level:
            out.append(n)
    return out


def name_effects(kind: str, sd: SensorData, off: Offset, lin: Linearised, sel: Selection, det: Detectability,
                 force: tuple[str, ...] = (), pool: tuple[str, ...] = (), level: float = 1.0,
                 huber: float | None = 3.0) -> Named | DropOffset | Unskew:
    """Stage 5, the promise of the report: every named effect lowers the physical held-out rms that
    the report prints, step by step (one that does not is demoted to ``rejected`` with a warning that
    says where the residual lives), and no named estimate of the joint refit lies outside its
    plausible range (:data:`jaxcal.diagnose.effects.PLAUSIBLE_RANGE`; outside, it is a
    misspecification warning). Effects in ``force`` are estimates on request, not gated.
    An effect of the linearisation point (a non-zero time offset or clock skew) that is demoted in
    any of these ways answers a restart instead (:func:`_restart`): the model is linearised at it, so
    the pass starts again without it (:class:`DropOffset`, :class:`Unskew`).

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sd: the sensor's prepared data.
        off, lin, sel, det: stages 1-4.
        force: effects estimated whatever the tests say.
        pool: effects whose intervals include their between-band variance
            (:func:`~jaxcal.diagnose.band_pool.pool_named`); one that is then not significant at
            ``level`` is not named (a warning says the bands disagree).
        level: the test level of that check (Bonferroni).
        huber: the joint refit's outlier threshold (:func:`~jaxcal.diagnose.refit.refit`); None:
            plain least squares.
    """
    s, nb, fit_rows, unit = sd.sensor, E.N_BASE[kind], sel.fit_rows, UNIT_OF[sd.sensor]
    decisions = dict(det.decisions)
    warnings: list[str] = []
    order = list(sel.selected)
    r_base, b_base = baseline_resid(kind, sd, np.zeros(E.N_THETA[s]), fit_rows)
    zt = np.zeros(E.N_THETA[s])
    base_all = RefitResult(b_base, zt, np.zeros(nb), zt, float("nan"), r_base)
    where_text = _where(r_base, fit_rows, sd, float(sd.inp.dt))
    for name, d in decisions.items():
        if not d.selected and d.reason.startswith("whitened test passes"):
            warnings.append(f"{s} {name}: significant in the whitened test (log10 p {d.log10_p:.1f}) but the physical held-out rms "
                            f"does not fall (change {d.heldout_rms_change:+.3g} {unit}), so it is not named; the residual lives {where_text}")
    point = [n for n in _at_point(s, lin.theta_lin) if n not in force]  # demoting one of these restarts the pass
    while True:
        path, path_ols = _heldout_paths(kind, sd, sel, lin.theta_lin, order)
        worse = [k for k in range(len(order)) if order[k] not in force and not path[k + 1] < path[k]]
        if worse:
            k = worse[0]
            name = order[k]
            why = f"held-out rms does not fall when it is added ({path[k]:.5g} -> {path[k + 1]:.5g})"
            warn = (f"{s} {name}: significant in the whitened test but it does not lower the physical held-out rms "
                    f"({path[k]:.5g} -> {path[k + 1]:.5g} {unit}), so it is not named; the residual lives {where_text}")
            restart = _drop(name, point, order, decisions, warnings, why, warn)
            if restart is not None:
                return restart
            continue
        final_all = _joint_refit(kind, sd, lin, sel, order, base_all, huber)
        bad = [(E.implausibility(s, n, final_all.theta), n) for n in order if n not in force]
        bad = [b for b in bad if b[0] > 1.0]
        if bad:
            ratio, name = max(bad)
            lim = E.PLAUSIBLE_RANGE[(name, s)]
            est = E.params_from_theta(s, name, final_all.theta)
            why = f"implausible estimate {est} (beyond |{lim:g}| {E.UNITS[(name, s)]})"
            warn = (f"{s} {name}: misspecification - its estimate {est} lies {ratio:.3g}x beyond the plausible "
                    f"{lim:g} {E.UNITS[(name, s)]} of a real part, so it is not named: the model does not fit this "
                    f"recording there; the residual lives {where_text}")
            restart = _drop(name, point, order, decisions, warnings, why, warn)
            if restart is not None:
                return restart
            continue
        final_all, bands = pool_named(kind, s, sd.inp, fit_rows, final_all, order, pool)
        weak = _band_weak(s, final_all, bands, force, level)
        if weak:
            name = weak[0]
            sd_b = np.sqrt(np.asarray(bands[name]["tau2"]))
            why = (f"not significant once the disagreement of its frequency bands is counted "
                   f"(between-band sd {_fmt3(sd_b)} {E.UNITS[(name, s)]})")
            warn = (f"{s} {name}: its estimate differs between frequency bands of the motion (between-band sd "
                    f"{_fmt3(sd_b)} {E.UNITS[(name, s)]}), so with that spread in its interval it is not significant and "
                    f"is not named: physics the vocabulary lacks (translational acceleration, different sensor filters) "
                    f"moves it; the residual lives {where_text}")
            restart = _drop(name, point, order, decisions, warnings, why, warn)
            if restart is not None:
                return restart
            continue
        return Named(order, decisions, warnings, base_all, final_all, path, path_ols, bands or None)


def _joint_refit(kind: str, sd: SensorData, lin: Linearised, sel: Selection, order: list[str], base_all: RefitResult,
                 huber: float | None = 3.0) -> RefitResult:
    """The joint nonlinear refit of baseline + ``order`` from the linear step (a start far outside
    an effect's plausible range only misleads the solver: that effect starts from the linearisation
    point); the baseline alone when nothing is named."""
    s, nb = sd.sensor, E.N_BASE[kind]
    theta0 = sel.full[nb:] + lin.theta_lin
    beta0 = lin.beta + sel.full[:nb]
    for n in order:
        if E.implausibility(s, n, theta0) > 1.0:
            sl = E.slot(s, n)
            theta0[sl.start : sl.start + sl.size] = lin.theta_lin[sl.start : sl.start + sl.size]
    return refit(kind, s, beta0, theta0, order, sd.inp, sd.y, sel.fit_rows, sel.ars, sd.block, huber=huber) if order else base_all


def sensor_pass(kind: str, sd: SensorData, cfg: SelectConfig, n_tests: int, start: Start = Start(),
                meas: E.Inputs | None = None, force: tuple[str, ...] = ()) -> SensorResult | Relinearise | Retrim | DropOffset | Unskew:
    """Stages 1-5 once from ``start``: the :class:`SensorResult`, or the answer that another pass
    is needed (:class:`Relinearise`, :class:`Retrim`, :class:`DropOffset`, :class:`Unskew`).

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sd: the sensor's prepared data.
        cfg: test level and search settings.
        n_tests: Bonferroni count of the recording (candidates of all its sensors).
        start: where this pass starts.
        meas: reference inputs from the sensors' own outputs, for the attenuation of a pose-derived
            reference; None: no correction.
        force: effects estimated whatever the tests say; reported as estimates, not as discoveries.
    """
    level = cfg.alpha / n_tests
    off = coarse_offset(kind, sd, cfg, level, start, force)
    lin = linearise(kind, sd, off.tau_lin, start.edge_shift, 0.0 if off.skew_lin is None else off.skew_lin)
    sel = select_effects(kind, sd, cfg, level, off, lin, start, force)
    det = detectability(kind, sd, cfg, level, off, lin, sel, meas)
    named = name_effects(kind, sd, off, lin, sel, det, force, cfg.band_pool, level, cfg.huber)
    if isinstance(named, (DropOffset, Unskew)):
        return named
    order, final_all, decisions = named.order, named.final_all, dict(named.decisions)
    if start.relin is None and "time_offset" in order:
        tau_hat = float(final_all.theta[E.slot(sd.sensor, "time_offset").start])
        if abs(tau_hat - off.tau_lin) > 0.02 * float(sd.inp.dt):
            d0 = decisions["time_offset"]
            return Relinearise(tau_hat, d0 if isinstance(d0, Decision) else Decision(**d0))
    if start.edge_shift == 0.0 and "clock_skew" in order:
        dt = float(sd.inp.dt)
        shift = abs(float(final_all.theta[E.slot(sd.sensor, "clock_skew").start])) * 1e-6 * float(np.max(np.abs(np.asarray(sd.inp.tc))))
        # relinearised at the skew once it moves the ends a whole sample (linearised at 0 its second-order
        # remainder inflated the standard errors 15x at 500 ppm over 5 minutes, 1.9 samples); the Retrim pass's
        # edge_shift also trims the rows past the reference where they pass the time offset's 3-row margin
        if shift >= dt:
            skew = float(final_all.theta[E.slot(sd.sensor, "clock_skew").start])
            d0 = decisions["clock_skew"]
            return Retrim(shift, skew, d0 if isinstance(d0, Decision) else Decision(**d0))
    for c in force:  # estimates on request stay marked as such, whatever relinearisation added
        d = decisions.get(c)
        if d is not None and d.selected and not d.reason.startswith(FORCED):
            decisions[c] = d._replace(reason=f"{FORCED}; {d.reason}")
    frame_fit = final_all if order else None
    if kind == "affine" and not order:  # baseline standard errors for the rotation's interval
        base = named.base_all
        frame_fit = refit(kind, sd.sensor, base.beta, base.theta, [], sd.inp, sd.y, sel.fit_rows, sel.ars, sd.block, huber=cfg.huber)
    ars = sel.ars
    return SensorResult(
        sd.sensor, order, {k: v._asdict() for k, v in decisions.items()}, det.mds, off.warnings + det.warnings + named.warnings,
        named.base_all, final_all, sel.fit_rows, named.path, named.path_ols, sel.saturation, off.tau_lin,
        [a.order for a in ars], [a.sigma for a in ars], [a.theta for a in ars], frame_fit, named.bands,
    )


def diagnose_sensor(kind: str, sd: SensorData, cfg: SelectConfig, n_tests: int, meas: E.Inputs | None = None,
                    force: tuple[str, ...] = (), lag_hint: int | None = None) -> SensorResult:
    """Locate-name-refit for one sensor: :func:`sensor_pass` from the coarse offset; once more
    linearised at the refit time offset when one is named (linearised at 0, an offset of a sizeable
    fraction of a sample leaves a second-order remainder that other effects would otherwise absorb);
    once more linearised at a named clock skew that moves the ends a sample or more, without the end
    rows it moves past the reference's ends where they exceed the time offset's margin
    (:class:`Retrim`); once more linearised at
    a zero skew if the skew then fails the promise (:class:`Unskew`); and once more without a time
    offset when it fails the promise there.

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sd: the sensor's prepared data (:func:`~jaxcal.diagnose.prepare.prepare` or
            :func:`~jaxcal.diagnose.noref.prepare_noref`).
        cfg: test level and search settings.
        n_tests: Bonferroni count of the recording (candidates of all its sensors).
        meas: reference inputs from the sensors' own outputs
            (:func:`~jaxcal.diagnose.prepare.measured_inputs`), for the attenuation of a
            pose-derived reference; None: no correction.
        force: effects estimated whatever the tests say (``jaxcal align`` estimates the time offset
            and lever arm of every rig); reported as estimates, not as discoveries.
        lag_hint: the coarse lag (samples) another sensor on the same clock found; taken as this
            sensor's candidate.
    """
    start, dropped = Start(lag_hint=lag_hint), None
    out = sensor_pass(kind, sd, cfg, n_tests, start, meas, force)
    for _ in range(4):  # each answer comes at most once (the start it sets rules it out): five passes at most
        if isinstance(out, SensorResult):
            break
        if isinstance(out, Relinearise):
            start = start._replace(lag_hint=None, relin=(out.tau, out.decision))
        elif isinstance(out, Retrim):
            start = start._replace(edge_shift=out.shift, skew_lin=(out.skew, out.decision))
        elif isinstance(out, Unskew):  # the end rows stay trimmed (edge_shift), so no Retrim can follow
            start = start._replace(skew_lin=None)
        else:  # DropOffset: without a time offset, no Relinearise or DropOffset can follow
            start, dropped = Start(no_offset=True, edge_shift=start.edge_shift, skew_lin=start.skew_lin), out
        out = sensor_pass(kind, sd, cfg, n_tests, start, meas, force)
    assert isinstance(out, SensorResult), out
    if dropped is None:
        return out
    return out._replace(decisions={**out.decisions, "time_offset": dropped.decision._asdict()}, warnings=out.warnings + [dropped.warning])
