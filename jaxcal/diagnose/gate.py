"""The reference gate of ``align`` and ``diagnose``: does the reference explain the sensor at all?

A reference that contradicts the IMU (random or frozen quaternions, a clock seconds off, positions
in millimetres labelled metres, quaternions in the wrong component order) still lets a least-squares
fit report a confident number: a gyro scale of 0.0006, a lever arm of 1716 mm. Two checks stand
before any estimate is reported or any model written:

1. :func:`reference_gate`, before the diagnosis, on the :class:`~jaxcal.diagnose.core.Prepared`
   recording: enough reference (samples and time span), a reference that moves when the sensor
   does, and an affine fit ``y = A x(t - lag) + b`` (lag searched within ``max_lag_s`` by the
   rotation-invariant rate norm; for the accelerometer ``+ M(t) r``, the lever arm's terms from the
   sensor's own gyroscope) whose held-out residual is small against the signal's own spread,
   with the singular values of ``A`` (the baseline's scales, the frame rotation factored out) near 1.
   :func:`check_reference` judges a failing pose-derived reference once more in its trusted band.
2. :func:`report_gate`, after it, on the report (and ``align``'s result): the baseline's and the
   final fit's held-out RMS against the same spread, the baseline's scales, and every reported
   quantity inside its plausible range (|tau| <= 2 s, |r| <= 1 m, ...).

Each failure is one sentence naming what does not fit and its likely cause. Pure: arrays and dicts
in, a :class:`GateResult` or a list of strings out.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxcal.diagnose.core import Prepared, prepare
from jaxcal.diagnose.kinematics import lever_force
from jaxcal.recording import Recording

__all__ = ["ALTERNATIVES", "GATE", "baseline_scales", "GateConfig", "GateResult", "SensorGate", "reference_gate", "report_gate", "check_reference"]


class GateConfig(NamedTuple):
    """Thresholds of the reference gate.

    Attributes:
        max_ratio: largest held-out residual RMS over the signal's own RMS spread, per sensor
            (real rigs: gyro 0.01-0.07, acc 0.1-0.3; contradicting references: 0.9-1.0).
        scale_range: per sensor, the singular values of the fitted affine matrix (the sensor's
            scales, the frame rotation factored out) must lie inside (real rigs: gyro within 1 % of 1,
            acc within 15 %, its lever arm and filter left unmodelled here).
        max_lag_s: the clock offset searched (s); a larger one is refused as a clock error
            (CONVENTIONS.md: |tau| <= 2 s).
        min_span_s: least time span the valid reference must cover (s).
        min_fraction: least fraction of the recording the valid reference must cover.
        min_rows: least number of valid reference rows (after decimation).
        still_ratio: a reference whose rate spread is below this fraction of the sensor's is frozen.
        max_lever_m: largest plausible lever arm (m).
        clock_search_s: on a failure, the wider lag searched to tell a clock error apart (s).
        post_scale_range: the finished diagnosis's baseline scales (``diag``: per axis; ``affine``:
            singular values) must lie inside (wider than ``scale_range``: the ``diag`` baseline's
            scales also carry a small frame rotation).
        min_spread: per sensor (rad/s, g), when neither the sensor nor its reference spreads this
            much, the fit is not judged (a rig at rest or barely moving: the noise would decide).
        max_gyro_bias: largest plausible gyroscope bias, rad/s (57 deg/s; consumer MEMS parts
            specify their zero-rate offset within about 0.35 rad/s, the MPU-6050 +-20 deg/s).
        max_tau_split_s: largest plausible difference between the accelerometer's and the
            gyroscope's time offsets (s): one clock, filter delays that differ by a few ms.
        tau_split_se: ... and the difference must also exceed this many combined standard errors.
    """

    max_ratio: dict = {"gyr": 0.5, "acc": 0.8}
    scale_range: dict = {"gyr": (0.8, 1.25), "acc": (0.7, 1.4)}
    max_lag_s: float = 2.0
    min_span_s: float = 2.0
    min_fraction: float = 0.25
    min_rows: int = 100
    still_ratio: float = 0.05
    clock_search_s: float = 60.0
    post_scale_range: tuple[float, float] = (0.5, 2.0)
    min_spread: dict = {"gyr": 0.05, "acc": 0.02}
    max_lever_m: float = 1.0
    max_gyro_bias: float = 1.0
    max_tau_split_s: float = 0.02
    tau_split_se: float = 5.0


GATE = GateConfig()


class SensorGate(NamedTuple):
    """One sensor's figures: the held-out residual RMS over the signal spread, the fitted
    affine matrix's singular values, the lag found (s), and the two RMS values (physical units)."""

    ratio: float
    scales: tuple[float, float, float]
    lag_s: float
    heldout_rms: float
    signal_rms: float


