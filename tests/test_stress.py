"""jaxcal.diagnose.stress: every stress against a truth computed independently of it.

The recording is synthetic and analytic: attitude R(t) = Exp(phi(t)) with phi a sum of sines, so the
body rate is w = J_r(phi) phi' in closed form (J_r the right Jacobian of SO(3)); the position is a
sum of sines, so the specific force f = R^T (p'' / g0 + e_z) is closed form too. The IMU sits at the
reference point with the reference body frame as its frame (tau = 0, R_ref_imu = I, r = 0).
Rotations in the checks use scipy.spatial.transform.Rotation, not jaxcal code.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import FS, make_rec, rot_of, truth_pos, truth_rate, truth_rot
from scipy.signal import welch
from scipy.spatial.transform import Rotation

from jaxcal.diagnose import conceal as C
from jaxcal.diagnose import stress as S
from jaxcal.recording import Recording


def frozen(rec: Recording) -> Recording:
    """Copy with read-only arrays: an in-place write by the code under test raises."""
    def ro(v):
        if isinstance(v, np.ndarray):
            v = v.copy()
            v.flags.writeable = False
        return v

    d = rec.to_dict()
    return rec.replace(**{k: ro(v) for k, v in d.items() if k not in rec.extra},
                       extra={k: ro(v) for k, v in rec.extra.items()})


@pytest.fixture(scope="module")
def rec():
    return frozen(make_rec(False))


@pytest.fixture(scope="module")
def rec_track():
    return frozen(make_rec(True))


def derived_rate(t, q):
    """Body rate on the grid from a pose: log(R_n^T R_n+1) / dt at mid-points, neighbours averaged."""
    dt = float(np.median(np.diff(t)))
    ok = np.isfinite(q).all(1)
    qq = np.where(ok[:, None], q, [1.0, 0, 0, 0])
    R = rot_of(qq)
    wm = (R[:-1].inv() * R[1:]).as_rotvec() / dt
    wm[~(ok[:-1] & ok[1:])] = np.nan
    w = np.full((len(t), 3), np.nan)
    w[1:-1] = 0.5 * (wm[1:] + wm[:-1])
    return w


def lag_s(a, b, t):
    """L (s) maximising the correlation of a(t) with b(t - L): a lags b by L. Coarse FFT search, then
    a 0.01-sample grid with b linearly interpolated."""
    fs = 1 / float(np.median(np.diff(t)))
    m = np.isfinite(a) & np.isfinite(b)
    a0 = np.where(m, a - a[m].mean(), 0.0)
    b0 = np.where(m, b - b[m].mean(), 0.0)
    n = len(a)
    xc = np.fft.irfft(np.fft.rfft(a0, 2 * n) * np.conj(np.fft.rfft(b0, 2 * n)), 2 * n)
    k = int(np.argmax(np.concatenate([xc[-n + 1:], xc[:n]]))) - (n - 1)
    bf = np.where(np.isfinite(b), b, np.nan)
    best, bestL = -np.inf, 0.0
    inner = m.copy()
    edge = abs(k) + 5
    inner[:edge] = inner[-edge:] = False
    for L in (k + np.linspace(-1.5, 1.5, 301)) / fs:
        bs = np.interp(t - L, t, bf)
        mm = inner & np.isfinite(bs)
        x, y = a[mm] - a[mm].mean(), bs[mm] - bs[mm].mean()
        c = x @ y / np.sqrt((x @ x) * (y @ y))
        if c > best:
            best, bestL = c, L
    return bestL


def same(x: Recording | dict, y: Recording | dict) -> bool:
    x, y = (r.to_dict() if isinstance(r, Recording) else r for r in (x, y))
    if x.keys() != y.keys():
        return False
    for k in x:
        a, b = np.asarray(x[k]), np.asarray(y[k])
        if a.shape != b.shape or not np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
            return False
    return True


# ----------------------------------------------------------------------------- (a) reference point


@pytest.mark.parametrize("track", [False, True])
def test_move_reference_point_recovers_original(rec, rec_track, track):
    r0 = rec_track if track else rec
    r = np.array([0.07, -0.12, 0.05])
    out = S.move_reference_point(r0, r)
    # R from jaxcal.rotation at JAX's default (float32) precision: ~1e-7 of |r|
    np.testing.assert_allclose(out.pos_ref + rot_of(out.quat_ref).apply(r), r0.pos_ref, atol=1e-7)
    np.testing.assert_array_equal(out.quat_ref, r0.quat_ref)
    if track:
        np.testing.assert_allclose(out.gt_pos + rot_of(out.gt_quat).apply(r), r0.gt_pos, atol=1e-7)
    # conceal_lever_arm is the same function
    assert same(S.conceal_lever_arm(r0, r), out)


# ----------------------------------------------------------------------------- (b) reference body


def test_rotate_reference_body_inverse_and_rate(rec_track):
    Rd = Rotation.from_rotvec(np.deg2rad([4.0, -7.0, 2.5])).as_matrix()
    out = S.rotate_reference_body(rec_track, Rd)
    # R_world_ref' = R_world_ref Rd
    np.testing.assert_allclose(rot_of(out.quat_ref).as_matrix(), rot_of(rec_track.quat_ref).as_matrix() @ Rd, atol=1e-12)
    back = S.rotate_reference_body(out, Rd.T)
    for k in ("quat_ref", "gt_quat"):
        q0, q1 = getattr(rec_track, k), getattr(back, k)
        sgn = np.sign(np.sum(q0 * q1, 1))[:, None]
        np.testing.assert_allclose(q1 * sgn, q0, atol=1e-12)
    np.testing.assert_array_equal(out.pos_ref, rec_track.pos_ref)
    # body rate from the new pose = Rd^T w, against the analytic rate
    t = rec_track.t
    w_new = derived_rate(t, out.quat_ref)
    w_true = truth_rate(t)
    sl = slice(1, -1)
    err = w_new[sl] - w_true[sl] @ Rd  # rows: (Rd^T w)^T = w^T Rd
    assert np.sqrt(np.mean(err**2)) < 2e-3 * np.sqrt(np.mean(w_true**2)), np.sqrt(np.mean(err**2))
    # and exactly Rd^T (rate from the old pose)
    np.testing.assert_allclose(w_new[sl], derived_rate(t, rec_track.quat_ref)[sl] @ Rd, atol=1e-9)


def test_rotate_reference_body_rejects_non_rotation(rec):
    with pytest.raises(ValueError):
        S.rotate_reference_body(rec, np.diag([1.0, 1.0, -1.0]))


# ----------------------------------------------------------------------------- (c) clock


@pytest.mark.parametrize("tau,track", [(0.001, False), (-0.0137, False), (0.25, False), (-0.5, False), (0.1234, True), (-0.00377, True), (-0.5, True)])
def test_shift_reference_clock_lag_and_round_trip(rec, rec_track, tau, track):
    r0 = rec_track if track else rec
    t = r0.t
    g = np.linalg.norm(r0.gyr, axis=1)
    out = S.shift_reference_clock(r0, tau)
    L0 = lag_s(g, np.linalg.norm(derived_rate(t, r0.quat_ref), axis=1), t)
    L1 = lag_s(g, np.linalg.norm(derived_rate(t, out.quat_ref), axis=1), t)
    assert abs(L0) < 0.05 / FS, L0
    assert abs((L1 - L0) - tau) < 0.1 / FS, (L1 - L0, tau)
    # samples whose t + tau leaves the source are NaN and invalid; the rest valid
    span = (r0.gt_t[0], r0.gt_t[-1]) if track else (t[0], t[-1])
    inside = (t + tau >= span[0]) & (t + tau <= span[1])
    np.testing.assert_array_equal(out.ref_valid, inside)
    assert np.isnan(out.pos_ref[~inside]).all() and np.isnan(out.quat_ref[~inside]).all()
    # pose = the source interpolated at t + tau (linear / slerp), and so the truth at t + tau
    ok = out.ref_valid
    ts, ps = (r0.gt_t, r0.gt_pos) if track else (t, r0.pos_ref)
    lin = np.stack([np.interp(t[ok] + tau, ts, ps[:, c]) for c in range(3)], 1)
    np.testing.assert_allclose(out.pos_ref[ok], lin, atol=1e-12)
    np.testing.assert_allclose(out.pos_ref[ok], truth_pos(t[ok] + tau), atol=1e-4)
    ang = (rot_of(out.quat_ref[ok]).inv() * truth_rot(t[ok] + tau)).magnitude()
    assert ang.max() < 1e-4, ang.max()
    # tau then -tau: the original away from the edges (with a track: exactly the track at t)
    back = S.shift_reference_clock(out, -tau)
    e = int(np.ceil(abs(tau) * FS)) + 2
    sl = slice(e, -e)
    assert back.ref_valid[sl].all()
    base = S.shift_reference_clock(r0, 0.0) if track else r0
    np.testing.assert_allclose(back.pos_ref[sl], base.pos_ref[sl], atol=1e-12 if track else 1e-4)
    ang = (rot_of(back.quat_ref[sl]).inv() * rot_of(base.quat_ref[sl])).magnitude()
    assert ang.max() < (1e-9 if track else 2e-4), ang.max()
    if track:
        np.testing.assert_allclose(out.gt_t, r0.gt_t - tau, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- (d) decimation


def test_decimate_reference(rec):
    jit = 0.003
    out = S.decimate_reference(rec, np.random.default_rng(7), rate_hz=100.0, jitter_s=jit, dropout_frac=0.02)
    gt = out.gt_t
    k = np.round(gt * 100.0)
    np.testing.assert_allclose(gt, k / 100.0, rtol=0, atol=1e-12)  # stamps on the 100 Hz grid
    k_all = np.arange(np.ceil(rec.t[0] * 100), np.floor(rec.t[-1] * 100) + 1)
    missing = np.setdiff1d(k_all, k)
    # ends may lose a sample whose jittered time left the source; dropouts are inside
    frac = len(missing) / len(k_all)
    assert 0.02 <= frac < 0.02 + 0.006 + 2 / len(k_all), frac
    t, v = rec.t, out.ref_valid
    # IMU samples between two kept consecutive stamps are valid, those across a missing stamp not
    # (as jaxcal.readers._attach_pose: the interval [gt_j, gt_j+1) with gt_j < t <= gt_j+1)
    jj = np.clip(np.searchsorted(gt, t) - 1, 0, len(gt) - 2)
    consecutive = (k[jj + 1] - k[jj] == 1) & (t >= gt[0]) & (t <= gt[-1])
    np.testing.assert_array_equal(v, consecutive)
    in_drop = np.isin(np.floor(t * 100 + 1e-9), missing) & ~np.isin(t, gt)
    assert in_drop.sum() > 0.015 * len(t) and not v[in_drop].any()
    assert np.isnan(out.pos_ref[~v]).all()
    # the track holds the poses at the true times k/100 + e_k: e_k recovered along the velocity
    vel = truth_pos(gt, 1)
    sp2 = np.sum(vel**2, 1)
    fast = sp2 > 0.25
    e = np.sum((out.gt_pos - truth_pos(gt)) * vel, 1)[fast] / sp2[fast]
    assert abs(np.std(e) / jit - 1) < 0.06, np.std(e)
    assert abs(np.mean(e)) < 4 * jit / np.sqrt(fast.sum()), np.mean(e)
    # pose error on the IMU grid (valid samples) ~ jitter x speed: interpolation of two errors
    u = (t - gt[jj]) / 0.01
    expect = jit * np.sqrt(np.mean((np.sum(truth_pos(t, 1) ** 2, 1) * ((1 - u) ** 2 + u**2))[v]))
    rms = np.sqrt(np.mean(np.sum((out.pos_ref[v] - truth_pos(t[v])) ** 2, 1)))
    assert 0.85 < rms / expect < 1.15, (rms, expect)
    # zero jitter, no dropouts: the exact pose at the stamps
    exact = S.decimate_reference(rec, np.random.default_rng(7), jitter_s=0.0, dropout_frac=0.0)
    assert len(exact.gt_t) == len(k_all)
    np.testing.assert_allclose(exact.gt_pos, truth_pos(exact.gt_t), atol=1e-4)


# ----------------------------------------------------------------------------- (e) vibration


def test_add_vibration(rec):
    out = S.add_vibration(rec, np.random.default_rng(3), rms_g=0.3, band_hz=(80.0, 250.0), oversample=8)
    d = out.acc - rec.acc
    np.testing.assert_allclose(np.sqrt(np.mean(d**2, 0)), 0.3, rtol=0.05)
    np.testing.assert_array_equal(out.gyr, rec.gyr)
    hi = S.vibration_signal(np.random.default_rng(3), len(rec.t), FS, 0.3, (80.0, 250.0), 8)
    np.testing.assert_allclose(d, hi[::8], rtol=0, atol=1e-12)  # plain sampling: no anti-alias filter
    f, p = welch(hi, fs=8 * FS, nperseg=4096, axis=0)
    band = (f >= 80) & (f <= 250)
    out_frac = p[~band].sum(0) / p.sum(0)
    assert (out_frac < 0.02).all(), out_frac
    # gyro part on request
    g = S.add_vibration(rec, np.random.default_rng(3), rms_g=0.3, gyr_rms=0.05)
    np.testing.assert_array_equal(g.acc, out.acc)
    np.testing.assert_allclose(np.sqrt(np.mean((g.gyr - rec.gyr) ** 2, 0)), 0.05, rtol=0.05)


# ----------------------------------------------------------------------------- (f) composed stress


def test_stress_truth_composes(rec_track):
    cfg = S.StressConfig(rate_hz=100.0, jitter_s=0.001, dropout_frac=0.02, vibration_rms_g=0.2,
                         lever_arm_m=(0.08, -0.05, 0.11), rotation_deg=(3.0, -6.0, 4.0), clock_shift_s=0.047)
    out, truth = S.stress(rec_track, cfg, np.random.default_rng(11))
    Rd = Rotation.from_rotvec(np.deg2rad(cfg.rotation_deg)).as_matrix()
    np.testing.assert_allclose(truth["R_ref_imu"], Rd.T, atol=1e-12)
    np.testing.assert_allclose(truth["r"], Rd.T @ np.array(cfg.lever_arm_m), atol=1e-12)
    assert truth["tau"] == cfg.clock_shift_s
    t, v, tau = out.t, out.ref_valid, truth["tau"]
    # Wahba (closed form, SVD): derived reference rate at t vs the IMU's gyro at t + tau
    w_ref = derived_rate(t, out.quat_ref)
    w_imu = truth_rate(t + tau)
    m = np.isfinite(w_ref).all(1)
    B = w_ref[m].T @ w_imu[m]
    U, _, Vt = np.linalg.svd(B)
    R_hat = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    ang = np.rad2deg(Rotation.from_matrix(R_hat.T @ truth["R_ref_imu"]).magnitude())
    assert ang < 0.1, ang
    # the IMU (old reference point, truth position p(t + tau)) sits at r from the new reference point
    p_imu = out.pos_ref[v] + rot_of(out.quat_ref[v]).apply(truth["r"])
    err = np.linalg.norm(p_imu - truth_pos(t[v] + tau), axis=1)
    assert np.sqrt(np.mean(err**2)) < 3e-3, np.sqrt(np.mean(err**2))
    # vibration present, gyro untouched, deterministic for a seed
    assert 0.15 < np.sqrt(np.mean((out.acc - rec_track.acc) ** 2)) < 0.25
    np.testing.assert_array_equal(out.gyr, rec_track.gyr)
    out2, truth2 = S.stress(rec_track, cfg, np.random.default_rng(11))
    assert same(out, out2) and same(truth, truth2)
    out3, _ = S.stress(rec_track, cfg, np.random.default_rng(12))
    assert not same(out, out3)


def test_random_stress_config_ranges():
    rng = np.random.default_rng(0)
    for _ in range(200):
        c = S.random_stress_config(rng)
        assert 0.05 <= np.linalg.norm(c.lever_arm_m) <= 0.20
        assert 1.0 <= np.linalg.norm(c.rotation_deg) <= 10.0
        assert 0.005 <= abs(c.clock_shift_s) <= 0.25
        assert 0.1 <= c.vibration_rms_g <= 0.5 and 0.001 <= c.jitter_s <= 0.005
        assert c.rate_hz == 100.0 and c.dropout_frac == 0.02
    signs = {np.sign(S.random_stress_config(rng).clock_shift_s) for _ in range(50)}
    assert signs == {-1.0, 1.0}


# ----------------------------------------------------------------------------- (g) no mutation


def test_inputs_never_mutated(rec_track):
    ref = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in rec_track.to_dict().items()}
    x = frozen(rec_track)  # read-only arrays: any in-place write raises
    rng = np.random.default_rng(0)
    outs = [
        S.move_reference_point(x, np.array([0.1, 0.0, 0.0])),
        S.rotate_reference_body(x, Rotation.from_rotvec([0.1, 0.0, 0.0]).as_matrix()),
        S.shift_reference_clock(x, 0.02),
        S.decimate_reference(x, rng),
        S.add_vibration(x, rng, gyr_rms=0.01),
        S.stress(x, S.random_stress_config(rng), rng)[0],
        C.conceal(x, "acc", "lever_arm", np.array([0.01, 0.02, 0.03])),
        C.conceal(x, "gyr", "time_offset", np.array([0.003])),
        C.conceal(x, "gyr", "g_sensitivity", np.full(9, 1e-3)),
        C.conceal(x, "acc", "misalignment", np.full(6, 1e-3)),
        C.conceal(x, "gyr", "bias_drift", np.full(3, 1e-4)),
    ]
    assert same(x, ref)
    assert all(o is not x for o in outs)
    with pytest.raises(KeyError):
        C.conceal(x, "acc", "nonsense", np.zeros(3))
