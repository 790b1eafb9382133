"""``diagnose`` without a reference motion: the IMU checked against itself.

A recording with no pose, ``acc_ref`` or ``gyr_ref`` is diagnosed from the IMU's self-consistency,
in the thesis's own setting (chapter 4: rotations about the sensor's centre). The reference mode's
machinery (:mod:`~jaxcal.diagnose.select`, :mod:`~jaxcal.diagnose.refit`,
:mod:`~jaxcal.diagnose.report`) runs unchanged; this mode only chooses the reference, i.e. the
residual:

* **accelerometer**: the measured specific force against the gravity direction that the
  gyroscope rotates (:func:`carried_gravity`): the calibrated gyroscope is dead-reckoned into an
  orientation ``R(t)`` (``R(t+dt) = R(t) Exp(w dt)``, CONVENTIONS.md); in that drifting world frame
  gravity is each rest's mean of ``R f``, interpolated across the motion to the next rest (where
  no rest brackets a motion: the low-pass of ``R f``, a Gaussian of ``gravity_sigma_s``),
  normalised to 1 g and rotated back, ``f_ref = R^T normalise(g_w)``. At rest this is
  ``|f| = 1 g``; between two rests it is the gravity direction carried by the gyroscope; during a
  motion, whatever the motion adds on top is the residual. The effects of the vocabulary act on that reference with the
  gyroscope as the rate: ``lever_arm`` (``dw/dt x r + w x (w x r)``, ``r`` from the point the
  rotation leaves unaccelerated) and ``time_offset`` (``tau`` of the accelerometer relative to the
  gyroscope, positive when it lags);
* **gyroscope**: at rest it reads its bias plus ``G f`` (``g_sensitivity``, ``f`` the calibrated
  accelerometer), plus bias drift and temperature terms; only rest samples are used.

The starting calibration (what turns LSB into g and rad/s and lets the gyroscope carry gravity)
comes from the rests by :func:`jaxcal.multipos.fit_multipos_recording` where the recording has the
poses for it, otherwise from the datasheet values / units as recorded with the gyro bias from the
rests. The baseline of the report is an affine refit of each sensor on top of it (eq. 2.3).
Cross-validation folds interleave: time segments of ``fold_s`` (acc) and whole rests (gyr) are
dealt round-robin into ``n_blocks`` folds, so each held-out figure is measured on motions and rests
that the fit did not use.

What the vocabulary cannot hold is said, not forced into an effect: translational acceleration
during motions (hand-held recordings) remains in the accelerometer's residual and is reported as a
warning with where it lives (:func:`translation_warning`). It is treated as noise, so where it
correlates with the rotation it biases what the motions estimate (time offset, lever arm):
``results/field_diagnose.md`` measures how much on BROAD.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
from scipy.ndimage import gaussian_filter1d

from jaxcal.diagnose import effects as E
from jaxcal.diagnose import kinematics as K
from jaxcal.diagnose.core import Mode, Prepared, SensorResult, count_tests, diagnose_sensors, require_recording
from jaxcal.diagnose.report import build_report
from jaxcal.diagnose.select import SelectConfig, SensorData
from jaxcal.recording import Recording
from jaxcal.sensor import LinearCal

__all__ = [
    "NorefConfig",
    "SelfReference",
    "has_reference",
    "check_input",
    "reference_calibration",
    "rest_mask",
    "dead_reckon",
    "carried_gravity",
    "interleaved_blocks",
    "self_reference",
    "prepare_noref",
    "SELF",
    "SELF_NO_REST",
    "diagnose_noref",
    "noref_report",
    "translation_warning",
    "carry_check",
]


class NorefConfig(NamedTuple):
    """Settings of the reference-free mode (host side, nothing traced).

    Args:
        gravity_sigma_s: Gaussian width (s) of the world-frame low-pass that finds gravity in the
            gyroscope's dead-reckoned frame; longer averages out more translational acceleration,
            shorter follows the gyro's drift more closely.
        rest_window_s: window (s) of the rest detector's moving standard deviations.
        rest_gyr_std: largest gyro standard deviation (rad/s, norm of the axes) at rest.
        rest_acc_std: largest accelerometer standard deviation (g, norm of the axes) at rest.
        min_rest_s: shortest rest kept (s).
        fold_s: length (s) of the time segments dealt into the accelerometer's folds.
        n_blocks: number of interleaved cross-validation folds.
        multipos: start from a multi-position calibration where the rests allow it.
        max_carry_s: longest motion between two rests across which gravity is carried from rest
            to rest (:func:`carried_gravity`); longer ones use the low-pass.
        min_rest_free_s: shortest recording (s) diagnosed without any rest: its gravity is the
            low-pass everywhere, which needs several of its widths of data.
    """

    gravity_sigma_s: float = 1.0
    rest_window_s: float = 0.5
    rest_gyr_std: float = 0.02
    rest_acc_std: float = 0.01
    min_rest_s: float = 0.5
    fold_s: float = 2.0
    n_blocks: int = 8
    multipos: bool = True
    max_carry_s: float = 30.0
    min_rest_free_s: float = 10.0


class SelfReference(NamedTuple):
    """The reference a recording gives itself (numpy, float64, all (N, ...) on its time grid).

    ``acc_cal``/``gyr_cal``: the starting calibration (:class:`~jaxcal.sensor.LinearCal`);
    ``f`` (g), ``w`` (rad/s): the outputs through it; ``f_ref`` (g): the gyro-carried gravity;
    ``rest``: (N,) bool rest samples; ``source``: where the calibration came from; ``notes``.
    """

    acc_cal: LinearCal
    gyr_cal: LinearCal
    f: np.ndarray
    w: np.ndarray
    f_ref: np.ndarray
    rest: np.ndarray
    source: str
    notes: list[str]


def has_reference(rec: Recording) -> bool:
    """True when ``rec`` carries a reference motion (``acc_ref``/``gyr_ref`` or a pose)."""
    return rec.acc_ref is not None or rec.gyr_ref is not None or (rec.pos_ref is not None and rec.quat_ref is not None)


def _spec_cal(rec: Recording, sensor: str) -> LinearCal | None:
    """The datasheet / unit conversion of ``sensor`` as a :class:`LinearCal`; None for LSB
    without datasheet values."""
    unit = rec.acc_unit if sensor == "acc" else rec.gyr_unit
    if unit != "LSB":
        return LinearCal(np.eye(3), np.zeros(3))
    s, b = (rec.acc_lsb_per_g, rec.acc_bias_lsb) if sensor == "acc" else (rec.gyr_lsb_per_rads, rec.gyr_bias_lsb)
    if s is None:
        return None
    s = np.broadcast_to(np.asarray(s, np.float64), (3,))
    b = np.broadcast_to(np.asarray(0.0 if b is None else b, np.float64), (3,))
    return LinearCal(np.diag(1.0 / s), b.copy())


def rest_mask(t: np.ndarray, f: np.ndarray, w: np.ndarray, cfg: NorefConfig = NorefConfig()) -> np.ndarray:
    """(N,) bool: samples at rest, where the moving standard deviations of the gyroscope (rad/s)
    and the accelerometer (g), norms over the axes, stay below ``cfg``'s limits for at least
    ``min_rest_s``; the window's half width is trimmed off each rest's ends.

    Args:
        t: (N,) times (s).
        f: (N, 3) specific force (g).
        w: (N, 3) body rate (rad/s).
        cfg: thresholds and window.
    """
    dt = float(np.median(np.diff(t)))
    sig = max(1.0, 0.5 * cfg.rest_window_s / dt)

    def mstd(x):
        m = gaussian_filter1d(x, sig, axis=0, mode="nearest")
        v = gaussian_filter1d(x * x, sig, axis=0, mode="nearest") - m * m
        return np.sqrt(np.maximum(v, 0.0).sum(1))

    still = (mstd(np.asarray(w, np.float64)) < cfg.rest_gyr_std) & (mstd(np.asarray(f, np.float64)) < cfg.rest_acc_std)
    out = np.zeros_like(still)
    trim = int(round(sig))
    for a, b in _runs(still):
        if (b - a) * dt >= cfg.min_rest_s + 2 * trim * dt:
            out[a + trim : b - trim] = True
    return out


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[(start, stop), ...]`` of the True runs of ``mask``."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return [(int(a), int(b)) for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1))]


def reference_calibration(rec: Recording, cfg: NorefConfig = NorefConfig()) -> tuple[LinearCal, LinearCal, str, list[str]]:
    """The starting calibration ``(acc, gyr, source, notes)``: multi-position self-calibration
    from the rests (:func:`jaxcal.multipos.fit_multipos_recording`) when ``cfg.multipos`` and the
    recording has the poses for it; otherwise the datasheet values / units as recorded, with the
    gyro bias taken from the rests (:func:`rest_mask`).

    Args:
        rec: the recording.
        cfg: settings.

    Raises:
        ValueError: raw counts without datasheet values and too few poses for multipos.
    """
    notes: list[str] = []
    if cfg.multipos:
        try:
            from jaxcal.multipos.detect import fit_multipos_recording

            a, g = fit_multipos_recording(rec)
            if g is not None:
                return (LinearCal(np.asarray(a.A, np.float64), np.asarray(a.b, np.float64)),
                        LinearCal(np.asarray(g.A, np.float64), np.asarray(g.b, np.float64)), "multipos", notes)
        except ValueError as err:
            notes.append(f"no multi-position calibration ({err}); starting from the datasheet values / units as recorded")
    a, g = _spec_cal(rec, "acc"), _spec_cal(rec, "gyr")
    if a is None or g is None:
        raise ValueError("no reference motion (acc_ref/gyr_ref or pos_ref+quat_ref), and diagnosing raw counts without one needs "
                         "datasheet values (acc_lsb_per_g, gyr_lsb_per_rads) or at least 9 rests for a multi-position calibration")
    f, w = a.apply(np.asarray(rec.acc, np.float64)), g.apply(np.asarray(rec.gyr, np.float64))
    rest = rest_mask(np.asarray(rec.t, np.float64), np.asarray(f), np.asarray(w), cfg)
    if rest.any():
        bw = np.asarray(w)[rest].mean(0)
        g = LinearCal(np.asarray(g.A), np.asarray(g.b) + np.linalg.solve(np.asarray(g.A), bw))
        notes.append(f"gyro bias from {len(_runs(rest))} rests: {np.array2string(bw, precision=5)} rad/s")
    else:
        notes.append("no rest found: the gyro bias is left as recorded, so gravity drifts in the dead-reckoned frame "
                     "(followed by the low-pass)")
    return (LinearCal(np.asarray(a.A, np.float64), np.asarray(a.b, np.float64)),
            LinearCal(np.asarray(g.A, np.float64), np.asarray(g.b, np.float64)), "datasheet / units as recorded", notes)


def dead_reckon(w: np.ndarray, dt: float) -> np.ndarray:
    """(N, 3, 3) orientations ``R(0) = I``, ``R(k+1) = R(k) Exp(w_k dt)`` (CONVENTIONS.md, eq. 4.1-4.3).

    Args:
        w: (N, 3) body rate (rad/s).
        dt: sample interval (s).
    """
    from scipy.spatial.transform import Rotation

    steps = Rotation.from_rotvec(np.asarray(w, np.float64) * dt).as_quat()  # x, y, z, w
    q = np.empty_like(steps)
    cur = np.array([0.0, 0.0, 0.0, 1.0])
    for k in range(len(steps)):  # Hamilton product cur * step, scalar last
        q[k] = cur
        x1, y1, z1, w1 = cur
        x2, y2, z2, w2 = steps[k]
        cur = np.array([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2])
        cur /= np.sqrt(cur @ cur)
    return Rotation.from_quat(q).as_matrix()


def carried_gravity(R: np.ndarray, f: np.ndarray, dt: float, sigma_s: float, rest: np.ndarray | None = None,
                    max_carry_s: float = 30.0) -> np.ndarray:
    """(N, 3) the gravity direction the gyroscope carries, as specific force (g, unit norm):
    ``R^T normalise(g_w)`` with ``g_w`` gravity in the dead-reckoned frame. Between two rests at
    most ``max_carry_s`` apart, ``g_w`` is each rest's mean of ``R f`` (constant over the rest)
    and linear in time across the motion between them: the first rest's gravity carried onto the
    second by the gyroscope, the dead-reckoning drift shared out linearly, and nothing taken from
    the motion itself (so the motion's own effects are not absorbed). Elsewhere (no rests, long
    motions, before the first and after the last rest) ``g_w`` is the low-pass of ``R f``, a
    Gaussian of ``sigma_s`` s.

    Args:
        R: (N, 3, 3) dead-reckoned orientations (:func:`dead_reckon`).
        f: (N, 3) calibrated specific force (g).
        dt: sample interval (s).
        sigma_s: Gaussian width (s) of the low-pass.
        rest: (N,) bool rest samples (:func:`rest_mask`); None: low-pass everywhere.
        max_carry_s: longest motion between two rests that is bridged by interpolation (s).
    """
    fw = np.einsum("nij,nj->ni", R, f)
    gw = gaussian_filter1d(fw, sigma_s / dt, axis=0, mode="nearest")
    runs = [] if rest is None else _runs(rest)
    for a, b in runs:
        gw[a:b] = fw[a:b].mean(0)
    for (a0, b0), (a1, b1) in zip(runs[:-1], runs[1:]):
        if (a1 - b0) * dt <= max_carry_s:
            u = (np.arange(b0, a1) - (b0 - 1)) / (a1 - (b0 - 1))
            gw[b0:a1] = (1 - u)[:, None] * gw[b0 - 1] + u[:, None] * gw[a1]
    gw /= np.linalg.norm(gw, axis=1, keepdims=True)
    return np.einsum("nji,nj->ni", R, gw)


def interleaved_blocks(seg: np.ndarray, n_blocks: int) -> np.ndarray:
    """(N,) fold ids: segment ids dealt round-robin into ``n_blocks`` folds.

    Args:
        seg: (N,) non-decreasing segment ids.
        n_blocks: number of folds.
    """
    return np.asarray(seg, int) % n_blocks


_NO_REST = ("no rest of at least {:g} s: gravity is the low-pass (sigma {:g} s) of the gyro-carried specific force "
            "everywhere, so only the accelerometer's motion effects (lever arm, time offset) are tested; its scale, "
            "cross-axis and nonlinearity terms need rests, and the gyroscope (its bias, g-sensitivity) is not diagnosed; "
            "hold the IMU still for a few seconds before and after the motion for a full diagnosis")


def _require_rest_free_length(t: np.ndarray, cfg: NorefConfig) -> None:
    """Refuse a recording without a rest that is shorter than ``cfg.min_rest_free_s``."""
    dur = float(t[-1] - t[0])
    if dur < cfg.min_rest_free_s:
        raise ValueError(f"no reference motion (acc_ref/gyr_ref or pos_ref+quat_ref), no rest of at least {cfg.min_rest_s:g} s, "
                         f"and {dur:.1f} s of data: without a rest the reference-free mode needs at least {cfg.min_rest_free_s:g} s; "
                         "hold the IMU still for a few seconds, or record longer")


def check_input(rec: Recording, cfg: NorefConfig = NorefConfig()) -> None:
    """Refuse, cheaply and before any work, a recording the reference-free mode cannot diagnose:
    no ``acc`` or ``gyr``, fewer than 100 samples, or (with datasheet values or physical units)
    no rest (:func:`rest_mask`) in fewer than ``cfg.min_rest_free_s`` seconds. A longer recording
    without a rest is diagnosed (the accelerometer's motion effects only, against the low-pass of
    the gyro-carried specific force; the report warns), not refused.

    Args:
        rec: the recording.
        cfg: settings.

    Raises:
        TypeError: ``rec`` is not a :class:`~jaxcal.recording.Recording`.
        ValueError: the reason, in one line.
    """
    require_recording(rec)
    if rec.acc is None or rec.gyr is None:
        raise ValueError("no reference motion (acc_ref/gyr_ref or pos_ref+quat_ref), and diagnosing without one needs both 'acc' and 'gyr'")
    t = np.asarray(rec.t, np.float64)
    if len(t) < 100:
        raise ValueError("diagnose needs a 't' array of at least 100 samples")
    a, g = _spec_cal(rec, "acc"), _spec_cal(rec, "gyr")
    if a is not None and g is not None and float(t[-1] - t[0]) < cfg.min_rest_free_s:
        f = np.asarray(a.apply(np.asarray(rec.acc, np.float64)))
        w = np.asarray(g.apply(np.asarray(rec.gyr, np.float64)))
        if not rest_mask(t, f, w, cfg).any():
            _require_rest_free_length(t, cfg)


def self_reference(rec: Recording, cfg: NorefConfig = NorefConfig()) -> SelfReference:
    """The recording's own reference (module docstring): starting calibration, rests,
    gyro-carried gravity.

    Args:
        rec: the recording (``t``, ``acc``, ``gyr``).
        cfg: settings.
    """
    check_input(rec, cfg)
    t = np.asarray(rec.t, np.float64)
    dt = float(np.median(np.diff(t)))
    a, g, source, notes = reference_calibration(rec, cfg)
    f = np.asarray(a.apply(np.asarray(rec.acc, np.float64)), np.float64)
    w = np.asarray(g.apply(np.asarray(rec.gyr, np.float64)), np.float64)
    rest = rest_mask(t, f, w, cfg)
    if not rest.any():
        _require_rest_free_length(t, cfg)
    f_ref = carried_gravity(dead_reckon(w, dt), f, dt, cfg.gravity_sigma_s, rest, cfg.max_carry_s)
    notes.append(f"reference-free: starting calibration from {source}; {len(_runs(rest))} rests "
                 f"({rest.mean() * 100:.0f} % of the samples); gravity carried by the gyroscope from rest to rest (motions up to {cfg.max_carry_s:g} s), elsewhere a low-pass of sigma {cfg.gravity_sigma_s:g} s")
    return SelfReference(a, g, f, w, f_ref, rest, source, notes)


def prepare_noref(rec: Recording, cfg: NorefConfig = NorefConfig(), ref: SelfReference | None = None) -> Prepared:
    """A :class:`~jaxcal.diagnose.core.Prepared` whose reference is the recording itself
    (module docstring): the accelerometer against the gyro-carried gravity on every sample, the
    gyroscope at rest against zero rate with the calibrated specific force as ``f``.

    Args:
        rec: the recording.
        cfg: settings.
        ref: an already computed :func:`self_reference`.
    """
    ref = self_reference(rec, cfg) if ref is None else ref
    t = np.asarray(rec.t, np.float64)
    n = len(t)
    dt = float(np.median(np.diff(t)))
    temp = None if rec.temp is None else np.asarray(rec.temp, np.float64)
    ok = np.isfinite(ref.f).all(1) & np.isfinite(ref.w).all(1)
    dT = np.zeros(n) if temp is None else temp - np.mean(temp[ok])
    tc = t - 0.5 * (t[0] + t[-1])
    wdot = K.derivative5(ref.w, dt)
    seg = np.floor((t - t[0]) / cfg.fold_s).astype(int)
    acc_inp = E.Inputs(ref.f_ref, ref.w, wdot, tc, dT, np.asarray(dt))
    sensors = {"acc": SensorData("acc", ref.f, None, np.ones(3), np.zeros(3), acc_inp, ok.copy(),
                                 interleaved_blocks(seg, cfg.n_blocks), temp is not None)}
    notes = list(ref.notes)
    runs = _runs(ref.rest)
    if len(runs) >= 2:
        rid = np.zeros(n, int)
        for k, (a, b) in enumerate(runs):
            rid[a:b] = k
        z = np.zeros((n, 3))
        gyr_inp = E.Inputs(ref.f, z, z, tc, dT, np.asarray(dt))
        sensors["gyr"] = SensorData("gyr", ref.w, None, np.ones(3), np.zeros(3), gyr_inp, ref.rest & ok,
                                    interleaved_blocks(rid, min(cfg.n_blocks, len(runs))), temp is not None)
    else:
        notes.append("gyr: fewer than 2 rests, so the gyroscope's rest output (bias, g-sensitivity) is not diagnosed")
    return Prepared(sensors, t, temp, dt, notes)


def translation_warning(prep: Prepared, res: SensorResult, rest: np.ndarray, ratio: float = 3.0) -> str | None:
    """A warning when the accelerometer's final residual during motion exceeds ``ratio`` times
    its residual at rest: translational acceleration (or anything else the vocabulary cannot
    hold) that no lever arm explains. Says where it lives (the 2-s segments with the largest rms).

    Args:
        prep: the prepared recording (:func:`prepare_noref`).
        res: the accelerometer's :class:`~jaxcal.diagnose.core.SensorResult`.
        rest: (N,) rest samples.
        ratio: motion / rest rms ratio that triggers the warning.
    """
    r = np.asarray(res.final_all.resid)
    rows = res.fit_rows
    mot, rst = rows & ~rest, rows & rest
    if not mot.any():
        return None
    rm = float(np.sqrt(np.mean(r[mot] ** 2)))
    rr = float(np.sqrt(np.mean(r[rst] ** 2))) if rst.sum() > 10 else float("nan")
    if np.isfinite(rr) and rm <= ratio * rr:
        return None
    t = prep.t - prep.t[0]
    seg = np.floor(t / 2.0).astype(int)
    e = np.sqrt(np.bincount(seg[mot], weights=(r[mot] ** 2).sum(1)) / np.maximum(np.bincount(seg[mot]), 1) / 3)
    top = np.argsort(e)[::-1][:3]
    where = ", ".join(f"{2 * k:.0f}-{2 * k + 2:.0f} s ({e[k] * 1e3:.0f} mg)" for k in top if e[k] > 0)
    ax = np.sqrt(np.mean(r[mot] ** 2, axis=0))
    return (f"acc: translational acceleration during motions that no lever arm explains - the residual during motion is "
            f"{rm * 1e3:.2f} mg rms ({'no rest' if not np.isfinite(rr) else f'{rr * 1e3:.2f} mg at rest'}), per axis "
            f"[{', '.join(f'{v * 1e3:.2f}' for v in ax)}] mg; it lives in the motions at {where}. It is not in the "
            f"vocabulary and is not forced into an effect; the estimates above treat it as noise")


def carry_check(ref: SelfReference, t: np.ndarray) -> dict:
    """Between two consecutive rests: the angle (deg) between the second rest's measured gravity
    direction and the first's carried onto it by the calibrated gyroscope (the thesis's gravity
    check); ``{"n": transitions, "median_deg", "max_deg"}`` (n = 0 with fewer than 2 rests).

    Args:
        ref: :func:`self_reference`'s result.
        t: (N,) times (s).
    """
    runs = _runs(ref.rest)
    if len(runs) < 2:
        return {"n": 0, "median_deg": None, "max_deg": None}
    dt = float(np.median(np.diff(t)))
    ang = []
    for (a0, b0), (a1, b1) in zip(runs[:-1], runs[1:]):
        u0 = ref.f[a0:b0].mean(0)
        u1 = ref.f[a1:b1].mean(0)
        R = dead_reckon(ref.w[b0 - 1 : a1], dt)
        Rt = R[-1] if len(R) else np.eye(3)
        from scipy.spatial.transform import Rotation

        Rt = Rt @ Rotation.from_rotvec(ref.w[a1 - 1] * dt).as_matrix() if a1 - 1 >= b0 - 1 else Rt
        c = Rt.T @ u0
        cosang = float(c @ u1 / (np.linalg.norm(c) * np.linalg.norm(u1)))
        ang.append(float(np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))))
    return {"n": len(ang), "median_deg": float(np.median(ang)), "max_deg": float(np.max(ang))}


MOTION_POOLED = ("time_offset", "lever_arm")
"""The accelerometer's effects estimated from the motions, whose intervals are pooled over bands."""