class GateResult(NamedTuple):
    """``problems``: one sentence per failed check (empty: the reference explains the sensor);
    ``sensors``: the figures behind them."""

    problems: list[str]
    sensors: dict[str, SensorGate]


_UNIT = {"gyr": "rad/s", "acc": "g"}
_NAME = {"gyr": "gyroscope", "acc": "accelerometer"}


def _norm_lag(y: np.ndarray, x: np.ndarray, valid: np.ndarray, max_lag: int) -> int:
    """The integer lag (samples; > 0: the sensor lags the reference) maximising the correlation of
    the two signals' norms (invariant to the frame rotation between them) within ``max_lag``."""
    a = np.where(valid, np.linalg.norm(y, axis=1), 0.0)
    b = np.where(valid, np.linalg.norm(x, axis=1), 0.0)
    a = np.where(valid, a - a[valid].mean(), 0.0)
    b = np.where(valid, b - b[valid].mean(), 0.0)
    n = len(a)
    m = 1 << int(np.ceil(np.log2(2 * n)))
    c = np.fft.irfft(np.fft.rfft(a, m) * np.conj(np.fft.rfft(b, m)), m)
    lags = np.arange(-max_lag, max_lag + 1)
    return int(lags[np.argmax(c[lags % m])])


def _shift(x: np.ndarray, valid: np.ndarray, lag: int) -> tuple[np.ndarray, np.ndarray]:
    """``x`` delayed by ``lag`` samples (row i holds x[i - lag]) and the rows where both exist."""
    n = len(x)
    xs = np.zeros_like(x)
    ok = np.zeros(n, bool)
    if lag >= 0:
        xs[lag:] = x[: n - lag]
        ok[lag:] = valid[: n - lag]
    else:
        xs[:lag] = x[-lag:]
        ok[:lag] = valid[-lag:]
    return xs, ok


def _lever_matrix(prep: Prepared) -> np.ndarray | None:
    """(N, 3, 3) ``M(t) = ([dw/dt]x + [w]x^2) / G0`` from the sensor's own gyroscope (its frame, g per
    metre): an accelerometer ``r`` metres from the reference point adds ``M(t) r`` to the specific
    force. ``None`` without a gyroscope."""
    sd = prep.sensors.get("gyr")
    if sd is None:
        return None
    w = np.where(np.asarray(sd.valid, bool)[:, None], np.asarray(sd.y, float), 0.0)
    wd = np.gradient(w, float(prep.dt), axis=0)
    return np.stack([lever_force(w, wd, e) for e in np.eye(3)], 2)  # column k: the force for r = e_k


def _stacked(x: np.ndarray, lever: np.ndarray | None) -> np.ndarray:
    """(N, 3, P) design of ``y_i = A_i . x + M_i(t) . r + b_i`` for every output axis ``i``: the
    unknowns ``vec(A)`` (9, row-major), ``r`` (3, shared by the axes, only with ``lever``), ``b`` (3)."""
    n = len(x)
    nr = 0 if lever is None else 3
    X = np.zeros((n, 3, 12 + nr))
    for i in range(3):
        X[:, i, 3 * i : 3 * i + 3] = x
        X[:, i, 9 + nr + i] = 1.0
        if lever is not None:
            X[:, i, 9:12] = lever[:, i, :]
    return X


