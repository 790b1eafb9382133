"""Method ``diagnosed`` (:mod:`jaxcal.methods.diagnosed`): ``apply`` inverts the forward model of
:mod:`jaxcal.diagnose.effects` for each effect it carries (closed-form synthetic signals, float64),
refuses a recording without a channel the model needs, and ``jaxcal diagnose --model-out`` writes a
model that ``jaxcal apply`` uses (the held-out proof is experiments/apply_effects.py)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcal import methods
from jaxcal.cli import main
from jaxcal.diagnose import effects as E
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.methods.diagnosed import apply, check, invert_nonlinearity
from jaxcal.model_file import load_model
from jaxcal.recording import load_recording, recording_from_dict, save_recording

N, DT, T0 = 1000, 0.01, 30.0
S_TRUE = {"acc": np.array([[16300.0, 40.0, -25.0], [10.0, 16500.0, 30.0], [-20.0, 15.0, 16200.0]]),
          "gyr": np.array([[7400.0, 12.0, -8.0], [5.0, 7600.0, 9.0], [-6.0, 4.0, 7550.0]])}
B_TRUE = {"acc": np.array([120.0, -80.0, 45.0]), "gyr": np.array([-60.0, 35.0, 20.0])}


def _motion(tt):
    """Smooth closed-form motion at times ``tt``: specific force (g), body rate (rad/s) and its exact derivative."""
    fr, ph, amp = np.array([0.3, 0.5, 0.7]), np.array([0.2, 1.1, 2.0]), np.array([1.5, 1.0, 2.0])
    w = amp * np.sin(2 * np.pi * fr * tt[:, None] + ph)
    wdot = amp * 2 * np.pi * fr * np.cos(2 * np.pi * fr * tt[:, None] + ph)
    f = 0.6 * np.sin(2 * np.pi * np.array([0.2, 0.35, 0.15]) * tt[:, None] + ph[::-1]) + np.array([0.0, 0.0, 0.8])
    return f, w, wdot


def _signals():
    """The closed-form motion and a temperature (degC) on a 100 Hz grid of 10 s."""
    t = np.arange(N) * DT
    f, w, wdot = _motion(t)
    temp = T0 + 10.0 * np.sin(2 * np.pi * t / 10.0)
    return t, f, w, wdot, temp


def _simulate(effects: dict):
    """Raw outputs of both sensors through the forward model (``effects_forward`` and an affine
    baseline) with ``effects = {(sensor, name): params}``, no noise; the recording, the truth and
    the state that ``apply`` should invert them with."""
    t, f, w, wdot, temp = _signals()
    inp = E.as_jax(E.Inputs(f, w, wdot, t - t.mean(), temp - T0, np.asarray(DT)))
    rec = {"t": t, "fs": 1.0 / DT, "temp": temp}
    state = {}
    for s in ("acc", "gyr"):
        mine = {n: p for (ss, n), p in effects.items() if ss == s}
        th = E.theta_from_params(s, mine)
        u = np.asarray(E.effects_forward(s, jnp.asarray(th), inp))
        rec[s] = u @ S_TRUE[s].T + B_TRUE[s]
        state[s] = {"S": S_TRUE[s], "b": B_TRUE[s]}
        for n in mine:
            v = E.params_from_theta(s, n, th)[E.slot(s, n).param]
            state[s][n] = np.asarray(v, np.float64).reshape(() if n == "time_offset" else np.shape(v))
            if n.startswith("temperature"):
                state[s]["T0"] = np.asarray(T0)
    return recording_from_dict(rec, "synthetic"), f, w, state


EFFECTS = [
    ("acc", "lever_arm", {"r": np.array([0.05, -0.03, 0.04])}),
    ("gyr", "g_sensitivity", {"G": np.array([[3e-3, 1e-3, -2e-3], [5e-4, -2e-3, 1e-3], [2e-3, 0.0, 4e-3]])}),
    ("acc", "misalignment", {"m": np.array([0.01, -0.02, 0.015, 0.005, -0.01, 0.02])}),
    ("gyr", "misalignment", {"m": np.array([0.01, -0.02, 0.015, 0.005, -0.01, 0.02])}),
    ("acc", "scale_nonlinearity", {"k2": np.array([0.04, -0.05, 0.03])}),
    ("gyr", "scale_nonlinearity", {"k2": np.array([0.04, -0.05, 0.03])}),
    ("acc", "temperature_bias", {"k": np.array([1e-3, -2e-3, 5e-4])}),
    ("gyr", "temperature_bias", {"k": np.array([1e-3, -2e-3, 5e-4])}),
    ("acc", "temperature_scale", {"k": np.array([5e-3, -8e-3, 3e-3])}),
    ("gyr", "temperature_scale", {"k": np.array([5e-3, -8e-3, 3e-3])}),
]


@pytest.mark.parametrize("sensor,name,params", EFFECTS, ids=[f"{s}-{n}" for s, n, _ in EFFECTS])
def test_apply_inverts_each_effect_exactly(x64, sensor, name, params):
    rec, f, w, state = _simulate({(sensor, name): params})
    out = apply(state, {}, rec)
    truth = {"acc_cal": f, "gyr_cal": w}
    for k in ("acc_cal", "gyr_cal"):
        # measured max error 2.4e-15 (closed-form inverses, float64); the lever arm's five-point
        # derivative of the calibrated rate adds 5.6e-9 g inside (O(dt^4) at these 0.3-0.7 Hz
        # rates) and 1.4e-5 g at the two end samples (second-order one-sided differences)
        inside = 5e-8 if name == "lever_arm" else 1e-12
        np.testing.assert_allclose(out[k][2:-2], truth[k][2:-2], rtol=0, atol=inside, err_msg=k)
        np.testing.assert_allclose(out[k], truth[k], rtol=0, atol=1e-4, err_msg=k)
    # and the effect was there to remove (the test can fail)
    lin = methods.apply(CalibrationModel("linear", ("acc", "gyr"), {s: {"S": S_TRUE[s], "b": B_TRUE[s]} for s in state},
                                         {}), rec)
    assert np.max(np.abs(lin[f"{sensor}_cal"] - truth[f"{sensor}_cal"])) > 1e-4


def test_apply_inverts_coupled_g_sensitivity_and_lever_arm(x64):
    eff = {("acc", "lever_arm"): {"r": np.array([0.05, -0.03, 0.04])},
           ("gyr", "g_sensitivity"): {"G": np.array([[3e-3, 1e-3, -2e-3], [5e-4, -2e-3, 1e-3], [2e-3, 0.0, 4e-3]])},
           ("acc", "temperature_bias"): {"k": np.array([1e-3, -2e-3, 5e-4])},
           ("gyr", "scale_nonlinearity"): {"k2": np.array([0.04, -0.05, 0.03])}}
    rec, f, w, state = _simulate(eff)
    out = apply(state, {}, rec)
    # inside, measured max error 5.6e-9 g and 1.8e-11 rad/s (the five-point derivative; the fixed
    # point converges to round-off); the two end samples 1.4e-5 g, 2.5e-8 rad/s (one-sided differences)
    np.testing.assert_allclose(out["acc_cal"][2:-2], f[2:-2], rtol=0, atol=5e-8)
    np.testing.assert_allclose(out["gyr_cal"][2:-2], w[2:-2], rtol=0, atol=5e-8)
    np.testing.assert_allclose(out["acc_cal"], f, rtol=0, atol=1e-4)


@pytest.mark.parametrize("sensor,tau", [("acc", 0.0123), ("gyr", -0.0371)])
def test_apply_undoes_a_time_offset_by_cubic_resampling(x64, sensor, tau):
    # a sensor that reads the closed-form motion late by tau: raw(t) = S x(t - tau) + b
    t = np.arange(N) * DT
    late = _motion(t - tau)[0 if sensor == "acc" else 1]
    truth = _motion(t)[0 if sensor == "acc" else 1]
    rec = recording_from_dict({"t": t, "fs": 1.0 / DT, sensor: late @ S_TRUE[sensor].T + B_TRUE[sensor]}, "synthetic")
    state = {sensor: {"S": S_TRUE[sensor], "b": B_TRUE[sensor], "time_offset": np.asarray(tau)}}
    out = apply(state, {}, rec)[f"{sensor}_cal"]
    edge = int(np.ceil(abs(tau) / DT))
    err = np.abs(out - truth)
    # inside: not-a-knot cubic spline error, O((2 pi f dt)^4); measured max 1.5e-9 g (acc, <= 0.35 Hz)
    # and 1.6e-7 rad/s (gyr, 0.7 Hz at 2 rad/s, larger near the ends)
    assert err[edge:N - edge].max() < 1e-6, err[edge:N - edge].max()
    # the ends hold the edge sample (no extrapolation): the first/last ceil(|tau|/dt) samples
    x1 = np.linalg.solve(S_TRUE[sensor], (getattr(rec, sensor) - B_TRUE[sensor]).T).T
    held, value = (slice(N - edge, N), x1[-1]) if tau > 0 else (slice(0, edge), x1[0])
    np.testing.assert_allclose(out[held], np.broadcast_to(value, out[held].shape), rtol=0, atol=1e-12)
    # without resampling the error is the delay times the rate of change: far larger
    assert np.abs(x1 - truth).max() > 1e-2


@pytest.mark.parametrize("sensor,tau", [("acc", 0.0123), ("gyr", -0.0371)])
def test_apply_inverts_the_forward_models_band_limited_shift(x64, sensor, tau):
    rec, f, w, state = _simulate({(sensor, "time_offset"): {"tau": np.array([tau])}})
    err = np.abs(apply(state, {}, rec)[f"{sensor}_cal"] - (f if sensor == "acc" else w))
    # the forward model's Fourier shift of the even extension rings near the ends (its own error
    # against the exact delay is 1.2e-5 at 0.2 s from an end, 1.5e-8 in the middle); in the middle
    # half the inverse matches the truth: measured max 4.7e-9 g (acc), 2.8e-8 rad/s (gyr)
    assert err[N // 4 : 3 * N // 4].max() < 2e-7, err[N // 4 : 3 * N // 4].max()


def test_nonlinearity_inverse_is_the_root_through_the_origin(x64):
    rng = np.random.default_rng(0)
    k2 = np.array([0.05, -0.05, 0.0])
    x1 = rng.uniform(-4, 4, (200, 3))  # inside the fold |x1| < 1/(2|k2|) = 10
    x2 = x1 + k2 * x1**2
    # measured max error 8.9e-16 (closed form, float64)
    np.testing.assert_allclose(invert_nonlinearity(x2, k2), x1, rtol=0, atol=1e-13)
    # beyond the fold: the fold value -1/(2 k2)
    assert invert_nonlinearity(np.array([[-6.0, 0.0, 0.0]]), k2)[0, 0] == pytest.approx(-10.0)


def _model(state, units=("LSB", "LSB")):
    return CalibrationModel("diagnosed", tuple(state), state, {"units": dict(zip(state, units))})


def test_recording_without_temp_is_refused_in_one_line(x64):
    rec, _, _, state = _simulate({("acc", "temperature_bias"): {"k": np.array([1e-3, 0.0, 0.0])}})
    with pytest.raises(ModelError, match="'temp'") as err:
        methods.apply(_model(state), rec.replace(temp=None))
    msg = str(err.value)
    assert "\n" not in msg and "temperature_bias" in msg and "malformed" not in msg, msg


def test_g_sensitivity_without_acc_is_refused(x64):
    rec, _, _, state = _simulate({("gyr", "g_sensitivity"): {"G": np.eye(3) * 1e-3}})
    with pytest.raises(ModelError, match="'acc'"):
        methods.apply(_model(state), rec.replace(acc=None))


def test_check_refuses_a_malformed_state():
    good = {"acc": {"S": np.eye(3), "b": np.zeros(3), "time_offset": np.asarray(0.01)}}
    check(good, {}, ("acc",))
    with pytest.raises(ModelError, match="expected \\(3,\\)"):
        check({"acc": {"S": np.eye(3), "b": np.zeros(3), "lever_arm": np.zeros(2)}}, {}, ("acc",))
    with pytest.raises(ModelError, match="g_sensitivity"):  # a gyro effect on the accelerometer
        check({"acc": {"S": np.eye(3), "b": np.zeros(3), "g_sensitivity": np.zeros((3, 3))}}, {}, ("acc",))
    with pytest.raises(ModelError, match="T0"):
        check({"gyr": {"S": np.eye(3), "b": np.zeros(3), "temperature_bias": np.zeros(3)}}, {}, ("gyr",))


def test_diagnose_model_out_then_apply(tmp_path, capsys):
    """``jaxcal diagnose --model-out`` on the smallest simulated recording the tests use (1500
    samples, a concealed gyro g-sensitivity); ``jaxcal apply`` of that model on the same recording
    gives what the library's apply gives and lowers the gyro error against truth (a smoke test of
    the command line; the held-out proof is experiments/apply_effects.py)."""
    from jaxcal.diagnose.simulate import RichConfig, simulate_recording

    G = np.array([[4e-3, 0, 1e-3], [0, -3e-3, 0], [2e-3, 0, 3e-3]])
    rec, _ = simulate_recording(jax.random.PRNGKey(5), RichConfig(n=1500), {("gyr", "g_sensitivity"): {"G": G}})
    rp, mp, op = tmp_path / "rec.npz", tmp_path / "m.npz", tmp_path / "cal.npz"
    save_recording(rec, rp)
    assert main(["diagnose", str(rp), "--out", str(tmp_path / "diag"), "--model-out", str(mp)]) == 0
    assert "wrote" in capsys.readouterr().err and (tmp_path / "diag" / "report.json").exists()
    model = load_model(mp)
    assert model.method == "diagnosed" and "g_sensitivity" in model.state["gyr"]
    # the estimate is close to the truth (1500 samples: measured max deviation 2e-4 (rad/s)/g)
    np.testing.assert_allclose(model.state["gyr"]["g_sensitivity"], G, atol=1e-3)
    assert main(["apply", str(mp), str(rp), "--out", str(op), "-q"]) == 0
    with np.load(op) as d:
        got = {k: d[k] for k in ("acc_cal", "gyr_cal")}
    want = model.apply(load_recording(rp))
    for k in got:
        np.testing.assert_array_equal(got[k], want[k])
    base = methods.fit("linear", rec).apply(rec)
    err_after = np.sqrt(np.mean((got["gyr_cal"] - rec.gyr_ref) ** 2))
    err_before = np.sqrt(np.mean((base["gyr_cal"] - rec.gyr_ref) ** 2))
    assert err_after < 0.8 * err_before, (err_after, err_before)


def test_model_out_must_be_npz(tmp_path, capsys):
    assert main(["diagnose", "nothing.npz", "--out", str(tmp_path / "d"), "--model-out", str(tmp_path / "m.txt")]) == 2
    assert "--model-out" in capsys.readouterr().err
