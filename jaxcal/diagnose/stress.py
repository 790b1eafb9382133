"""Stress a real IMU + motion-capture recording the way real rigs are, with known truth.

Every function takes a :class:`~jaxcal.recording.Recording` and returns a NEW one
(``Recording.replace``: the input and its arrays are never modified); random ones take an explicit
:class:`numpy.random.Generator`. A recording here holds ``t`` (N,) s, ``acc`` (N, 3) g
(``acc_unit`` = "g"), ``gyr`` (N, 3) rad/s (``gyr_unit`` = "rad/s"), ``pos_ref`` (N, 3) m and
``quat_ref`` (N, 4) (Hamilton ``[w, x, y, z]``, reference body to world) on the IMU time grid, NaN
rows marking reference gaps, optionally ``ref_valid`` (N,) bool and the original reference track
``gt_t`` (M,), ``gt_pos`` (M, 3), ``gt_quat`` (M, 4) at its own times (as
:func:`jaxcal.formats.pose.attach_pose` leaves it). Other fields are carried over unchanged.

Truth vocabulary (CONVENTIONS.md): ``time_offset`` tau > 0 means the IMU reads x(t - tau), i.e. it
lags the reference; ``lever_arm`` r is the IMU position relative to the reference point in the
reference body frame; ``R_ref_imu`` rotates IMU-frame vectors into the reference body frame, so
``w_ref = R_ref_imu w_imu`` and ``R_world_imu = R_world_ref R_ref_imu``.

What each stress does to that truth, for a recording whose as-recorded values are
``(tau0, R0 = R_ref_imu, r0)``:

================================  ==========================================================
:func:`move_reference_point` r    r' = r0 + r (r in the input's reference frame); tau, R same
:func:`rotate_reference_body` Rd  R' = Rd^T R0, r' = Rd^T r0; tau same
:func:`shift_reference_clock` tau tau' = tau0 + tau; R, r same
:func:`decimate_reference`        unchanged (zero-mean jitter, dropouts only remove data)
:func:`add_vibration`             unchanged (zero-mean noise on the IMU)
================================  ==========================================================

:func:`stress` applies them in that order from a :class:`StressConfig` and returns the truth for
an input whose reference frame is the IMU frame with zero offsets (tau0 = 0, R0 = I, r0 = 0); for
a real recording the as-recorded offsets add on top as in the table
(tau0 + tau, Rd^T R0, Rd^T (r0 + r)).

:func:`conceal_lever_arm` is the one effect concealer here (it moves the reference point, this
module's geometry); the others, which add vocabulary effects to the IMU streams, are in
:mod:`jaxcal.diagnose.conceal`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import numpy as np

from jaxcal import rotation
from jaxcal.precision import float64
from jaxcal.recording import Recording

__all__ = [
    "GT_MAX_GAP",
    "StressConfig",
    "add_vibration",
    "conceal_lever_arm",
    "decimate_reference",
    "move_reference_point",
    "random_stress_config",
    "rotate_reference_body",
    "shift_reference_clock",
    "stress",
    "vibration_signal",
    "GOALS",
    "compose_truth",
    "alignment_errors",
    "matrix_to_quat",
    "quat_mul",
    "quat_to_matrix",
    "rotvec_to_matrix",
]

GT_MAX_GAP = 0.05  # s: a gap in a ``gt_t`` track longer than this is a reference gap (readers' default)


# ----------------------------------------------------------------------------- rotations (jaxcal.rotation, float64)


@float64
def _f64(fn, *args) -> np.ndarray:
    """``fn(*args)`` of :mod:`jaxcal.rotation` in float64, as a numpy array."""
    return np.array(fn(*[jax.numpy.asarray(np.asarray(a, np.float64)) for a in args]))


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of ``[w, x, y, z]`` quaternions (:func:`jaxcal.rotation.quat_mul`, float64)."""
    return _f64(rotation.quat_mul, a, b)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (body to world) of ``[w, x, y, z]`` quaternions (:func:`jaxcal.rotation.matrix_from_quat`, float64)."""
    return _f64(rotation.matrix_from_quat, q)


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """``[w, x, y, z]`` quaternion (w >= 0) of a rotation matrix (:func:`jaxcal.rotation.quat_from_matrix`, float64)."""
    return _f64(rotation.quat_from_matrix, R)


def rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    """Exp of a rotation vector (rad; :func:`jaxcal.rotation.exp_so3`, float64)."""
    return _f64(rotation.exp_so3, v)


# ----------------------------------------------------------------------------- pose tracks


def _interp_track(ts, pos, quat, good, t, max_gap):
    """Pose of a track (``ts`` increasing, ``good`` usable samples) at times ``t``.

    Linear in position, slerp in attitude, between the bracketing samples. A time is ``ok`` when
    it lies inside the track and either falls exactly on a good sample or between two good
    samples at most ``max_gap`` s apart. Returns ``(pos, quat, ok)`` with NaN rows where not ok.
    """
    ts = np.asarray(ts, np.float64)
    t = np.asarray(t, np.float64)
    j = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 2)
    h = ts[j + 1] - ts[j]
    u = (t - ts[j]) / h
    inside = (t >= ts[0]) & (t <= ts[-1])
    ok = inside & (((u == 0) & good[j]) | ((u == 1) & good[j + 1]) | (good[j] & good[j + 1] & (h <= max_gap)))
    uc = np.clip(np.where(ok, u, 0.0), 0.0, 1.0)
    p0, p1 = np.nan_to_num(pos[j]), np.nan_to_num(pos[j + 1])
    q0 = np.where(np.isfinite(quat[j]).all(1, keepdims=True), quat[j], [1.0, 0, 0, 0])
    q1 = np.where(np.isfinite(quat[j + 1]).all(1, keepdims=True), quat[j + 1], [1.0, 0, 0, 0])
    p = (1 - uc)[:, None] * p0 + uc[:, None] * p1
    q = rotation.slerp_pairs(q0 / np.linalg.norm(q0, axis=1, keepdims=True), q1 / np.linalg.norm(q1, axis=1, keepdims=True), uc)
    # exactly on a sample: that sample, bit for bit
    on0, on1 = ok & (u == 0), ok & (u == 1) & ~(u == 0)
    p[on0], q[on0] = pos[j[on0]], quat[j[on0]]
    p[on1], q[on1] = pos[j[on1] + 1], quat[j[on1] + 1]
    p[~ok] = np.nan
    q[~ok] = np.nan
    return p, q, ok


def _grid_valid(rec: Recording) -> np.ndarray:
    """Usable reference samples on the IMU grid: finite pose and ``ref_valid`` (when given)."""
    good = np.isfinite(rec.pos_ref).all(1) & np.isfinite(rec.quat_ref).all(1)
    if rec.ref_valid is not None:
        good &= np.asarray(rec.ref_valid, bool)
    return good


def _has_track(rec: Recording) -> bool:
    return rec.gt_t is not None and rec.gt_pos is not None and rec.gt_quat is not None


def _sampler(rec: Recording, max_gap: float | None):
    """``f(times) -> (pos, quat, ok)``: the recording's reference pose at arbitrary times.

    Uses the track ``gt_t/gt_pos/gt_quat`` when present (gaps: spacing over ``max_gap``, default
    :data:`GT_MAX_GAP`; and, when the recording has ``ref_valid``, IMU samples it marks invalid,
    taken between the bracketing IMU samples); else the pose on the IMU grid (gaps: NaN rows or
    ``ref_valid`` False; spacing over ``max_gap``, default 1.5 sample intervals).
    """
    t = np.asarray(rec.t, np.float64)
    pos, quat = np.asarray(rec.pos_ref, np.float64), np.asarray(rec.quat_ref, np.float64)
    gv = _grid_valid(rec)
    if _has_track(rec):
        ts = np.asarray(rec.gt_t, np.float64)
        tp, tq = np.asarray(rec.gt_pos, np.float64), np.asarray(rec.gt_quat, np.float64)
        tgood = np.isfinite(tp).all(1) & np.isfinite(tq).all(1)
        mg = GT_MAX_GAP if max_gap is None else float(max_gap)
        has_rv = rec.ref_valid is not None
        rv = np.asarray(rec.ref_valid, bool) if has_rv else None

        def f(tq_: np.ndarray):
            p, q, ok = _interp_track(ts, tp, tq, tgood, tq_, mg)
            if has_rv:
                # the recording's own gap judgement on the IMU grid (held beyond its ends)
                tc = np.clip(tq_, t[0], t[-1])
                _, _, okg = _interp_track(t, np.zeros((len(t), 3)), np.tile([1.0, 0, 0, 0], (len(t), 1)), rv, tc, np.inf)
                ok = ok & okg
                p[~ok] = np.nan
                q[~ok] = np.nan
            return p, q, ok

        return f
    dt = float(np.median(np.diff(t)))
    mg = 1.5 * dt if max_gap is None else float(max_gap)
    return lambda tq_: _interp_track(t, pos, quat, gv, tq_, mg)


# ----------------------------------------------------------------------------- geometry and clock


def move_reference_point(rec: Recording, r: np.ndarray) -> Recording:
    """Move the reference point so the IMU sits at ``r`` (m, reference body frame) from it.

    ``p_ref' = p_ref - R_world_ref r`` on the IMU grid and, when present, on the track
    (``gt_pos`` with ``gt_quat``); attitude, clock and every other key unchanged.

    R_world_ref comes from :func:`jaxcal.rotation.matrix_from_quat` at JAX's default precision
    (float32 unless x64 is enabled: about 1e-7 relative, i.e. < 0.1 um for r < 1 m); kept so, as
    the experiment's concealed lever arm, bit for bit.

    Truth: lever arm r' = r0 + r (r0 the as-recorded one, both in the reference body frame);
    tau and R_ref_imu unchanged.

    Args:
        rec: the recording (pose ``pos_ref``/``quat_ref``, optionally the track ``gt_*``).
        r: (3,) displacement added to the lever arm (m, reference body frame).
    """
    from jaxcal.rotation import matrix_from_quat

    def moved(p, q):
        ok = np.isfinite(q).all(1)
        R = np.full((len(q), 3, 3), np.nan)
        R[ok] = np.asarray(matrix_from_quat(jax.numpy.asarray(q[ok])))
        return p - np.einsum("nij,j->ni", R, r)

    changes = {"pos_ref": moved(rec.pos_ref, rec.quat_ref)}
    if _has_track(rec):
        changes["gt_pos"] = moved(np.asarray(rec.gt_pos, np.float64), np.asarray(rec.gt_quat, np.float64))
    return rec.replace(**changes)


def conceal_lever_arm(rec: Recording, r: np.ndarray) -> Recording:
    """Conceal a lever arm ``r`` (m, reference frame): :func:`move_reference_point` (same code).

    Args:
        rec: the recording (with a pose).
        r: (3,) lever arm to conceal (m, reference body frame).
    """
    return move_reference_point(rec, r)


def rotate_reference_body(rec: Recording, R_delta: np.ndarray) -> Recording:
    """Rotate the mocap body frame: ``R_world_ref' = R_world_ref @ R_delta``.

    Quaternions: ``q' = q ⊗ q_delta`` (``quat_ref`` and, when present, ``gt_quat``); positions (the
    reference point) and the clock unchanged; NaN rows stay NaN. A body-frame vector v of the old
    frame reads ``R_delta^T v`` in the new one, so the body rate derived from the pose becomes
    ``R_delta^T w``.

    Truth: if the old reference frame was the IMU frame, afterwards ``R_ref_imu = R_delta^T``; in
    general ``R_ref_imu' = R_delta^T R_ref_imu``, and a lever arm r given in the old frame reads
    ``r' = R_delta^T r`` in the new one; tau unchanged.

    Args:
        rec: the recording (pose ``quat_ref``, optionally the track ``gt_quat``).
        R_delta: (3, 3) rotation matrix; anything else raises ``ValueError``.
    """
    R_delta = np.asarray(R_delta, np.float64)
    if R_delta.shape != (3, 3) or not np.allclose(R_delta @ R_delta.T, np.eye(3), atol=1e-9) or np.linalg.det(R_delta) < 0:
        raise ValueError("R_delta must be a 3x3 rotation matrix")
    qd = matrix_to_quat(R_delta)
    changes = {"quat_ref": quat_mul(np.asarray(rec.quat_ref, np.float64), qd)}
    if _has_track(rec):
        changes["gt_quat"] = quat_mul(np.asarray(rec.gt_quat, np.float64), qd)
    return rec.replace(**changes)


def shift_reference_clock(rec: Recording, tau: float, max_gap: float | None = None) -> Recording:
    """Shift the reference clock so the IMU lags the reference by ``tau`` more seconds.

    ``reference'(t) = reference(t + tau)``: the pose is re-interpolated at ``t + tau`` (linear in
    position, slerp in attitude) from the track ``gt_t/gt_pos/gt_quat`` when present, else from
    the pose on the IMU grid; the IMU streams are not touched. When present the track becomes
    ``gt_t' = gt_t - tau`` (same poses), which is the same function of time. Samples where
    ``t + tau`` lies outside the track or in a reference gap (see ``max_gap``; with a track and
    ``ref_valid``, also where the input's ``ref_valid`` was False) become NaN with
    ``ref_valid`` False; the output always has ``ref_valid``.

    Args:
        rec: recording.
        tau: seconds, either sign (tested from 1 ms to 0.5 s).
        max_gap: longest spacing (s) of source samples that is interpolated across; default
            0.05 s for a track, 1.5 IMU sample intervals for the grid pose.

    Truth: time_offset tau' = tau0 + tau (the IMU reads x(t - tau') against the new reference);
    lever arm and R_ref_imu unchanged.
    """
    tau = float(tau)
    t = np.asarray(rec.t, np.float64)
    p, q, ok = _sampler(rec, max_gap)(t + tau)
    changes = {"pos_ref": p, "quat_ref": q, "ref_valid": ok}
    if _has_track(rec):
        changes["gt_t"] = np.asarray(rec.gt_t, np.float64) - tau
    return rec.replace(**changes)


# ----------------------------------------------------------------------------- mocap as a real system


def decimate_reference(
    rec: Recording,
    rng: np.random.Generator,
    rate_hz: float = 100.0,
    jitter_s: float = 0.003,
    dropout_frac: float = 0.02,
    dropout_len: tuple[float, float] = (0.02, 0.3),
    max_gap: float | None = None,
    nan_invalid: bool = True,
) -> Recording:
    """Re-record the reference as a slow, jittery, lossy motion-capture system.

    1. Stamps ``k / rate_hz`` over the span of the source (the track ``gt_*`` when present, else
       the pose on the IMU grid; its gaps as in :func:`shift_reference_clock`, ``max_gap``).
    2. Each pose is taken at the true time ``k / rate_hz + e_k``, ``e_k ~ N(0, jitter_s)``
       (interpolated from the source), but stamped ``k / rate_hz``. Samples whose true time falls
       outside the source or in one of its gaps are lost.
    3. Random dropout runs (lengths uniform in ``dropout_len`` s, starts uniform) are removed until
       a fraction ``>= dropout_frac`` of the stamps is gone (``dropout_frac = 0``: none).
    4. The track is attached to the IMU grid by :func:`jaxcal.formats.pose.attach_pose` with
       ``max_gap = 1.5 / rate_hz``: ``pos_ref``/``quat_ref`` interpolated, ``ref_valid`` False
       across every missing stamp (dropouts) and outside the track, ``gt_t``/``gt_pos``/
       ``gt_quat`` = the decimated track. With ``nan_invalid`` (default) the pose is also NaN
       where ``ref_valid`` is False (``jaxcal diagnose`` reads gaps from NaN rows).

    Random draws, in order: jitter (one normal per stamp), then per dropout run its length and start.

    Truth: unchanged (the jitter is zero-mean, so there is no bias in time; the pose error on the
    IMU grid is about jitter x speed, plus the linear-interpolation error of a ``rate_hz`` track).

    Args:
        rec: the recording (a pose on the IMU grid, optionally the track ``gt_*``).
        rng: numpy generator (jitter, then dropout runs).
        rate_hz: motion-capture rate (Hz).
        jitter_s: time-stamp jitter std (s); 0: none.
        dropout_frac: fraction of stamps removed in runs; 0: none.
        dropout_len: ``(min, max)`` length of a dropout run (s).
        max_gap: longest source spacing interpolated across (s); None: as in :func:`shift_reference_clock`.
        nan_invalid: also set the pose to NaN where ``ref_valid`` is False.
    """
    from jaxcal.formats.pose import attach_pose

    rate = float(rate_hz)
    sample = _sampler(rec, max_gap)
    if _has_track(rec):
        span = np.asarray(rec.gt_t, np.float64)
        span = (span[0], span[-1])
    else:
        span = (float(rec.t[0]), float(rec.t[-1]))
    k = np.arange(np.ceil(span[0] * rate), np.floor(span[1] * rate) + 1)
    stamps = k / rate
    e = rng.normal(0.0, jitter_s, len(stamps)) if jitter_s > 0 else np.zeros(len(stamps))
    p, q, ok = sample(stamps + e)
    keep = ok.copy()
    if dropout_frac > 0 and len(stamps) > 1:
        lo, hi = float(dropout_len[0]), float(dropout_len[1])
        drop = np.zeros(len(stamps), bool)
        for _ in range(100000):
            if drop.mean() >= dropout_frac:
                break
            L = rng.uniform(lo, hi)
            s0 = rng.uniform(stamps[0], max(stamps[0], stamps[-1] - L))
            drop |= (stamps >= s0) & (stamps < s0 + L)
        keep &= ~drop
    if keep.sum() < 2:
        raise ValueError("decimated reference has fewer than 2 samples")
    pose = {"t": rec.t}  # attach_pose fills pos_ref, quat_ref, ref_valid and the track gt_*
    attach_pose(pose, stamps[keep], p[keep], q[keep], 1.5 / rate, where="decimated pose")
    if nan_invalid:
        bad = ~pose["ref_valid"]
        pose["pos_ref"] = np.where(bad[:, None], np.nan, pose["pos_ref"])
        pose["quat_ref"] = np.where(bad[:, None], np.nan, pose["quat_ref"])
    del pose["t"]
    return rec.replace(**pose)


def vibration_signal(
    rng: np.random.Generator,
    n: int,
    fs: float,
    rms: float,
    band_hz: tuple[float, float] = (80.0, 250.0),
    oversample: int = 8,
    order: int = 8,
) -> np.ndarray:
    """Band-limited vibration at ``oversample * fs``: (n * oversample, 3), rms ``rms`` per axis.

    White Gaussian noise (``rng.standard_normal((n * oversample, 3))``), Butterworth band-pass
    ``band_hz`` of ``order`` run forward and backward (``sosfiltfilt``, zero phase; with the default
    order 8 about 1.2 % of the power lies outside ``band_hz``, 2.6 % with order 4), each axis then
    scaled to exactly ``rms``.

    Args:
        rng: numpy generator.
        n: IMU samples (the output has ``n * oversample`` rows).
        fs: IMU rate (Hz).
        rms: rms per axis of the output (in the unit wanted).
        band_hz: ``(low, high)`` pass band (Hz), inside ``(0, oversample * fs / 2)``.
        oversample: rate of the signal, in multiples of ``fs``.
        order: Butterworth filter order.
    """
    from scipy.signal import butter, sosfiltfilt

    fs_hi = float(fs) * int(oversample)
    lo, hi = float(band_hz[0]), float(band_hz[1])
    if not 0 < lo < hi < fs_hi / 2:
        raise ValueError(f"band {band_hz} Hz must lie inside (0, {fs_hi / 2:g}) Hz (oversample x rate / 2)")
    x = rng.standard_normal((int(n) * int(oversample), 3))
    sos = butter(order, [lo, hi], btype="bandpass", fs=fs_hi, output="sos")
    x = sosfiltfilt(sos, x, axis=0)
    return x * (float(rms) / np.sqrt(np.mean(x**2, axis=0)))


def add_vibration(
    rec: Recording,
    rng: np.random.Generator,
    rms_g: float = 0.3,
    band_hz: tuple[float, float] = (80.0, 250.0),
    oversample: int = 8,
    gyr_rms: float = 0.0,
) -> Recording:
    """Rotor-like vibration on the accelerometer (and optionally the gyroscope), aliased.

    :func:`vibration_signal` at ``oversample`` x the IMU rate (rms ``rms_g`` per axis at that
    rate), then every ``oversample``-th sample is added to ``acc`` with NO anti-alias filter, so
    energy above the IMU's Nyquist frequency aliases into its band (MEMS parts without an
    anti-alias filter). With ``gyr_rms > 0`` (rad/s) an independent draw of the same band is added
    to ``gyr`` (drawn after the accelerometer's). The IMU grid is taken as uniform (median step).

    Truth: unchanged (zero-mean noise).

    Args:
        rec: the recording (``acc`` in g, ``gyr`` in rad/s).
        rng: numpy generator (the accelerometer's draw, then the gyroscope's).
        rms_g: accelerometer vibration, rms per axis at the oversampled rate (g).
        band_hz: ``(low, high)`` vibration band (Hz).
        oversample: rate of the vibration, in multiples of the IMU rate.
        gyr_rms: gyroscope vibration, rms per axis (rad/s); 0: none.
    """
    for k, u in (("acc", "g"), ("gyr", "rad/s")):
        unit = getattr(rec, f"{k}_unit")
        if getattr(rec, k) is not None and unit != u:
            raise ValueError(f"add_vibration needs {k} in {u} ({k}_unit = {unit!r})")
    t = np.asarray(rec.t, np.float64)
    n = len(t)
    fs = 1.0 / float(np.median(np.diff(t)))
    os_ = int(oversample)
    changes = {"acc": np.asarray(rec.acc, np.float64) + vibration_signal(rng, n, fs, rms_g, band_hz, os_)[::os_][:n]}
    if gyr_rms > 0:
        changes["gyr"] = np.asarray(rec.gyr, np.float64) + vibration_signal(rng, n, fs, gyr_rms, band_hz, os_)[::os_][:n]
    return rec.replace(**changes)


# ----------------------------------------------------------------------------- composed stress


class StressConfig(NamedTuple):
    """One stress of a recording (see :func:`stress`).

    Attributes:
        rate_hz: motion-capture rate (Hz).
        jitter_s: motion-capture time-stamp jitter, 1 sigma (s).
        dropout_frac: fraction of motion-capture samples lost in runs.
        vibration_rms_g: accelerometer vibration, rms per axis (g); 0: none.
        lever_arm_m: reference point move (m), in the input's reference body frame.
        rotation_deg: reference body rotation, axis-angle (deg).
        clock_shift_s: ``tau`` added to the IMU's lag behind the reference (s).
        dropout_len_s: ``(min, max)`` length of a dropout run (s).
        vibration_band_hz: ``(low, high)`` vibration band (Hz).
    """

    rate_hz: float = 100.0  # mocap rate
    jitter_s: float = 0.003  # mocap time-stamp jitter (1 sigma)
    dropout_frac: float = 0.02  # fraction of mocap samples lost in runs
    vibration_rms_g: float = 0.3  # accelerometer vibration, rms per axis (g); 0: none
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # reference point move, input's reference frame
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)  # reference body rotation, axis-angle (deg)
    clock_shift_s: float = 0.0  # tau added to the IMU's lag behind the reference
    dropout_len_s: tuple[float, float] = (0.02, 0.3)  # dropout run lengths (s)
    vibration_band_hz: tuple[float, float] = (80.0, 250.0)  # vibration band


def stress(rec: Recording, cfg: StressConfig, rng: np.random.Generator) -> tuple[Recording, dict]:
    """Apply a :class:`StressConfig`; returns ``(stressed recording, truth)``.

    Order (each step acts on the physical object the previous one left): move the reference point
    by ``lever_arm_m`` (in the input's reference frame), rotate the reference body by
    ``R_delta = Exp(radians(rotation_deg))``, shift the reference clock by ``clock_shift_s``,
    decimate the reference (``rate_hz``, ``jitter_s``, ``dropout_frac``, ``dropout_len_s``), add
    vibration (``vibration_rms_g`` in ``vibration_band_hz``; skipped when 0). Random draws:
    decimation, then vibration, from ``rng``.

    Truth, given that the input's reference frame was the IMU frame with zero offsets::

        {"tau": clock_shift_s,                    # s, IMU lags the new reference
         "R_ref_imu": R_delta^T,                  # IMU frame -> new reference body frame
         "r": R_delta^T lever_arm_m,              # m, IMU from new reference point, new ref frame
         "R_delta": R_delta}

    The as-recorded offsets (tau0, R0, r0) add on top: tau0 + tau, R_delta^T R0,
    R_delta^T (r0 + lever_arm_m).

    Args:
        rec: the recording (``acc``/``gyr`` in g and rad/s, pose ``pos_ref``/``quat_ref``).
        cfg: the stress.
        rng: numpy generator (decimation, then vibration).
    """
    r = np.asarray(cfg.lever_arm_m, np.float64)
    Rd = rotvec_to_matrix(np.deg2rad(np.asarray(cfg.rotation_deg, np.float64)))
    out = move_reference_point(rec, r) if np.any(r != 0) else rec.replace()
    out = rotate_reference_body(out, Rd)
    if cfg.clock_shift_s != 0:
        out = shift_reference_clock(out, cfg.clock_shift_s)
    out = decimate_reference(out, rng, cfg.rate_hz, cfg.jitter_s, cfg.dropout_frac, tuple(cfg.dropout_len_s))
    if cfg.vibration_rms_g > 0:
        out = add_vibration(out, rng, cfg.vibration_rms_g, tuple(cfg.vibration_band_hz))
    truth = {"tau": float(cfg.clock_shift_s), "R_ref_imu": Rd.T.copy(), "r": Rd.T @ r, "R_delta": Rd}
    return out, truth


def random_stress_config(rng: np.random.Generator) -> StressConfig:
    """A random, realistic :class:`StressConfig`.

    Lever arm: norm uniform 5-20 cm, direction uniform on the sphere; rotation: angle uniform 1-10
    deg about a uniform axis; clock shift: 5-250 ms uniform, random sign; vibration 0.1-0.5 g rms;
    jitter 1-5 ms; mocap 100 Hz; 2 % dropouts.
    """
    u = rng.standard_normal(3)
    lever = rng.uniform(0.05, 0.20) * u / np.linalg.norm(u)
    a = rng.standard_normal(3)
    rot = rng.uniform(1.0, 10.0) * a / np.linalg.norm(a)
    shift = rng.uniform(0.005, 0.25) * rng.choice([-1.0, 1.0])
    return StressConfig(
        rate_hz=100.0,
        jitter_s=float(rng.uniform(0.001, 0.005)),
        dropout_frac=0.02,
        vibration_rms_g=float(rng.uniform(0.1, 0.5)),
        lever_arm_m=tuple(float(x) for x in lever),
        rotation_deg=tuple(float(x) for x in rot),
        clock_shift_s=float(shift),
    )


# ----------------------------------------------------------------------------- scoring an alignment

GOALS = {"tau_s": 1e-3, "rotation_deg": 0.5, "r_m": 0.01}  # issue 14's goals; or 3 standard errors, the larger


def compose_truth(truth: dict, tau0: float, R0: np.ndarray, r0: np.ndarray) -> dict:
    """The expected alignment of a stressed real recording: the stress's ``truth`` (for an input
    with zero offsets, :func:`stress`) composed with the input's as-recorded estimates
    ``(tau0, R0 = R_ref_imu, r0)``: ``tau0 + tau``, ``R_delta^T R0``, ``r + R_delta^T r0``.

    Args:
        truth: the truth dict :func:`stress` returns.
        tau0: as-recorded time offset (s).
        R0: (3, 3) as-recorded ``R_ref_imu``.
        r0: (3,) as-recorded lever arm (m, reference body frame).
    """
    Rt = np.asarray(truth["R_ref_imu"], np.float64)
    return {"tau": float(tau0) + float(truth["tau"]), "R_ref_imu": Rt @ np.asarray(R0, np.float64),
            "r": np.asarray(truth["r"], np.float64) + Rt @ np.asarray(r0, np.float64)}


def alignment_errors(align: dict, expected: dict, goals: dict = GOALS) -> dict:
    """Errors of an ``align.json`` dict against ``expected`` (:func:`compose_truth`) and whether
    each lies within its goal: ``|err| <= max(goal, 3 standard errors)`` (per component for ``r``).
    The rotation error is the angle of ``R_est R_expected^T``.

    Args:
        align: an ``align.json`` dict (``tau``, ``tau_stderr``, ``R_ref_imu``, optionally
            ``rotation_deg_stderr``, ``r`` and ``stderr.r``).
        expected: the expected alignment (:func:`compose_truth`).
        goals: tolerance per quantity (``tau_s``, ``rotation_deg``, ``r_m``); default :data:`GOALS`.
    """
    from scipy.spatial.transform import Rotation

    tau_err = float(align["tau"]) - float(expected["tau"])
    tau_se = float(align["tau_stderr"])
    rot_err = float(np.degrees(np.linalg.norm(Rotation.from_matrix(np.asarray(align["R_ref_imu"]) @ np.asarray(expected["R_ref_imu"]).T).as_rotvec())))
    rot_se = float(align.get("rotation_deg_stderr") or 0.0)
    out = {"tau_err_s": tau_err, "tau_se_s": tau_se, "tau_ok": abs(tau_err) <= max(goals["tau_s"], 3 * tau_se),
           "rotation_err_deg": rot_err, "rotation_se_deg": rot_se, "rotation_ok": rot_err <= max(goals["rotation_deg"], 3 * rot_se)}
    if align.get("r") is not None:
        r_err = np.asarray(align["r"], np.float64) - np.asarray(expected["r"], np.float64)
        r_se = np.asarray(align["stderr"]["r"], np.float64)
        out.update({"r_err_m": r_err.tolist(), "r_se_m": r_se.tolist(), "r_err_norm_m": float(np.linalg.norm(r_err)),
                    "r_ok": bool(np.all(np.abs(r_err) <= np.maximum(goals["r_m"], 3 * r_se)))})
    out["all_ok"] = bool(out["tau_ok"] and out["rotation_ok"] and out.get("r_ok", True))
    return out