def _affine_heldout(y: np.ndarray, x: np.ndarray, rows: np.ndarray, block: np.ndarray,
                    lever: np.ndarray | None = None) -> tuple[float, float, np.ndarray]:
    """Affine least squares ``y = A x + b`` on the even blocks, scored on the odd ones (and the
    other way round); returns the held-out RMS, the held-out signal RMS spread and ``A`` fitted on
    all rows. With ``lever`` (:func:`_lever_matrix`), ``y = A x + M(t) r + b``: one lever arm ``r``
    for the three axes (the accelerometer's offset from the reference point, which ``align``
    estimates)."""
    X = _stacked(x, lever)

    def solve(m: np.ndarray) -> np.ndarray:
        return np.linalg.lstsq(X[m].reshape(-1, X.shape[2]), y[m].reshape(-1), rcond=None)[0]

    res, sig = [], []
    for k in (0, 1):
        tr = rows & (block % 2 == k)
        te = rows & (block % 2 != k)
        if tr.sum() < 12 or te.sum() < 2:
            continue
        res.append(y[te] - X[te] @ solve(tr))
        sig.append(y[te] - y[te].mean(0))
    th = solve(rows)
    A = th[:9].reshape(3, 3)
    if not res:
        r = y[rows] - X[rows] @ th
        return float(np.sqrt(np.mean(r**2))), float(np.sqrt(np.mean((y[rows] - y[rows].mean(0)) ** 2))), A
    r, s = np.concatenate(res), np.concatenate(sig)
    return float(np.sqrt(np.mean(r**2))), float(np.sqrt(np.mean(s**2))), A


