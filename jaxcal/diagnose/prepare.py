"""Stage 1 of the diagnosis: a recording prepared against its reference motion.

:func:`prepare` turns a :class:`jaxcal.recording.Recording` into a :class:`Prepared` (one
:class:`~jaxcal.diagnose.select.SensorData` per sensor): physical outputs via the datasheet values,
the reference motion (given, or derived from a pose with smoothing and decimation), the
temperature, validity, and contiguous time blocks for cross-validation. The reference-free mode
builds the same :class:`Prepared` from the IMU itself (:func:`jaxcal.diagnose.noref.prepare_noref`):
a mode is a choice of residual, and everything after this stage is shared
(:mod:`jaxcal.diagnose.stages`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxcal.diagnose import effects as E
from jaxcal.diagnose import kinematics as K
from jaxcal.diagnose.band import HALF_POWER as BH
from jaxcal.diagnose.band import Band, choose_sigma
from jaxcal.diagnose.select import SensorData, coarse_lag
from jaxcal.recording import Recording

__all__ = ["Prepared", "require_recording", "split_blocks", "prepare", "measured_inputs"]


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




class Motion(NamedTuple):
    """What the reference gives before decimation (the hand-off inside :func:`prepare`): the motion
    ``f`` (g), ``w`` (rad/s), ``wdot`` (rad/s^2), ``valid`` rows, the temperature, the sensors' raw
    outputs (smoothed alike when the reference is pose-derived), and for a pose-derived reference
    each sensor's own ``(f, w, wdot, ww)``, kernel widths ``sig`` (s), ``band`` and ``pose_sigma``."""

    f: np.ndarray
    w: np.ndarray
    wdot: np.ndarray
    valid: np.ndarray
    temp: np.ndarray | None
    raw: dict
    per_sensor: dict
    decim: int = 1
    sig: dict | None = None
    band: Band | None = None
    pose_sigma: float | None = None
    smoothed: bool = False


def _pose_motion(rec: Recording, t, dt, pos, quat, raw: dict, temp, pose_sigma, band, notes: list[str]) -> Motion:
    """The reference derived from a pose (:func:`jaxcal.diagnose.kinematics.reference_from_pose`),
    each sensor with its own kernel width and its output smoothed alike."""
    raw = dict(raw)
    if pose_sigma is None:
        band = _choose_band(t, dt, pos, quat, raw, rec)
        pose_sigma = band.sigma_s
        sig = dict(band.sigma_by_sensor)
    else:
        sig = {s: float(pose_sigma) for s in raw if raw[s] is not None}
    valid = np.ones(len(t), bool)
    per_sensor: dict = {}  # pose-derived reference per sensor (its own kernel width): (f, w, wdot, ww)
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
    return Motion(f, w, wdot, valid, temp, raw, per_sensor, decim, sig, band, pose_sigma, True)


def _given_motion(rec: Recording, t, dt, raw: dict, temp, ref_ok, ref_sigma_samples: float, band, notes: list[str]) -> Motion:
    """The reference as given (``acc_ref`` / ``gyr_ref``), angular acceleration by differentiation."""
    acc_ref, gyr_ref = rec.acc_ref, rec.gyr_ref
    if gyr_ref is None and acc_ref is None:
        raise ValueError("diagnose needs reference motion: gyr_ref/acc_ref or pos_ref+quat_ref")
    w = np.zeros((len(t), 3)) if gyr_ref is None else np.asarray(gyr_ref, np.float64)
    f = None if acc_ref is None else np.asarray(acc_ref, np.float64)
    if f is None:
        if rec.acc is not None:
            notes.append("no acc_ref: accelerometer not diagnosed; g-sensitivity uses the measured acc")
        f = np.zeros((len(t), 3))
    wdot = K.derivative5(w, dt) if ref_sigma_samples <= 0 else K.derivative(w, ref_sigma_samples * dt, dt)
    valid = np.isfinite(w).all(1) & np.isfinite(f).all(1) & ref_ok
    return Motion(f, w, wdot, valid, temp, dict(raw), {}, band=band)


