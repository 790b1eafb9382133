"""The diagnosis pipeline: prepare a recording, then per sensor locate -> name -> refit.

:func:`prepare` turns a :class:`jaxcal.recording.Recording` into
:class:`~jaxcal.diagnose.select.SensorData` per sensor: physical outputs via the datasheet
values, the reference motion (given, or derived from a pose with smoothing and decimation), the
temperature, validity, and contiguous time blocks for cross-validation.
:func:`diagnose_sensor` runs the coarse time-offset search, saturation check, iterated
noise-model + forward selection, detectability and confounding analysis, and the joint refits.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
from scipy import stats

from jaxcal.diagnose import effects as E
from jaxcal.diagnose import kinematics as K
from jaxcal.diagnose.band import HALF_POWER as BH
from jaxcal.diagnose.band import Band, choose_sigma
from jaxcal.diagnose.locate import breakdown
from jaxcal.diagnose.refit import RefitResult, refit
from jaxcal.diagnose.select import (
    Decision,
    SelectConfig,
    SensorData,
    attenuation,
    block_score_inflation,
    build_system,
    candidates,
    canonical_correlation,
    coarse_lag,
    critical_value,
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
from jaxcal.diagnose.whiten import apply_filter, choose_lambda, fill_index, fit_ar, gap_ok, reml_profile
from jaxcal.recording import Recording

__all__ = [
    "EXCITE",
    "Prepared",
    "require_recording",
    "split_blocks",
    "prepare",
    "measured_inputs",
    "SensorResult",
    "UNIT_OF",
    "FORCED",
    "diagnose_sensor",
    "diagnose_prepared",
    "diagnose_banded",
]

# Motion/conditions that excite each effect (used in warnings).
EXCITE = {
    "lever_arm": "angular acceleration and rates about several axes (a constant rate makes a lever arm look like a bias)",
    "g_sensitivity": "orientations that put gravity along each axis",
    "misalignment": "inputs on every axis",
    "scale_nonlinearity": "large inputs of both signs on every axis",
    "time_offset": "changing inputs (angular acceleration); with none a time offset is unobservable",
    "temperature_bias": "a temperature change that is not monotonic in time (heat and cool)",
    "temperature_scale": "a temperature change while the inputs are large",
    "bias_drift": "a longer recording",
}


class Prepared(NamedTuple):
    """A recording ready for diagnosis: per-sensor data, time, temperature, notes."""

    sensors: dict[str, SensorData]
    t: np.ndarray
    temp: np.ndarray | None
    dt: float
    notes: list[str]
    from_pose: bool = False  # reference derived from a (noisy) pose: regressors carry its noise
    band: Band | None = None  # the coherent band that chose the smoothing (pose_sigma=None)
    pose_sigma: float | None = None  # the Gaussian width that set the decimation (s), pose-derived reference
    sigma_by_sensor: dict | None = None  # each sensor's kernel width (s), pose-derived reference


def require_recording(rec: Recording) -> None:
    """Refuse anything but a :class:`~jaxcal.recording.Recording` (e.g. a plain dict of arrays):
    ``prepare`` and ``align_recording`` read its fields by name.

    Raises:
        TypeError: ``rec`` is not a :class:`~jaxcal.recording.Recording`.
    """
    if not isinstance(rec, Recording):
        raise TypeError(f"diagnose takes a jaxcal.recording.Recording, got {type(rec).__name__} "
                        "(build one with jaxcal.recording.recording_from_dict)")


def _unit(rec: Recording, sensor: str) -> str:
    """``"LSB"`` or the physical unit of ``sensor``'s output in ``rec``."""
    return rec.acc_unit if sensor == "acc" else rec.gyr_unit