def _clock(y: np.ndarray, x: np.ndarray, valid: np.ndarray, block: np.ndarray, dt: float, cfg: GateConfig,
           sensor: str) -> float | None:
    """The lag (s) beyond ``max_lag_s`` at which the reference would explain the sensor, if any."""
    wide = min(int(round(cfg.clock_search_s / dt)), int(valid.sum()) // 3)
    if wide <= int(round(cfg.max_lag_s / dt)):
        return None
    lag = _norm_lag(y, x, valid, wide)
    if abs(lag * dt) <= cfg.max_lag_s:
        return None
    xs, ok = _shift(x, valid, lag)
    rows = ok & valid
    if rows.sum() < cfg.min_rows:
        return None
    hr, sig, _ = _affine_heldout(y, xs, rows, block)
    return lag * dt if sig > 0 and hr <= cfg.max_ratio[sensor] * sig else None


def _cause(sensor: str, cfg: GateConfig, ref_spread: float, sig: float, sv: np.ndarray, clock: float | None) -> str:
    if clock is not None:
        return (f"the clocks differ: the reference matches only when shifted by {clock:+.2f} s, beyond the "
                f"{cfg.max_lag_s:g} s an IMU-to-mocap offset may take (a reference {abs(clock):.1f} s "
                f"{'late' if clock < 0 else 'early'}? align the time stamps first)")
    if ref_spread < cfg.still_ratio * sig:
        return "the reference barely moves while the sensor does (a frozen or constant pose?)"
    if sig < cfg.still_ratio * ref_spread:
        return (f"the {_NAME[sensor]} barely moves while the reference does (a stuck or wrong sensor channel, or a "
                "reference of another body?)")
    if sensor == "acc" and np.isfinite(sv).all() and sv.max() < cfg.scale_range[sensor][0]:
        return ("the sensor sees a fraction of the reference's motion: the position unit is likely wrong "
                "(millimetres read as metres?)")
    if sensor == "gyr":
        return ("check the quaternion order (jaxcal reads [w, x, y, z], scalar first; xyzw read as wxyz "
                "looks like this) and that the pose is the sensor's rigid body")
    return ("check the position unit (metres; millimetres read as metres scale the motion by 1000), the "
            "quaternion order and the clock")


def reference_gate(prep: Prepared, cfg: GateConfig = GATE) -> GateResult:
    """Check that the reference of a prepared recording explains its sensors (see module doc).

    Args:
        prep: :func:`jaxcal.diagnose.core.prepare`'s result (any ``pose_sigma``).
        cfg: thresholds.

    Returns:
        :class:`GateResult`; empty ``problems`` when every check passes.
    """
    problems: list[str] = []
    figures: dict[str, SensorGate] = {}
    t = np.asarray(prep.t, float)
    span_all = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    dt = float(prep.dt)
    max_lag = max(1, int(round(cfg.max_lag_s / dt)))
    lag = None
    lever = _lever_matrix(prep)
    for s in ("gyr", "acc"):
        sd = prep.sensors.get(s)
        if sd is None:
            continue
        x = np.asarray(sd.inp.w if s == "gyr" else sd.inp.f, float)
        y = np.asarray(sd.y, float)
        valid = np.asarray(sd.valid, bool) & np.isfinite(x).all(1) & np.isfinite(y).all(1)
        nv = int(valid.sum())
        span = float(t[valid][-1] - t[valid][0]) if nv > 1 else 0.0
        if nv < cfg.min_rows or span < cfg.min_span_s or span < cfg.min_fraction * span_all:
            problems.append(f"the reference covers {span:.1f} s ({nv} samples) of the {span_all:.1f} s recording; "
                            f"at least {max(cfg.min_span_s, cfg.min_fraction * span_all):.1f} s are needed "
                            "(a pose track that stops early, or mostly invalid rows?)")
            return GateResult(problems, figures)
        x = np.where(valid[:, None], x, 0.0)
        y = np.where(valid[:, None], y, 0.0)
        if lag is None:
            lag = _norm_lag(y, x, valid, min(max_lag, nv // 4))
        xs, ok = _shift(x, valid, lag)
        rows = ok & valid
        if rows.sum() < cfg.min_rows:
            rows = valid
        # the accelerometer may sit centimetres from the reference point (align estimates that lever arm):
        # its terms, from the sensor's own gyroscope, are fitted alongside
        hr, sig, A = _affine_heldout(y, xs, rows, np.asarray(sd.block), lever if s == "acc" else None)
        sv = np.linalg.svd(A, compute_uv=False) if np.isfinite(A).all() else np.full(3, np.nan)
        ref_spread = float(np.sqrt(np.mean((x[rows] - x[rows].mean(0)) ** 2)))
        ratio = hr / sig if sig > 0 else np.inf
        figures[s] = SensorGate(float(ratio), tuple(float(v) for v in sv), lag * dt, hr, sig)  # type: ignore[arg-type]
        lo, hi = cfg.scale_range[s]
        if sig < cfg.min_spread[s] and ref_spread < cfg.min_spread[s]:
            continue  # neither moves: nothing to judge the reference by (the diagnosis says what it can)
        if sig <= 0:
            problems.append(f"the {_NAME[s]} output does not change over the recording; there is nothing to align or diagnose")
        elif not ratio <= cfg.max_ratio[s]:
            clock = _clock(y, x, valid, np.asarray(sd.block), dt, cfg, s)
            problems.append(f"the reference does not explain the {_NAME[s]}: held-out residual {hr:.3g} {_UNIT[s]} against a "
                            f"signal spread of {sig:.3g} {_UNIT[s]} (ratio {ratio:.2f}, at most {cfg.max_ratio[s]:g} accepted); likely cause: "
                            + _cause(s, cfg, ref_spread, sig, sv, clock))
        elif not (lo <= sv.min() and sv.max() <= hi):
            problems.append(f"the {_NAME[s]} scales fitted against the reference are {', '.join(f'{v:.3g}' for v in sv)} "
                            f"(a MEMS part is within [{lo:g}, {hi:g}]); likely cause: "
                            + _cause(s, cfg, ref_spread, sig, sv, None))
    return GateResult(problems, figures)


def _num(v) -> np.ndarray:
    return np.asarray(v, float) if v is not None else np.zeros(0)


def baseline_scales(results: dict, kind: str) -> dict[str, np.ndarray]:
    """Per sensor, the final fit's baseline scales in physical units: ``|diag|`` for the ``diag``
    baseline, the singular values of the matrix for ``affine`` (the frame rotation factored out).

    Args:
        results: ``{sensor: SensorResult}`` of :func:`jaxcal.diagnose.core.diagnose_banded`.
        kind: ``"diag"`` or ``"affine"``.
    """
    out = {}
    for s, r in results.items():
        beta = np.asarray(r.final_all.beta, float)
        out[s] = np.abs(beta[:3]) if kind == "diag" else np.linalg.svd(beta[:9].reshape(3, 3), compute_uv=False)
    return out


def report_gate(report: dict, gate: GateResult | None = None, align: dict | None = None, cfg: GateConfig = GATE,
                scales: dict[str, np.ndarray] | None = None) -> list[str]:
    """Plausibility of a finished diagnosis before anything is reported or written.

    Args:
        report: the ``report.json`` dict of ``diagnose`` (or the one behind ``align``).
        gate: :func:`reference_gate`'s result, for the signal spread (None: that check is skipped).
        align: ``align``'s ``align.json`` dict (its tau and r checked too).
        cfg: thresholds.
        scales: :func:`baseline_scales` of the diagnosis; each must lie in ``cfg.post_scale_range``
            (a model file with a gyro scale of 0.0006 multiplied the gyro by 2000 on apply).

    Returns:
        One sentence per implausible figure (empty: all plausible).
    """
    out: list[str] = []
    for part in ("baseline", "final"):
        for s, v in (report.get(part) or {}).items():
            if not isinstance(v, dict):
                continue
            for k in ("rms", "heldout_rms"):
                x = v.get(k)
                if x is not None and not np.isfinite(float(x)):
                    out.append(f"the {part} {_NAME.get(s, s)} {k} is {x}: the fit failed")
            hr = v.get("heldout_rms")
            if part == "final" and gate is not None and s in gate.sensors and hr is not None and np.isfinite(float(hr)):
                sig = gate.sensors[s].signal_rms
                lim = cfg.max_ratio.get(s, 1.0)
                if sig > 0 and float(hr) > lim * sig:
                    out.append(f"the diagnosed {_NAME.get(s, s)} still leaves a held-out residual of {float(hr):.3g} "
                               f"{_UNIT.get(s, '')} against a signal spread of {sig:.3g} (ratio {float(hr) / sig:.2f}); "
                               "the reference does not explain the sensor")
    lo, hi = cfg.post_scale_range
    for s, sv in (scales or {}).items():
        sv = np.asarray(sv, float)
        if not (np.isfinite(sv).all() and lo <= sv.min() and sv.max() <= hi):
            out.append(f"the diagnosed {_NAME.get(s, s)} scales are {', '.join(f'{v:.3g}' for v in sv)} (a MEMS part is "
                       f"within [{lo:g}, {hi:g}] of its datasheet): the reference or the datasheet scale does not fit the sensor")
    for e in report.get("effects", []) or []:
        name, p = e.get("name"), e.get("params") or {}
        if name == "time_offset" and "tau" in p and not abs(float(p["tau"])) <= cfg.max_lag_s:
            out.append(f"{e.get('sensor')} time offset {float(p['tau']):.3g} s is beyond {cfg.max_lag_s:g} s: a clock error")
        if name == "lever_arm" and "r" in p:
            r = _num(p["r"])
            if not (np.isfinite(r).all() and np.linalg.norm(r) <= cfg.max_lever_m):
                out.append(f"lever arm {np.linalg.norm(r) * 1e3:.0f} mm is beyond {cfg.max_lever_m * 1e3:.0f} mm: "
                           "the position unit is likely wrong (millimetres read as metres?)")
        for k, v in p.items():
            a = _num(v)
            if a.dtype.kind == "f" and a.size and not np.isfinite(a).all():
                out.append(f"{e.get('sensor')} {name} {k} is not finite")
    if align is not None:
        tau = align.get("tau")
        if tau is not None and not abs(float(tau)) <= cfg.max_lag_s:
            out.append(f"time offset {float(tau):.3g} s is beyond {cfg.max_lag_s:g} s: a clock error")
        r = align.get("r")
        if r is not None:
            rr = _num(r)
            if not (np.isfinite(rr).all() and np.linalg.norm(rr) <= cfg.max_lever_m):
                out.append(f"lever arm {np.linalg.norm(rr) * 1e3:.0f} mm is beyond {cfg.max_lever_m * 1e3:.0f} mm: "
                           "the position unit is likely wrong (millimetres read as metres?)")
        for k in ("tau_stderr", "rotation_deg"):
            v = align.get(k)
            if v is not None and not np.isfinite(float(v)):
                out.append(f"{k} is not finite: the fit failed")
        out += _align_consistency(align, cfg)
    return list(dict.fromkeys(out))


def _align_consistency(align: dict, cfg: GateConfig) -> list[str]:
    """``align``'s figures that no rig produces: a gyroscope bias beyond ``cfg.max_gyro_bias``, and
    accelerometer and gyroscope time offsets further apart than one clock and two filter delays
    allow (both: a solution that fits the wrong rotation and clock, e.g. 170 deg off with a
    2.9 rad/s bias on a stressed BROAD trial)."""
    out = []
    b = align.get("bias_gyr_rads")
    if b is not None:
        bn = float(np.linalg.norm(_num(b)))
        if not bn <= cfg.max_gyro_bias:
            out.append(f"the gyroscope bias found is {bn:.3g} rad/s (beyond {cfg.max_gyro_bias:g} rad/s, no MEMS gyroscope's): "
                       f"the alignment settled on a wrong rotation ({float(align.get('rotation_deg', np.nan)):.0f} deg) or clock")
    per = align.get("tau_per_sensor") or {}
    if "gyr" in per and "acc" in per:
        (tg, sg), (ta, sa) = ((float(per[s]["tau"]), float(per[s].get("stderr") or 0.0)) for s in ("gyr", "acc"))
        d = abs(tg - ta)
        if not (d <= cfg.max_tau_split_s or d <= cfg.tau_split_se * float(np.hypot(sg, sa))):
            out.append(f"the gyroscope and accelerometer put the time offset at {tg * 1e3:.1f} and {ta * 1e3:.1f} ms, "
                       f"{d * 1e3:.1f} ms apart (beyond {cfg.max_tau_split_s * 1e3:g} ms and {cfg.tau_split_se:g} standard errors): "
                       "one clock cannot; the alignment did not find the rig's offset")
    return out


ALTERNATIVES = (
    ("quat_ref", lambda q: q[:, [3, 0, 1, 2]],
     "the quaternions are stored scalar last (x, y, z, w) while jaxcal reads w, x, y, z: read that way the reference fits"),
    ("quat_ref", lambda q: q * np.array([1.0, -1.0, -1.0, -1.0]),
     "the quaternions are world to body (conjugated) while jaxcal reads body to world: conjugated the reference fits"),
    ("pos_ref", lambda p: p / 1000.0,
     "the positions are in millimetres, labelled metres: divided by 1000 the reference fits"),
    ("pos_ref", lambda p: p / 100.0,
     "the positions are in centimetres, labelled metres: divided by 100 the reference fits"),
)


def check_reference(rec: Recording, cfg: GateConfig = GATE) -> GateResult:
    """:func:`reference_gate` on ``prepare(rec)``, raising ``ValueError`` with its first problem (the
    CLI's one line). A pose-derived reference that fails is judged once more in its trusted band
    (``prepare(rec, pose_sigma=None)``: jittery motion capture, whose 20 ms derivatives are mostly
    noise) and passes if it passes there. When it still fails, the usual mistakes are undone one at a
    time (quaternions scalar last or conjugated, millimetres or centimetres as metres); if one makes
    the reference fit, the line names it as the cause.

    Raises:
        ValueError: the reference does not explain the sensor (or ``prepare`` refuses the recording).
    """
    g = reference_gate(prepare(rec), cfg)
    if g.problems and rec.gyr_ref is None and rec.pos_ref is not None and rec.quat_ref is not None:
        # a pose-derived reference differentiated with the 20 ms kernel can be mostly noise (100 Hz
        # mocap with ms time-stamp jitter: accelerometer scales fitted 0.3-0.8, the attenuation of
        # errors in variables); judged again in the band where it keeps its gain (jaxcal.diagnose.band,
        # the diagnosis's own kernel), it may explain the sensor after all
        banded = reference_gate(prepare(rec, pose_sigma=None), cfg)
        if not banded.problems:
            return banded
    if not g.problems:
        return g
    first = g.problems[0]
    if rec.pos_ref is not None and rec.quat_ref is not None and "likely cause: " in first:
        for field, undo, why in ALTERNATIVES:
            v = getattr(rec, field)
            try:
                alt = reference_gate(prepare(rec.replace(**{field: undo(np.asarray(v, float))})), cfg)
            except ValueError:
                continue
            if not alt.problems:
                raise ValueError(first.split("likely cause: ")[0] + "likely cause: " + why)
    raise ValueError(first)