def _decimate(m: Motion, t: np.ndarray, dt: float) -> tuple[Motion, np.ndarray, float]:
    """Every signal of ``m`` decimated by ``m.decim``, invalid stretches bridged by linear
    interpolation (not zeros: the band-limited time shift and its derivative would otherwise ring
    at every gap edge). Returns ``(motion, t, dt)`` on the decimated grid."""
    sl = slice(None, None, m.decim)
    t, f, w, wdot, valid = t[sl], m.f[sl], m.w[sl], m.wdot[sl], m.valid[sl]
    temp = None if m.temp is None else np.asarray(m.temp, np.float64)[sl]
    raw = {s: None if v is None else v[sl] for s, v in m.raw.items()}
    idx = np.arange(len(t))

    def bridge(a):
        if valid.all() or not valid.any():
            return np.nan_to_num(a)
        return np.stack([np.interp(idx, idx[valid], a[valid, c]) for c in range(a.shape[1])], 1)

    per_sensor = {s: tuple(bridge(a[sl]) for a in v) for s, v in m.per_sensor.items()}
    m = m._replace(f=bridge(f), w=bridge(w), wdot=bridge(wdot), valid=valid, temp=temp, raw=raw, per_sensor=per_sensor)
    return m, t, dt * m.decim


def _sensor_data(rec: Recording, m: Motion, t: np.ndarray, dt: float, n_blocks: int, notes: list[str]) -> dict[str, SensorData]:
    """One :class:`SensorData` per sensor that has a matching reference, in physical units."""
    acc_ref, gyr_ref, pos = rec.acc_ref, rec.gyr_ref, rec.pos_ref
    raw, valid, temp = m.raw, m.valid, m.temp
    f, w, wdot = m.f, m.w, m.wdot
    n = len(t)
    block = split_blocks(n, n_blocks)
    dT = np.zeros(n) if temp is None else temp - np.mean(temp[valid])
    tc = t - 0.5 * (t[0] + t[-1])
    out: dict[str, SensorData] = {}
    for s in ("acc", "gyr"):
        if raw[s] is None:
            continue
        if s == "acc" and acc_ref is None and gyr_ref is not None:
            continue
        if s == "gyr" and gyr_ref is None and pos is None:
            continue
        ww = None
        if s in m.per_sensor:  # pose-derived, with this sensor's own kernel width
            f, w, wdot, ww = m.per_sensor[s]
            ww = ww.reshape(-1, 3, 3)
        x = f if s == "acc" else w
        if s == "gyr" and acc_ref is None and raw["acc"] is not None and pos is None:
            sca, bia = _spec(rec, "acc", raw["acc"], f, valid, notes)
            f = (raw["acc"] - bia) / sca
        sc, bi = _spec(rec, s, raw[s], x, valid, notes)
        y = (raw[s] - bi) / sc
        is_counts = (not m.smoothed) and _unit(rec, s) == "LSB"
        inp = E.Inputs(f, w, wdot, tc, dT, np.asarray(dt), ww)
        out[s] = SensorData(s, y, raw[s] if is_counts else None, sc, bi, inp, valid.copy(), block, temp is not None)
    return out


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
    pos, quat = rec.pos_ref, rec.quat_ref
    raw = {s: None if getattr(rec, s) is None else np.asarray(getattr(rec, s), np.float64) for s in ("acc", "gyr")}
    ref_ok = _reference_ok(rec, t, notes)
    if rec.gyr_ref is None and pos is not None and quat is not None:
        pos = np.where(ref_ok[:, None], np.asarray(pos, np.float64), np.nan)
        quat = np.where(ref_ok[:, None], np.asarray(quat, np.float64), np.nan)
        m = _pose_motion(rec, t, dt, pos, quat, raw, rec.temp, pose_sigma, band, notes)
    else:
        m = _given_motion(rec, t, dt, raw, rec.temp, ref_ok, ref_sigma_samples, band, notes)
    m, t, dt = _decimate(m, t, dt)
    out = _sensor_data(rec, m, t, dt, n_blocks, notes)
    return Prepared(out, t, m.temp, dt, notes, m.smoothed, m.band, m.pose_sigma if m.smoothed else None,
                    {s: float(v) for s, v in (m.sig.items() if m.smoothed else ())})


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