def _rest_config(sensor: str, cfg: SelectConfig) -> SelectConfig:
    """The gyroscope's rows are separate rests: an AR noise model without the random walk, which
    would take each rest's level (its bias + G f) for noise. No clock_skew: one clock, the IMU's.
    The accelerometer's motion effects (time offset, lever arm) count the disagreement of their
    frequency bands in their intervals (:data:`MOTION_POOLED`): translational acceleration that
    the vocabulary lacks moves them. No Huber reweighting: the residual's heavy tails are that
    translational acceleration, not glitches (:class:`~jaxcal.diagnose.system.SelectConfig`)."""
    cfg = cfg._replace(exclude=("clock_skew",), huber=None)
    return cfg._replace(band_pool=MOTION_POOLED) if sensor == "acc" else cfg._replace(random_walk=False)


def _rest_warning(sensor: str, warning: str) -> bool:
    """The rests hold no rate: only the rest-output effects are diagnosable there, so the
    gyroscope's "not excited" warnings say nothing."""
    return sensor != "gyr" or "not excited" not in warning


SELF = Mode("none", share_clock=False, sensor_config=_rest_config, keep_warning=_rest_warning)
"""Against the IMU itself (:func:`prepare_noref`): the accelerometer's residual is already relative
to the gyroscope's clock, so no clock offset is shared."""


