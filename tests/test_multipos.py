"""multipos and static detection: recovery of known parameters on a simulated multi-position
recording (closed-form truth), invariants of the 12-parameter model, and the Xsens goal
(held-out |f| error below the factory calibration's)."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcal import multipos as mp
from jaxcal.readers import load_npz
from jaxcal.rotation import exp_so3, log_so3, random_rotation


def _exp_np(v):
    th = np.linalg.norm(v)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    if th < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + np.sin(th) / th * k + (1 - np.cos(th)) / th**2 * (k @ k)
from jaxcal.static import detect_static, intervals_from_mask, moving_variance

DATA = Path(__file__).resolve().parent.parent / "data"

# truth: applied calibrations x = A (y - b); the accelerometer's A is T diag(k) with T unit
# lower-triangular (the 9-parameter model's frame), the gyro's A is a full matrix.
A_ACC = np.array([[1.0, 0.0, 0.0], [0.012, 1.0, 0.0], [-0.008, 0.02, 1.0]]) @ np.diag([1 / 16000, 1 / 16700, 1 / 16200])
B_ACC = np.array([310.0, -540.0, 820.0])
A_GYR = np.array([[1.03, 0.01, -0.02], [-0.015, 0.97, 0.012], [0.008, 0.02, 1.01]]) / 7500.0
B_GYR = np.array([-420.0, 150.0, -80.0])


def simulate(key, n_poses=24, fs=100.0, rest=10.0, hold=2.0, move=1.5, noise=True):
    """Rest, then ``n_poses`` random static poses joined by constant-rate body rotations.

    Body rate ``w`` is constant over each move, ``R(t) = R_j Exp(w t)``; the specific force is
    ``f = R^T (0, 0, 1)`` g (z up). Raw = ``A^-1 x + b`` rounded to counts (+ white noise).
    """
    dt = 1.0 / fs
    rots = np.asarray(random_rotation(key, (n_poses,)), np.float64)
    rots[0] = np.eye(3)
    f_list, w_list = [], []
    n_rest = int(rest * fs)
    for j in range(n_poses):
        n_hold = n_rest if j == 0 else int(hold * fs)
        f_list.append(np.tile(rots[j].T @ [0, 0, 1.0], (n_hold, 1)))
        w_list.append(np.zeros((n_hold, 3)))
        if j + 1 < n_poses:
            n_move = int(move * fs)
            w = np.asarray(log_so3(jnp.asarray(rots[j].T @ rots[j + 1]))) / (n_move * dt)
            r = rots[j].copy()
            step = _exp_np(w * dt)
            for _ in range(n_move):
                r = r @ step
                f_list.append((r.T @ [0, 0, 1.0])[None])
                w_list.append(w[None])
    f, w = np.concatenate(f_list), np.concatenate(w_list)
    rng = np.random.default_rng(0)
    acc = f @ np.linalg.inv(A_ACC).T + B_ACC
    gyr = w @ np.linalg.inv(A_GYR).T + B_GYR
    if noise:
        acc = acc + rng.normal(0, 4.0, acc.shape)
        gyr = gyr + rng.normal(0, 2.0, gyr.shape)
    t = np.arange(len(f)) * dt
    return t, np.round(acc), np.round(gyr)


@pytest.fixture(scope="module")
def sim():
    return simulate(jax.random.PRNGKey(3))


def test_moving_variance_matches_numpy():
    x = np.random.default_rng(1).normal(size=(50, 3)) * [1, 2, 3]
    with jax.enable_x64(True):
        v = np.asarray(moving_variance(jnp.asarray(x), 4))
    np.testing.assert_allclose(v[10], np.var(x[6:15], axis=0), rtol=1e-9)
    np.testing.assert_allclose(v[0], np.var(x[0:5], axis=0), rtol=1e-9)


def test_intervals_from_mask():
    m = np.array([1, 1, 0, 1, 1, 1, 0, 0, 1], bool)
    np.testing.assert_array_equal(intervals_from_mask(m, 2), [[0, 2], [3, 6]])


def test_static_detection_finds_simulated_poses(sim):
    t, acc, _ = sim
    det = detect_static(t, acc, k=3, init_duration=8.0, window=0.5, min_duration=1.0)
    assert len(det.intervals) == 24
    # every interval lies inside a hold (holds: [0, 1000), then 150 moving + 200 static samples)
    starts = det.intervals[1:, 0]
    assert np.all(((starts - 1000 - 150) % 350) < 60)


def test_multipos_recovers_simulated_calibration(sim):
    t, acc, gyr = sim
    det = detect_static(t, acc, k=3, init_duration=8.0, window=0.5, min_duration=1.0)
    fit = mp.fit_multipos(t, acc, gyr, det.intervals)
    np.testing.assert_allclose(fit.acc.A, A_ACC, atol=2e-3 * A_ACC[0, 0])
    np.testing.assert_allclose(fit.acc.b, B_ACC, atol=2.0)
    np.testing.assert_allclose(fit.gyr.A, A_GYR, atol=3e-3 * A_GYR[0, 0])
    np.testing.assert_allclose(fit.gyr.b, B_GYR, atol=0.5)
    # no datasheet value was given: the gyro scale was found by the grid from the data alone


def test_multipos_12_param_same_metric_symmetric_frame(sim):
    t, acc, gyr = sim
    det = detect_static(t, acc, k=3, init_duration=8.0, window=0.5, min_duration=1.0)
    fit = mp.fit_multipos(t, acc, gyr, det.intervals, mp.MultiposConfig(acc_model="12"))
    a = fit.acc.A
    np.testing.assert_allclose(a, a.T, atol=1e-6 * a[0, 0])  # gauge pinned
    # |A x| is what the poses determine: A^T A equals the truth's (closed form)
    np.testing.assert_allclose(a.T @ a, A_ACC.T @ A_ACC, rtol=5e-3, atol=1e-3 * (A_ACC.T @ A_ACC)[0, 0])
    np.testing.assert_allclose(fit.acc.b, B_ACC, atol=2.0)


def test_gyro_residual_uses_physical_convention():
    # one transition: 90 deg about x. Physical: f_next = Exp(w T)^T f_prev.
    u = jnp.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    w = jnp.zeros((1, 100, 3)).at[:, :, 0].set(jnp.pi / 2)
    dt = jnp.full((1, 100), 0.01)
    r = mp.carry_rotation(w, dt)
    pred = jnp.einsum("jba,jb->ja", r, u[:-1])
    np.testing.assert_allclose(pred[0], [0.0, 1.0, 0.0], atol=1e-5)


@pytest.fixture(scope="module")
def xsens():
    rec = load_npz(DATA / "imu_tk_xsens_multipos" / "xsens.npz")
    det = detect_static(rec["t"], rec["acc"], k=5, init_duration=45.0, window=1.0, min_duration=1.0)
    return rec, det


def test_xsens_static_intervals_match_readme(xsens):
    _, det = xsens
    assert len(det.intervals) == 38  # README: the initial rest plus 37 poses


def _factory_acc_rms_mg(pose_acc):
    # factory: f = M^-1 K^-1 (raw - offset) / g_local (README), scored on the same poses
    k = np.diag([415.0, 413.0, 415.0])
    m = np.array([[1.0, 0.0, -0.01], [0.01, 1.0, 0.01], [0.02, 0.01, 1.0]])
    f = (pose_acc - [33123.0, 33276.0, 32360.0]) @ np.linalg.inv(k @ m).T / 9.81744
    return 1e3 * np.sqrt(np.mean((np.linalg.norm(f, axis=1) - 1.0) ** 2))


def test_xsens_heldout_acc_beats_factory(xsens):
    rec, det = xsens
    data = mp.prepare(rec["t"], rec["acc"], rec["gyr"], det.intervals)
    P = len(det.intervals)
    folds = mp.fold_ids(P, 5)
    with jax.enable_x64(True):
        w = jnp.asarray((folds[None, :] != np.arange(5)[:, None]).astype(float))
        pa = jnp.asarray(data.pose_acc)
        cals, _ = jax.jit(jax.vmap(lambda wk: mp.fit_acc(pa, wk)))(w)
        err = np.asarray(jax.vmap(lambda c: mp.acc_norm_errors(c, pa))(cals))[folds, np.arange(P)]
    rms_mg = 1e3 * np.sqrt(np.mean(err**2))
    factory = _factory_acc_rms_mg(data.pose_acc)
    assert factory == pytest.approx(2.0, abs=0.3)  # the 2.0 mg
    assert rms_mg < 0.5 * factory


@pytest.mark.slow
def test_xsens_heldout_gyro_and_acc(xsens):
    rec, det = xsens
    data = mp.prepare(rec["t"], rec["acc"], rec["gyr"], det.intervals)
    held = mp.leave_poses_out(data, mp.MultiposConfig(), n_folds=5)
    assert 1e3 * np.sqrt(np.mean(held.acc_err**2)) < 0.5 * _factory_acc_rms_mg(data.pose_acc)
    assert np.degrees(np.nanmedian(held.gyr_err)) < 1.5  # README: factory gyro median 2.3 deg


def test_fit_multipos_recording_contract(sim):
    """The CLI entry point: a recording in, forward models y = S x + b out (imu_tk threshold scan)."""
    t, acc, gyr = sim
    rec = {"t": t, "acc": acc, "gyr": gyr, "acc_unit": "LSB", "gyr_unit": "LSB"}
    acc_model, gyr_model = mp.fit_multipos_recording(rec, init_duration=8.0, window=0.5)
    np.testing.assert_allclose(acc_model.S, np.linalg.inv(A_ACC), rtol=3e-3, atol=30.0)
    np.testing.assert_allclose(acc_model.b, B_ACC, atol=2.0)
    np.testing.assert_allclose(gyr_model.S, np.linalg.inv(A_GYR), rtol=5e-3, atol=40.0)
    np.testing.assert_allclose(gyr_model.b, B_GYR, atol=0.5)
    with pytest.raises(ValueError, match="gyr"):
        mp.fit_multipos_recording({"t": t, "acc": acc})