def _spec(rec: Recording, sensor: str, y: np.ndarray, x: np.ndarray, rows: np.ndarray, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    if _unit(rec, sensor) != "LSB":
        return np.ones(3), np.zeros(3)
    s, b = (rec.acc_lsb_per_g, rec.acc_bias_lsb) if sensor == "acc" else (rec.gyr_lsb_per_rads, rec.gyr_bias_lsb)
    if s is not None:
        return np.broadcast_to(np.asarray(s, float), (3,)).copy(), np.broadcast_to(np.asarray(b if b is not None else 0.0, float), (3,)).copy()
    sc, bi = np.zeros(3), np.zeros(3)
    for i in range(3):
        a = np.stack([x[rows, i], np.ones(rows.sum())], 1)
        sc[i], bi[i] = np.linalg.lstsq(a, y[rows, i], rcond=None)[0]
    notes.append(f"{sensor}: no datasheet values; LSB converted with a per-axis scale/bias fit")
    return sc, bi


def _reference_ok(rec: Recording, t: np.ndarray, notes: list[str]) -> np.ndarray:
    """(N,) bool: where the recording's reference may be used. A reader's ``ref_valid`` marking
    is honoured, and when the original pose track's times ``gt_t`` are kept, samples interpolated
    across a missing track sample are dropped too (:func:`jaxcal.diagnose.kinematics.reference_gap_mask`)."""
    ok = np.ones(len(t), bool)
    rv = rec.ref_valid
    if rv is not None:
        rv = np.asarray(rv).astype(bool).reshape(-1)
        if rv.shape != ok.shape:
            raise ValueError(f"'ref_valid' has {rv.size} values for {len(t)} samples")
        ok &= rv
    gt_t = rec.gt_t
    if gt_t is not None and np.ndim(gt_t) == 1 and len(gt_t) >= 2:
        ok &= K.reference_gap_mask(t, gt_t)
    if not ok.all():
        notes.append(f"reference gaps: {int((~ok).sum())} of {len(t)} samples have no trustworthy reference "
                     "(the reader's ref_valid, and interpolation across a missing pose sample); they and the kernel around them are dropped")
    return ok


def split_blocks(n: int, n_blocks: int = 8) -> np.ndarray:
    """Block id (N,) of ``n_blocks`` contiguous equal time blocks (cross-validation folds).

    Args:
        n: number of samples.
        n_blocks: number of blocks (cross-validation folds).
    """
    return np.minimum((np.arange(n) * n_blocks) // n, n_blocks - 1)


def _choose_band(t, dt, pos, quat, raw, rec: Recording) -> Band:
    """The smoothing of a pose-derived reference from the coherence of sensor and reference
    (:func:`jaxcal.diagnose.band.choose_sigma`), measured against a reference derived with a
    kernel of about one sample (nearly unsmoothed) in the spec's physical units."""
    ref0 = K.reference_from_pose(t, pos, quat, max(dt, 1e-4))
    valid = ref0["valid"]
    pairs = {}
    for s, key in (("gyr", "gyr_ref"), ("acc", "acc_ref")):
        if raw[s] is None:
            continue
        y = raw[s]
        if _unit(rec, s) == "LSB":
            sc, bi = _spec(rec, s, y, ref0[key], valid, [])
            y = (y - bi) / sc
        pairs[s] = (y, ref0[key])
    lag = 0
    if "gyr" in pairs:  # a clock offset decorrelates Welch windows: align the streams first (|rate| is frame-free)
        y, x = pairs["gyr"]
        lag = coarse_lag(np.linalg.norm(y, axis=1)[:, None], np.linalg.norm(x, axis=1)[:, None], valid, int(min(1.0 / dt, len(t) // 10)))
    if lag:
        sh = lambda a: np.roll(a, lag, axis=0)  # noqa: E731 - x(t - lag), as the sensor reads it
        pairs = {s: (y, sh(x)) for s, (y, x) in pairs.items()}
        valid = valid & sh(valid)
        valid[: abs(lag)] = valid[-abs(lag) :] = False
    return choose_sigma(pairs, valid, dt, lag_s=lag * dt)


def prepare(rec: Recording, pose_sigma: float | None = 0.02, ref_sigma_samples: float = 0.0, n_blocks: int = 8,
            band: Band | None = None) -> Prepared:
    """Build per-sensor :class:`SensorData` from a recording (see module docstring).

    With ``gyr_ref``/``acc_ref`` given, angular acceleration is the five-point derivative of
    ``gyr_ref`` (or a Gaussian-smoothed one of ``ref_sigma_samples`` samples if > 0). With only a pose, the reference is derived with a Gaussian
    of ``pose_sigma`` s (:func:`jaxcal.diagnose.kinematics.reference_from_pose`), the sensor outputs
    are smoothed by the same kernel and everything is decimated by ``round(pose_sigma / dt)``;
    ``pose_sigma=None`` chooses the width from the coherence of sensor and reference
    (:mod:`jaxcal.diagnose.band`: the band where the reference is trustworthy); ``band``: an already
    chosen :class:`~jaxcal.diagnose.band.Band` to report beside a fixed ``pose_sigma``.

    Args:
        rec: the recording (physical units, or LSB with datasheet values).
        pose_sigma: Gaussian width (s) of a pose-derived reference; None chooses it by coherence.
        ref_sigma_samples: with ``gyr_ref`` given, Gaussian width (samples) of its derivative;
            0 uses the five-point difference.
        n_blocks: contiguous time blocks for cross-validation.
        band: an already chosen :class:`~jaxcal.diagnose.band.Band`, reported beside a fixed ``pose_sigma``.
    """
    require_recording(rec)
    notes: list[str] = []
    t = np.asarray(rec.t, np.float64)
    if t.ndim != 1 or len(t) < 100:
        raise ValueError("diagnose needs a 't' array of at least 100 samples")
    dt = float(np.median(np.diff(t)))
    acc = rec.acc
    gyr = rec.gyr
    temp = rec.temp
    acc_ref, gyr_ref = rec.acc_ref, rec.gyr_ref
    pos, quat = rec.pos_ref, rec.quat_ref
    raw = {"acc": None if acc is None else np.asarray(acc, np.float64), "gyr": None if gyr is None else np.asarray(gyr, np.float64)}
    ref_ok = _reference_ok(rec, t, notes)
    if pos is not None and quat is not None:
        pos = np.where(ref_ok[:, None], np.asarray(pos, np.float64), np.nan)
        quat = np.where(ref_ok[:, None], np.asarray(quat, np.float64), np.nan)
    decim = 1
    per_sensor: dict = {}  # pose-derived reference per sensor (its own kernel width): (f, w, wdot)
    if gyr_ref is None and pos is not None and quat is not None:
        if pose_sigma is None:
            band = _choose_band(t, dt, pos, quat, raw, rec)
            pose_sigma = band.sigma_s
            sig = dict(band.sigma_by_sensor)
        else:
            sig = {s: float(pose_sigma) for s in raw if raw[s] is not None}
        valid = np.ones(len(t), bool)
        for s in sig:
            ref = K.reference_from_pose(t, pos, quat, sig[s])
            per_sensor[s] = (ref["acc_ref"], ref["gyr_ref"], ref["wdot_ref"], ref["ww_ref"].reshape(-1, 9))
            valid &= ref["valid"]
            raw[s] = K._conv(raw[s], K.gaussian_kernels(sig[s], dt)[0])
        f, w, wdot, _ = per_sensor["gyr" if "gyr" in per_sensor else "acc"]
        h0 = K.gaussian_kernels(pose_sigma, dt)[0]
        if temp is not None:
            temp = K._conv(np.asarray(temp, np.float64)[:, None], h0)[:, 0]
        decim = max(1, int(round(pose_sigma / dt)))
        notes.append("reference derived from the pose (Gaussian " + ", ".join(f"{s} sigma {v * 1e3:.0f} ms, band 0-{BH / v:.1f} Hz" for s, v in sig.items())
                     + f"); outputs smoothed alike, decimated by {decim}")
        if band is not None and pose_sigma == band.sigma_s:
            notes.append("band: " + band.reason)
        smoothed = True
    else:
        if gyr_ref is None and acc_ref is None:
            raise ValueError("diagnose needs reference motion: gyr_ref/acc_ref or pos_ref+quat_ref")
        smoothed = False
        w = np.zeros((len(t), 3)) if gyr_ref is None else np.asarray(gyr_ref, np.float64)
        f = None if acc_ref is None else np.asarray(acc_ref, np.float64)
        if f is None:
            if acc is not None:
                notes.append("no acc_ref: accelerometer not diagnosed; g-sensitivity uses the measured acc")
            f = np.zeros((len(t), 3))
        wdot = K.derivative5(w, dt) if ref_sigma_samples <= 0 else K.derivative(w, ref_sigma_samples * dt, dt)
        valid = np.isfinite(w).all(1) & np.isfinite(f).all(1) & ref_ok
    sl = slice(None, None, decim)
    t, f, w, wdot, valid = t[sl], f[sl], w[sl], wdot[sl], valid[sl]
    temp = None if temp is None else np.asarray(temp, np.float64)[sl]
    for s in raw:
        if raw[s] is not None:
            raw[s] = raw[s][sl]
    dt = dt * decim
    n = len(t)
    block = split_blocks(n, n_blocks)
    dT = np.zeros(n) if temp is None else temp - np.mean(temp[valid])
    tc = t - 0.5 * (t[0] + t[-1])
    # bridge invalid stretches by linear interpolation (not zeros): the band-limited time shift
    # and its derivative would otherwise ring at every gap edge
    idx = np.arange(n)

    def bridge(a):
        if valid.all() or not valid.any():
            return np.nan_to_num(a)
        return np.stack([np.interp(idx, idx[valid], a[valid, c]) for c in range(a.shape[1])], 1)

    f, w, wdot = bridge(f), bridge(w), bridge(wdot)
    per_sensor = {s: tuple(bridge(a[sl]) for a in v) for s, v in per_sensor.items()}
    out: dict[str, SensorData] = {}
    for s in ("acc", "gyr"):
        if raw[s] is None:
            continue
        if s == "acc" and acc_ref is None and gyr_ref is not None:
            continue
        if s == "gyr" and gyr_ref is None and pos is None:
            continue
        ww = None
        if s in per_sensor:  # pose-derived, with this sensor's own kernel width
            f, w, wdot, ww = per_sensor[s]
            ww = ww.reshape(-1, 3, 3)
        x = f if s == "acc" else w
        if s == "gyr" and acc_ref is None and raw["acc"] is not None and pos is None:
            sca, bia = _spec(rec, "acc", raw["acc"], f, valid, notes)
            f = (raw["acc"] - bia) / sca
        sc, bi = _spec(rec, s, raw[s], x, valid, notes)
        y = (raw[s] - bi) / sc
        is_counts = (not smoothed) and _unit(rec, s) == "LSB"
        inp = E.Inputs(f, w, wdot, tc, dT, np.asarray(dt), ww)
        out[s] = SensorData(s, y, raw[s] if is_counts else None, sc, bi, inp, valid.copy(), block, temp is not None)
    return Prepared(out, t, temp, dt, notes, smoothed, band, pose_sigma if smoothed else None,
                    {s: float(v) for s, v in (sig.items() if smoothed else ())})


def measured_inputs(prep: Prepared, s: str) -> E.Inputs | None:
    """The reference inputs of sensor ``s`` with the motion replaced by the sensors' own outputs
    (acc for ``f``, gyro for ``w`` and, differentiated, ``wdot``); for the errors-in-variables
    attenuation of pose-derived references (:func:`jaxcal.diagnose.select.attenuation`). None when
    the reference is not pose-derived or a sensor is missing.

    Args:
        prep: a prepared recording.
        s: the sensor, ``"acc"`` or ``"gyr"``.
    """
    if not prep.from_pose or "acc" not in prep.sensors or "gyr" not in prep.sensors:
        return None
    inp = prep.sensors[s].inp
    w = np.asarray(prep.sensors["gyr"].y)
    return inp._replace(f=np.asarray(prep.sensors["acc"].y), w=w, wdot=K.derivative5(w, prep.dt), ww=None)


class SensorResult(NamedTuple):
    """Everything the report needs about one sensor."""

    sensor: str
    selected: list[str]
    decisions: dict
    mds: dict
    warnings: list[str]
    base_all: RefitResult  # baseline fitted on all fit rows
    final_all: RefitResult  # baseline + named effects, joint nonlinear refit on all fit rows
    fit_rows: np.ndarray
    heldout_path: list[float]  # held-out RMS, noise-model (GLS) fits, as effects are added
    heldout_path_ols: list[float]  # the same with least-squares fits on the physical residual
    saturation: dict | None
    tau_lin: float
    ar_orders: list[int]
    ar_sigma: list[float]
    ar_theta: list[float]
    frame_fit: RefitResult | None = None  # the refit whose covariance gives the affine frame split


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


def _theta_with_tau(sensor: str, tau: float) -> np.ndarray:
    th = np.zeros(E.N_THETA[sensor])
    th[E.slot(sensor, "time_offset").start] = tau
    return th


def _edge_rows(valid: np.ndarray, tau: float, dt: float) -> np.ndarray:
    m = valid.copy()
    e = int(np.ceil(abs(tau) / dt)) + 3
    m[:e] = False
    m[-e:] = False
    return m


def _baseline_resid(kind, sd, theta, rows):
    x, z = linearize_baseline(kind, sd, E.identity_beta(kind), theta)
    nb = E.N_BASE[kind]
    a = x[rows].reshape(-1, nb)
    d = np.linalg.lstsq(a, z[rows].reshape(-1), rcond=None)[0]
    return z - x @ d, E.identity_beta(kind) + d


def _whitened_rss(resid, ars, rows):
    tot = 0.0
    fi = fill_index(rows)
    for i in range(3):
        ok = gap_ok(rows, ars[i].memory)
        u = apply_filter(resid[fi, i], ars[i])[ok]
        tot += float(u @ u)
    return tot


def _refine_tau(kind: str, sd: SensorData, tau_c: float, ars, rows: np.ndarray, dt: float) -> float:
    """Sub-sample refinement of a coarse time offset: whitened baseline RSS at ``tau_c + k dt / 2``
    (k = -2..2), parabola through the smallest value and its neighbours, clamped to +-1 sample."""
    s = sd.sensor
    ks = np.arange(-2, 3) * 0.5
    v = np.array([_whitened_rss(_baseline_resid(kind, sd, _theta_with_tau(s, tau_c + k * dt), rows)[0], ars, rows) for k in ks])
    i = int(np.clip(np.argmin(v), 1, len(ks) - 2))
    a, b, c = v[i - 1], v[i], v[i + 1]
    den = a - 2 * b + c
    off = 0.5 * (a - c) / den if den > 0 else 0.0
    return float(tau_c + (ks[i] + 0.5 * np.clip(off, -1.0, 1.0)) * dt)


def diagnose_sensor(kind: str, sd: SensorData, cfg: SelectConfig, n_tests: int, _relin: tuple | None = None,
                    meas: E.Inputs | None = None, force: tuple[str, ...] = (), lag_hint: int | None = None,
                    _no_offset: bool = False) -> SensorResult:
    """Locate-name-refit for one sensor.

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sd: the sensor's prepared data (:func:`prepare`).
        cfg: test level and search settings.
        n_tests: Bonferroni count of the recording (candidates of all its sensors).
        _relin: internal: ``(tau, decision)`` of the relinearised pass (below).
        meas: reference inputs from the sensors' own outputs (:func:`measured_inputs`), for the
            attenuation of a pose-derived reference; None: no correction.
        force: effects estimated whatever the tests say (``jaxcal align`` estimates the time offset
            and lever arm of every rig); reported as estimates, not as discoveries.
        lag_hint: the coarse lag (samples) another sensor on the same clock found; taken as this
            sensor's candidate.
        _no_offset: internal: drop the time offset from the candidates.

    The promise of the report, enforced here: every named effect lowers the physical held-out rms
    that the report prints (an effect that does not is demoted to ``rejected`` with a warning that
    says where the residual lives), and no named estimate lies outside its plausible range
    (:data:`jaxcal.diagnose.effects.PLAUSIBLE_RANGE`; outside, it is a misspecification warning).

    When a time offset is named, the selection is repeated once with the model relinearised at the
    refit offset (``_relin = (tau, decision)``, internal): linearised at 0, an offset of a sizeable
    fraction of a sample leaves a second-order remainder that other effects would otherwise absorb.
    """
    s = sd.sensor
    level = cfg.alpha / n_tests
    dt = float(sd.inp.dt)
    warnings: list[str] = []
    cands = candidates(kind, sd)
    if _no_offset:  # internal: a time offset was tested and did not lower the held-out rms
        cands = [c for c in cands if c != "time_offset"]
        lag_hint = None
    pre: list[str] = []
    decisions: dict = {}
    # coarse time offset: cross-correlation over +-max_lag_s, then a likelihood-ratio check
    x_in = np.asarray(sd.inp.f if s == "acc" else sd.inp.w)
    max_lag = int(min(cfg.max_lag_s / dt, len(sd.y) // 10))
    lag = 0 if _no_offset else coarse_lag(sd.y, x_in, sd.valid, max_lag)
    if lag_hint is not None and abs(lag_hint) <= max_lag:
        # the other sensor runs on the same clock and its lag is the sharper: an accelerometer's
        # cross-correlation is dominated by slow gravity, and effects the baseline leaves out (a lever
        # arm at high rates) swamp any comparison of lags by baseline fit; the likelihood-ratio check
        # below still decides whether this sensor has the offset at all
        lag = int(lag_hint)
    tau_lin = 0.0
    coarse = None
    if _relin is not None:
        tau_lin = float(_relin[0])
        pre.append("time_offset")
        lag = 0
    if lag != 0:
        tau_c = lag * dt
        rows = _edge_rows(sd.valid, tau_c, dt)
        r0, _ = _baseline_resid(kind, sd, _theta_with_tau(s, 0.0), rows)
        r1, _ = _baseline_resid(kind, sd, _theta_with_tau(s, tau_c), rows)
        ars = [fit_ar(r1[:, i], rows , cfg.max_ar_order) for i in range(3)]
        stat = _whitened_rss(r0, ars, rows) - _whitened_rss(r1, ars, rows)
        if stat > critical_value(level, 1):
            coarse = (float(stat), float(stats.chi2.logsf(stat, 1) / np.log(10)))
            tau_lin = _refine_tau(kind, sd, tau_c, ars, rows, dt)
            pre.append("time_offset")
            warnings.append(f"{s}: coarse search found a large time offset of {tau_lin * 1e3:.1f} ms ({lag} samples, refined to a fraction of a sample); refined below")
    pre += [c for c in force if c not in pre and c in cands]
    fit_rows = _edge_rows(sd.valid, tau_lin, dt)
    theta_lin = _theta_with_tau(s, tau_lin)
    resid, beta = _baseline_resid(kind, sd, theta_lin, fit_rows)
    x, z = linearize(kind, sd, beta, theta_lin)
    plateau = saturation_plateau(sd.raw)
    sat_info = None
    prev = None
    nb = E.N_BASE[kind]
    # Noise model from the residual of the largest model (baseline + every candidate, plain least
    # squares): a concealed effect left in the residual would otherwise be learnt as "coloured
    # noise" by the AR/random-walk filter and whitened away (estimates shrink towards zero). A
    # random walk is more than any candidate regressor, so what is left still shows it.
    cs = list(range(nb)) + [j for c in cands for j in group_columns(kind, s, c)]

    def noise_model(rows):
        a_ = x[rows][:, :, cs].reshape(-1, len(cs))
        sol = np.linalg.lstsq(a_, z[rows].reshape(-1), rcond=None)[0]
        r_full = z - x[:, :, cs] @ sol
        profs = [reml_profile(r_full[:, i], rows, X=x[:, i, cs]) for i in range(3)]
        lams = choose_lambda(profs, pooled=cfg.rw_pooled, slack=cfg.rw_slack) if cfg.random_walk else [0.0] * 3
        return [fit_ar(r_full[:, i], rows, cfg.max_ar_order, lam=lams[i]) for i in range(3)]

    ars_fixed = noise_model(fit_rows)
    for it in range(cfg.max_passes):
        ars = ars_fixed
        if plateau is not None and it == 0:
            lim, pmask = plateau
            # predict the plateau from a baseline fitted without it: clipped samples pull a fit that
            # includes them towards the limit and hide the clipping they are evidence of
            r_np, _ = _baseline_resid(kind, sd, theta_lin, fit_rows & ~pmask)
            st = saturation_stat(sd, sd.y - r_np, r_np, ars, fit_rows, lim)
            lp = float(stats.chi2.logsf(max(st, 0.0), 1) / np.log(10))
            sel = lp < np.log10(level)
            sat_info = {"limit": lim, "n_clipped": int(pmask.sum()), "stat": st, "log10_p": lp, "selected": bool(sel)}
            if sel:
                fit_rows = fit_rows & ~pmask
                ars = ars_fixed
        S = build_system(x, z, ars, fit_rows, sd.block)
        selected, decisions, th, cols = forward_select(S, kind, s, cands, pre, level)
        full = np.zeros(x.shape[2])
        full[cols] = th
        resid = z - x @ full
        # re-level: biases the whitening cannot see (random-walk noise model) from the plain mean
        off = resid[fit_rows].mean(0)
        resid = resid - off
        full[nb - 3 : nb] += off  # the bias columns of both baselines
        if prev == selected:
            break
        prev = selected
    if coarse is not None:
        decisions["time_offset"] = Decision("time_offset", coarse[0], 1, coarse[1], float("nan"), True, "selected (coarse search)")
    for c in force:
        if c in pre and c not in decisions and c in cands:
            decisions[c] = Decision(c, float("nan"), len(group_columns(kind, s, c)), float("nan"), float("nan"), True,
                                    FORCED)
    if _relin is not None:
        decisions["time_offset"] = _relin[1]._replace(reason=_relin[1].reason + f"; model relinearised at the refit offset {tau_lin * 1e3:.2f} ms and the other effects reselected")
    # detectability and confounding, relative to the baseline
    base = list(range(nb))
    mds = {}
    grams = None if meas is None else cross_gram(x, linearize(kind, sd._replace(inp=meas), beta, theta_lin)[0], ars, fit_rows)
    mds_infl: dict[str, np.ndarray] = {}
    for c in cands:
        F = projected_information(S, base, group_columns(kind, s, c))
        att = None
        if grams is not None:
            att = attenuation(*grams, base, group_columns(kind, s, c))
            infl = block_score_inflation(S, base, group_columns(kind, s, c), cols, th)
            F = F * (att / infl)[:, None] * (att / infl)[None, :]
            mds_infl[c] = infl
            if float(infl.max()) > 1.5:
                warnings.append(
                    f"{s} {c}: its score varies between time blocks {float(infl.max()):.1f}x more than the noise model allows "
                    "(real-data misspecification); detectable sizes are scaled by this block-robust factor"
                )
            if float(att.min()) < 0.7:
                warnings.append(
                    f"{s} {c}: its regressor comes from the pose-derived reference, whose noise dilutes it (attenuation "
                    f"{float(att.min()):.2f}-{float(att.max()):.2f}); detectable sizes are scaled by 1/attenuation (the joint "
                    "refit, run to convergence, is not diluted)"
                )
        comp, worst = minimum_detectable(F, level, cfg.power)
        mds[c] = {"components": comp.tolist(), "worst": worst, "min": float(comp.min()), "fisher": F.tolist(),
                  "lambda_star": detectable_noncentrality(level, F.shape[0], cfg.power)}
        if att is not None:
            mds[c]["attenuation"] = att.tolist()
            mds[c]["block_inflation"] = mds_infl[c].tolist()
        if c.startswith("temperature") and np.ptp(np.asarray(sd.inp.dT)[fit_rows]) == 0:
            warnings.append(  # a constant temp channel is no temperature channel: no size to report
                f"{s} {c}: not testable - the recording has no temperature channel that changes (temp is constant); "
                f"needs {EXCITE[c]}"
            )
        elif (c, s) in E.PLAUSIBLE and float(np.median(comp)) > E.PLAUSIBLE[(c, s)]:
            warnings.append(
                f"{s} {c}: not excited - smallest detectable size {float(np.median(comp)):.3g} {E.UNITS[(c, s)]} "
                f"exceeds a plausible {E.PLAUSIBLE[(c, s)]:.3g}; needs {EXCITE[c]}"
            )
    if sat_info is not None or sd.raw is not None:
        pred = sd.y - resid
        mds["saturation"] = {"depth_lsb": saturation_mds(sd, pred, ars, fit_rows, level, cfg.power),
                             "predicted_peak_lsb": float(np.max(np.abs((pred * sd.spec_scale + sd.spec_bias)[fit_rows])))}
    confounded: dict[str, list[str]] = {}
    for i, a in enumerate(cands):
        for b in cands[i + 1 :]:
            rho = canonical_correlation(S, base, group_columns(kind, s, a), group_columns(kind, s, b))
            if rho > cfg.confound_threshold:
                confounded.setdefault(a, []).append(b)
                confounded.setdefault(b, []).append(a)
                hint = EXCITE.get(a, "") if a.startswith("temperature") or b.startswith("temperature") else EXCITE.get(b, "")
                if {a, b} == {"temperature_bias", "bias_drift"}:
                    hint = "the temperature changes monotonically with time, so a temperature coefficient and a bias drift look alike; a heat-and-cool cycle separates them"
                warnings.append(f"{s}: {a} and {b} are confounded in this recording (canonical correlation {rho:.3f}); the data cannot tell them apart - {hint}")
    for c in confounded:
        if c in decisions:
            decisions[c] = decisions[c]._replace(reason=decisions[c].reason + f"; confounded with {', '.join(confounded[c])}")
    order = [c for c in selected]
    fixed = set(force)  # effects estimated on request are estimates, not names: not gated
    r_base, b_base = _baseline_resid(kind, sd, np.zeros(E.N_THETA[s]), fit_rows)
    zt = np.zeros(E.N_THETA[s])
    base_all = RefitResult(b_base, zt, np.zeros(nb), zt, float("nan"), r_base)
    where_text = _where(r_base, fit_rows, sd, dt)
    for name, d in decisions.items():
        if not d.selected and d.reason.startswith("whitened test passes"):
            warnings.append(f"{s} {name}: significant in the whitened test (log10 p {d.log10_p:.1f}) but the physical held-out rms "
                            f"does not fall (change {d.heldout_rms_change:+.3g} {UNIT_OF[s]}), so it is not named; the residual lives {where_text}")
    while True:
        path = heldout_rms_path(S, kind, s, order)
        path_ols = heldout_rms_path(S, kind, s, order, fit="ols")
        if tau_lin != 0.0:
            # baseline held-out rms at zero time offset (the path starts at the linearisation point)
            # linearised at the zero-offset baseline fit: a random-walk noise model annihilates the bias
            # columns, so starting from unit scale / zero bias would leave the whole bias in the residual
            _, beta_z = _baseline_resid(kind, sd, np.zeros(E.N_THETA[s]), fit_rows)
            xb, zb = linearize_baseline(kind, sd, beta_z, np.zeros(E.N_THETA[s]))
            Sb = build_system(xb, zb, ars, fit_rows, sd.block)
            path[0] = heldout_rms_path(Sb, kind, s, [])[0]
            path_ols[0] = heldout_rms_path(Sb, kind, s, [], fit="ols")[0]
        # the promise: every named effect lowers the printed held-out rms, step by step
        worse = [k for k in range(len(order)) if order[k] not in fixed and not path[k + 1] < path[k]]
        if worse:
            k = worse[0]
            name = order.pop(k)
            why = f"held-out rms does not fall when it is added ({path[k]:.5g} -> {path[k + 1]:.5g})"
            warn = (f"{s} {name}: significant in the whitened test but it does not lower the physical held-out rms "
                    f"({path[k]:.5g} -> {path[k + 1]:.5g} {UNIT_OF[s]}), so it is not named; the residual lives {where_text}")
            if name == "time_offset" and tau_lin != 0.0:
                # the model is linearised at that offset: diagnose again without one
                res = diagnose_sensor(kind, sd, cfg, n_tests, None, meas, force, None, _no_offset=True)
                res.decisions["time_offset"] = _demote(decisions[name], why)._asdict()
                res.warnings.append(warn)
                return res
            decisions[name] = _demote(decisions[name], why)
            warnings.append(warn)
            continue
        theta0 = full[nb:] + theta_lin
        beta0 = beta + full[:nb]
        for n in order:  # a linearised start far outside the plausible range only misleads the solver
            if E.implausible(s, n, theta0) > 1.0:
                sl = E.slot(s, n)
                theta0[sl.start : sl.start + sl.size] = theta_lin[sl.start : sl.start + sl.size]
        final_all = refit(kind, s, beta0, theta0, order, sd.inp, sd.y, fit_rows, ars, sd.block) if order else base_all
        bad = [(E.implausible(s, n, final_all.theta), n) for n in order if n not in force]
        bad = [b for b in bad if b[0] > 1.0]
        if bad:
            ratio, name = max(bad)
            order.remove(name)
            lim = E.PLAUSIBLE_RANGE[(name, s)]
            est = E.params_from_theta(s, name, final_all.theta)
            decisions[name] = _demote(decisions.get(name), f"implausible estimate {est} (beyond |{lim:g}| {E.UNITS[(name, s)]})", name)
            warnings.append(f"{s} {name}: misspecification - its estimate {est} lies {ratio:.3g}x beyond the plausible "
                            f"{lim:g} {E.UNITS[(name, s)]} of a real part, so it is not named: the model does not fit this "
                            f"recording there; the residual lives {where_text}")
            continue
        break
    if _relin is None and "time_offset" in order:
        tau_hat = float(final_all.theta[E.slot(s, "time_offset").start])
        if abs(tau_hat - tau_lin) > 0.02 * dt:
            d0 = decisions["time_offset"]
            return diagnose_sensor(kind, sd, cfg, n_tests, (tau_hat, d0 if isinstance(d0, Decision) else Decision(**d0)), meas, force)
    for c in force:  # estimates on request stay marked as such, whatever relinearisation added
        d = decisions.get(c)
        if d is not None and d.selected and not d.reason.startswith(FORCED):
            decisions[c] = d._replace(reason=f"{FORCED}; {d.reason}")
    frame_fit = final_all if order else None
    if kind == "affine" and not order:  # baseline standard errors for the rotation's interval
        frame_fit = refit(kind, s, b_base, zt, [], sd.inp, sd.y, fit_rows, ars, sd.block)
    return SensorResult(
        s, order, {k: v._asdict() for k, v in decisions.items()}, mds, warnings, base_all, final_all, fit_rows, path, path_ols,
        sat_info, tau_lin, [a.order for a in ars], [a.sigma for a in ars], [a.theta for a in ars], frame_fit,
    )


def diagnose_prepared(prep: Prepared, kind: str, cfg: SelectConfig = SelectConfig(),
                      force: Mapping[str, tuple[str, ...]] | None = None) -> dict[str, SensorResult]:
    """:func:`diagnose_sensor` for every sensor of a :class:`Prepared` recording (one Bonferroni
    family over all of them); ``force`` per sensor as in :func:`diagnose_sensor`. The gyroscope
    runs first and its coarse clock offset guides the accelerometer's search.

    Args:
        prep: a prepared recording (:func:`prepare`).
        kind: baseline, ``"diag"`` or ``"affine"``.
        cfg: test level and search settings.
        force: ``{sensor: effect names}`` estimated whatever the tests say; None: none.
    """
    n_tests = sum(len(candidates(kind, sd)) + (sd.raw is not None) for sd in prep.sensors.values())
    force = dict(force or {})
    out: dict[str, SensorResult] = {}
    hint = None
    for s in sorted(prep.sensors, key=lambda k: k != "gyr"):  # the gyroscope first: its clock offset is the sharper
        out[s] = diagnose_sensor(kind, prep.sensors[s], cfg, n_tests, meas=measured_inputs(prep, s), force=tuple(force.get(s, ())),
                                 lag_hint=hint)
        if s == "gyr" and out[s].tau_lin != 0.0:
            hint = int(round(out[s].tau_lin / prep.dt))
    return {s: out[s] for s in prep.sensors}


def diagnose_banded(rec: Recording, kind: str, cfg: SelectConfig = SelectConfig(), force: Mapping[str, tuple[str, ...]] | None = None,
                    pose_sigma: float | None = None) -> tuple[dict[str, Prepared], dict[str, SensorResult]]:
    """Prepare and diagnose a recording, each sensor in its own trusted band.

    With a pose-derived reference and ``pose_sigma=None``, :mod:`jaxcal.diagnose.band` may give
    the accelerometer a wider kernel than the gyroscope (the position's second derivative is
    noisier than the rotation's first); each sensor is then prepared with its own kernel and
    decimation and diagnosed there, the gyroscope first (its clock offset guides the
    accelerometer's search). Returns ``({sensor: Prepared},
    {sensor: SensorResult})``; one shared :class:`Prepared` when a single kernel serves both.

    Args:
        rec: the recording.
        kind: baseline, ``"diag"`` or ``"affine"``.
        cfg: test level and search settings.
        force: ``{sensor: effect names}`` estimated whatever the tests say; None: none.
        pose_sigma: Gaussian width (s) of a pose-derived reference; None chooses it per sensor.
    """
    prep = prepare(rec, pose_sigma=pose_sigma)
    if not prep.sensors:
        raise ValueError("no sensor with a matching reference to diagnose")
    sig = prep.sigma_by_sensor or {}
    if prep.band is None or len(set(sig.values())) <= 1:
        res = diagnose_prepared(prep, kind, cfg, force)
        return {s: prep for s in res}, res
    force = dict(force or {})
    n_tests = sum(len(candidates(kind, sd)) + (sd.raw is not None) for sd in prep.sensors.values())
    preps: dict[str, Prepared] = {}
    out: dict[str, SensorResult] = {}
    for s in sorted(prep.sensors, key=lambda k: k != "gyr"):
        ps = prep if sig[s] == prep.pose_sigma else prepare(rec, pose_sigma=sig[s], band=prep.band)
        ps = ps._replace(band=prep.band, sigma_by_sensor=sig)
        hint = None
        if s == "acc" and "gyr" in out and out["gyr"].tau_lin != 0.0:
            hint = int(round(out["gyr"].tau_lin / ps.dt))
        preps[s] = ps
        out[s] = diagnose_sensor(kind, ps.sensors[s], cfg, n_tests, meas=measured_inputs(ps, s), force=tuple(force.get(s, ())),
                                 lag_hint=hint)
    return {s: preps[s] for s in prep.sensors}, {s: out[s] for s in prep.sensors}