def _motion_only_config(sensor: str, cfg: SelectConfig) -> SelectConfig:
    """No rest: only the accelerometer's motion effects (:data:`MOTION_POOLED`) are tested. Its
    scale, cross-axis and nonlinearity terms need ``|f| = 1 g`` at rests; without them gravity is
    the low-pass of the gyro-carried specific force, which takes in part of the motion's own slow
    content (a lever arm's centripetal term), and those terms would fit that (measured on a
    simulated rest-free stretch with a 7 cm lever arm: a misalignment named that the simulation
    does not have)."""
    cfg = _rest_config(sensor, cfg)
    others = tuple(n for n in E.EFFECT_NAMES if n not in MOTION_POOLED)
    return cfg._replace(exclude=tuple(dict.fromkeys(cfg.exclude + others)))


SELF_NO_REST = SELF._replace(sensor_config=_motion_only_config)
""":data:`SELF` for a recording without a rest (:func:`_motion_only_config`)."""


def diagnose_noref(rec: Recording, kind: str = "affine", cfg: SelectConfig = SelectConfig(),
                   noref: NorefConfig = NorefConfig(), force: Mapping[str, tuple[str, ...]] | None = None,
                   ) -> tuple[Prepared, dict[str, SensorResult], SelfReference]:
    """Prepare a recording against itself (:func:`prepare_noref`) and run the reference mode's
    stages on it (:func:`jaxcal.diagnose.core.diagnose_sensors` with :data:`SELF`, one Bonferroni
    family over both sensors; the gyroscope's noise model without a random walk). Returns
    ``(prepared, {sensor: SensorResult}, self reference)``.

    Args:
        rec: the recording (no reference motion needed).
        kind: baseline on top of the starting calibration, ``"affine"`` (default) or ``"diag"``.
        cfg: test level and search settings.
        noref: settings of the self reference.
        force: ``{sensor: effect names}`` estimated whatever the tests say (reported as estimates
            on request, not as discoveries); None: none.
    """
    ref = self_reference(rec, noref)
    prep = prepare_noref(rec, noref, ref)
    mode = SELF if ref.rest.any() else SELF_NO_REST
    res = diagnose_sensors({s: prep for s in prep.sensors}, kind, cfg, count_tests(kind, prep, cfg, mode), force, mode=mode)
    return prep, res, ref


def noref_report(prep: Prepared, results: dict[str, SensorResult], ref: SelfReference, kind: str, runtime_s: float, noref: NorefConfig = NorefConfig()) -> dict:
    """The ``report.json`` dict of a reference-free diagnosis (:func:`jaxcal.diagnose.noref.diagnose_noref`):
    :func:`~jaxcal.diagnose.report.build_report` plus the optional fields ``"reference": "none"``
    and ``"self_reference"`` (starting calibration, rests, gravity carried between rests), and the
    translational-acceleration warning where the accelerometer's motion residual asks for one.

    Args:
        prep: the prepared recording (:func:`jaxcal.diagnose.noref.prepare_noref`).
        results: ``{sensor: SensorResult}``.
        ref: the :class:`~jaxcal.diagnose.noref.SelfReference`.
        kind: baseline, ``"diag"`` or ``"affine"``.
        runtime_s: wall time to record (s).
        noref: the settings used.
    """
    rep = build_report(prep, results, kind, runtime_s)
    rep["reference"] = "none"
    carry = carry_check(ref, prep.t)
    rep["self_reference"] = {
        "calibration_from": ref.source, "n_rests": int(np.count_nonzero(np.diff(np.concatenate([[0], ref.rest.astype(int)])) == 1)),
        "rest_fraction": float(ref.rest.mean()), "gravity_sigma_s": noref.gravity_sigma_s, "fold_s": noref.fold_s,
        "n_folds": noref.n_blocks, "carried_gravity_between_rests_deg": carry,
        "acc_cal": {"A": np.asarray(ref.acc_cal.A).tolist(), "b": np.asarray(ref.acc_cal.b).tolist()},
        "gyr_cal": {"A": np.asarray(ref.gyr_cal.A).tolist(), "b": np.asarray(ref.gyr_cal.b).tolist()},
        "residual": "acc: measured specific force - gyro-carried gravity (1 g); gyr: output at rest - 0",
    }
    for sens in rep["sensors"].values():
        sens["estimator"]["fit"] = ("noise-model least squares (AR; random walk on the accelerometer only), not Huber-reweighted "
                                    "(the motion's heavy tails are its translational acceleration)")
    if not ref.rest.any():
        rep["warnings"].append(_NO_REST.format(noref.min_rest_s, noref.gravity_sigma_s))
    if "acc" in results:
        w = translation_warning(prep, results["acc"], ref.rest)
        if w is not None:
            rep["warnings"].append(w)
            rep["self_reference"]["translation"] = True
    return rep
