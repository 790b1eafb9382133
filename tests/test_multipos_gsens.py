"""Gyro g-sensitivity end to end: ``jaxcal calibrate --method multipos --g-sensitivity`` fits ``G``
((rad/s)/g), stores it as ``state/gyr/G``, prints it, scores the held-out figure with ``G`` fitted in
every fold, and ``jaxcal apply`` inverts ``y_g = S_g (w + G f) + b_g`` exactly (``f`` the calibrated
accelerometer); a recording without ``acc`` is refused for such a model."""

from __future__ import annotations

import functools
import re

import jax
import numpy as np
import pytest
import yaml

from jaxcal import methods
from jaxcal.cli import main
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.methods.base import check_linear_state
from jaxcal.methods.multipos import MultiposOptions
from jaxcal.model_file import load_model, save_model
from jaxcal.multipos.detect import traceless
from jaxcal.multipos.heldout import jackknife_sd
from jaxcal.recording import Recording, save_recording
from jaxcal.simulate.recordings import multipos_recording

# simulated g-sensitivity, (rad/s)/g: entries up to 0.1 (deg/s)/g (MEMS datasheets: about 0.1 (deg/s)/g); larger
# values shift the rests' gyro output by more than the rest detector's gyro gate allows (10 x the gyro noise)
G_TRUE = 0.4 * np.radians(np.array([[0.20, -0.10, 0.05], [0.08, -0.15, 0.12], [-0.06, 0.10, 0.25]]))


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@functools.cache
def _session() -> Recording:
    """24 random static poses joined by rotations, gyro with ``G_TRUE`` (raw counts, white noise 4 / 2 LSB)."""
    return multipos_recording(jax.random.PRNGKey(1), n_poses=24, gsens=G_TRUE)


@functools.cache
def _cli_session() -> Recording:
    """As :func:`_session` with 12 poses: the CLI test's leave-one-pose-out folds run one after another
    on a CPU, three sets of them (issue 30's test budget)."""
    return multipos_recording(jax.random.PRNGKey(1), n_poses=12, gsens=G_TRUE)


def test_cli_g_sensitivity_recovers_G_and_improves_the_held_out_figure(tmp_path, capsys):
    """Both fits on one simulated session of 12 poses through the CLI (two fits, each with its 12
    leave-one-pose-out folds; the G fit also scores the folds without G)."""
    save_recording(_cli_session(), tmp_path / "mp.npz")
    code, _, err = _run(capsys, "calibrate", "--method", "multipos", tmp_path / "mp.npz", "--out", tmp_path / "plain.npz")
    assert code == 0, err
    code, out, err = _run(capsys, "calibrate", "--method", "multipos", tmp_path / "mp.npz", "--g-sensitivity",
                          "--out", tmp_path / "g.npz")
    assert code == 0, err
    plain, g = load_model(tmp_path / "plain.npz"), load_model(tmp_path / "g.npz")
    assert set(plain.state["gyr"]) == {"S", "b"} and set(g.state["gyr"]) == {"S", "b", "G"}
    G = np.asarray(g.state["gyr"]["G"])
    # bias and G come jointly from the rests (each pose's mean output is b + S G f), trace included.
    # Measured on this session: max error 0.0015 (deg/s)/g against entries up to 0.10, Frobenius error 0.013
    # of the truth's (24 poses: 0.00079 and 0.011; before the joint rest fit, with the bias fixed at the rests'
    # mean: 0.050 and 0.41)
    err_G = np.degrees(np.abs(G - G_TRUE))
    assert err_G.max() < 0.003, err_G
    assert np.linalg.norm(G - G_TRUE) < 0.05 * np.linalg.norm(G_TRUE)
    # held out (leave-one-pose-out, G fitted in every fold): measured carried-gravity median 0.245 deg without,
    # 0.0091 deg with G; the accelerometer is fitted alike (0.094 mg both: equal to 5.7e-14 relative at 12 poses,
    # bit-equal at 24, so compared to 1e-9)
    ho_plain, ho_g = plain.meta["held_out"], g.meta["held_out"]
    assert ho_g["gyr_median_deg"] < 0.2 * ho_plain["gyr_median_deg"], (ho_plain, ho_g)
    np.testing.assert_allclose(ho_g["acc_rms_mg"], ho_plain["acc_rms_mg"], rtol=1e-9)
    # the G fit also reports the plain figure, computed again: the same as the plain fit's
    ho_cmp = ho_g["without_g_sensitivity"]
    np.testing.assert_allclose([ho_cmp["gyr_median_deg"], ho_cmp["acc_rms_mg"]],
                               [ho_plain["gyr_median_deg"], ho_plain["acc_rms_mg"]], rtol=1e-6)
    assert "held out without --g-sensitivity: " in out and "note: G left" not in out  # G helped here
    assert "without_g_sensitivity" not in ho_plain
    # the folds' calibrations are stored for the exports' standard errors: their biases' jackknife is the
    # stored bias_sd (the same kept folds), and the OpenVINS file carries its own numbers' jackknife
    for s in ("acc", "gyr"):
        folds = ho_plain["fold_cals"][s]
        assert np.asarray(folds["A"]).shape == (len(folds["b"]), 3, 3)
        np.testing.assert_allclose(jackknife_sd(np.asarray(folds["b"])), ho_plain["bias_sd"][s], rtol=1e-12)
    code, _, err = _run(capsys, "export", tmp_path / "plain.npz", "--format", "openvins", "--out", tmp_path / "ov.yaml")
    assert code == 0 and "jaxcal_intrinsics_sd" in err, err
    imu = yaml.safe_load((tmp_path / "ov.yaml").read_text().split("\n", 1)[1])["imu0"]  # after %YAML:1.0
    for key in ("Ta", "Tw"):  # measured relative sd of the diagonal: Ta 5.1e-5 to 8.8e-5, Tw 8.2e-4 to 4.2e-3
        rel = np.diag(imu["jaxcal_intrinsics_sd"][key]) / np.abs(np.diag(imu[key]))
        assert np.all((rel > 0) & (rel < 2e-2)), (key, rel)
    # printed and stored in (deg/s)/g
    assert "gyr: g-sensitivity G rows" in out and "(deg/s)/g" in out
    np.testing.assert_allclose(g.meta["parameters"]["gyr"]["g_sensitivity_degs_per_g"], np.degrees(G), rtol=1e-12)
    assert "g_sensitivity_degs_per_g" not in plain.meta["parameters"]["gyr"]
    # apply of the G model on the session: the rests read 0 up to the white noise (measured median |w| at the
    # rests 0.024 deg/s with G, 0.098 deg/s without: the plain model leaves G f in; white noise alone ~0.02)
    rec = _cli_session()
    rests = np.flatnonzero(np.linalg.norm(rec.gyr - np.median(rec.gyr, axis=0), axis=1) < 100)  # moves: ~7000 LSB
    assert len(rests) > 1000
    wg = np.degrees(methods.apply(g, rec)["gyr_cal"][rests])
    wp = np.degrees(methods.apply(plain, rec)["gyr_cal"][rests])
    assert np.median(np.linalg.norm(wg, axis=1)) < 0.04 < np.median(np.linalg.norm(wp, axis=1))


def test_rest_gsens_recovers_bias_and_G_in_closed_form(x64):
    """``pose_gyr_k = b + H f_k`` exactly: the weighted regression returns ``b`` and ``H`` to rounding,
    and a zero weight is the same as dropping that pose. Pose counts from three sizes (the fewest
    the fit takes, 4, up to 29): each new shape recompiles every eager op (20 draws from 4..29: 12.1 s
    CPU, from three sizes: 3.4 s)."""
    import jax.numpy as jnp

    from jaxcal.multipos.gyro import rest_gsens

    rng = np.random.default_rng(3)
    for _ in range(20):
        P = int(rng.choice([4, 9, 29]))
        f = rng.normal(size=(P, 3))
        f /= np.linalg.norm(f, axis=1, keepdims=True)
        b, H = rng.normal(0, 100, 3), rng.normal(0, 5, (3, 3))
        y = b + f @ H.T
        w = rng.uniform(50, 500, P)
        bb, hh = (np.asarray(x) for x in rest_gsens(jnp.asarray(y), jnp.asarray(f), jnp.asarray(w)))
        # measured max |error| 3.1e-13 LSB (bias ~100) and 3.3e-13 (H ~5); a zero weight against the pose
        # dropped: 1.1e-13
        np.testing.assert_allclose(bb, b, atol=1e-9)
        np.testing.assert_allclose(hh, H, atol=1e-9)
        if P > 4:  # a zero weight leaves the pose out (noisy data, so the fit depends on which poses are in)
            yn = y + rng.normal(0, 1, y.shape)
            w0 = w.copy()
            w0[0] = 0.0
            got = rest_gsens(jnp.asarray(yn), jnp.asarray(f), jnp.asarray(w0))
            want = rest_gsens(jnp.asarray(yn[1:]), jnp.asarray(f[1:]), jnp.asarray(w[1:]))
            for a_, b_ in zip(got, want):
                np.testing.assert_allclose(np.asarray(a_), np.asarray(b_), atol=1e-9)


def test_rests_and_transitions_estimate_the_same_G():
    """Two independent estimates of ``G`` on one session: from the rests' outputs (the default) and
    from the carried gravity of the transitions (``gsens_from="transitions"``, traceless). Their
    traceless parts agree (measured max difference 0.0016 (deg/s)/g; each within 0.0019 of the truth)."""
    from jaxcal.multipos import MultiposConfig
    from jaxcal.multipos.detect import fit_multipos_recording_gsens

    _, _, g_rest, q = fit_multipos_recording_gsens(_session(), MultiposConfig(g_sensitivity=True))
    _, _, g_tran, _ = fit_multipos_recording_gsens(_session(), MultiposConfig(g_sensitivity=True, gsens_from="transitions"))
    assert abs(np.trace(g_tran)) < 1e-15 and abs(np.degrees(np.trace(g_rest)) / 3 - 0.04) < 0.003  # true tr/3 0.040
    assert np.degrees(np.abs(traceless(g_rest) - g_tran)).max() < 0.005
    assert q["gsens_rest_sv_min"] > 0.3  # 24 random poses (measured 0.78)


def test_rests_that_do_not_span_3d_are_refused():
    """Coplanar gravity directions leave bias and G undetermined: the design's least relative singular
    value is 0 to rounding, against 0.5 or more for the six faces of a cube."""
    from jaxcal.multipos.data import MultiposData
    from jaxcal.multipos.detect import rest_design_sv
    from jaxcal.sensor import LinearCal

    ident = LinearCal(np.eye(3), np.zeros(3))

    def data(f):
        z = np.zeros((len(f), 3))
        return MultiposData(f, z, np.ones(len(f)), *([None] * 7))

    a = np.linspace(0, 2 * np.pi, 7)[:-1]
    coplanar = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
    assert rest_design_sv(data(coplanar), ident).min() < 1e-12
    cube = np.concatenate([np.eye(3), -np.eye(3)])
    assert rest_design_sv(data(cube), ident).min() > 0.5


def test_g_sensitivity_with_the_initial_rest_bias_is_refused(tmp_path, capsys):
    save_recording(_session(), tmp_path / "mp.npz")
    code, out, err = _run(capsys, "calibrate", "--method", "multipos", tmp_path / "mp.npz", "--g-sensitivity",
                          "--gyro-bias", "init", "--out", tmp_path / "g.npz")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--gyro-bias init" in err, err
    assert not (tmp_path / "g.npz").exists()


def test_without_the_flag_the_model_is_the_affine_one():
    """The option's default is off, and a fit without it stores exactly ``S``, ``b`` per sensor."""
    assert MultiposOptions().g_sensitivity is False
    from jaxcal.multipos import MultiposConfig

    with pytest.raises(ValueError, match="fit_multipos_recording_gsens"):
        from jaxcal.multipos import fit_multipos_recording

        fit_multipos_recording(_session(), MultiposConfig(g_sensitivity=True))


def _random_model(rng: np.random.Generator) -> CalibrationModel:
    S_a = np.diag([16000.0, 16700.0, 16200.0]) + rng.normal(0, 200, (3, 3))
    S_g = np.diag([7500.0, 7300.0, 7700.0]) + rng.normal(0, 100, (3, 3))
    state = {"acc": {"S": S_a, "b": rng.normal(0, 300, 3)},
             "gyr": {"S": S_g, "b": rng.normal(0, 100, 3), "G": np.radians(rng.normal(0, 0.2, (3, 3)))}}
    return CalibrationModel("multipos", ("acc", "gyr"), state, {"units": {"acc": "LSB", "gyr": "LSB"}})


def test_apply_inverts_the_forward_model_exactly(x64, tmp_path):
    """Closed form: ``y_a = S_a f + b_a``, ``y_g = S_g (w + G f) + b_g`` from known ``f``, ``w``;
    ``jaxcal apply`` (after a save/load round trip) gives them back."""
    rng = np.random.default_rng(0)
    model = _random_model(rng)
    save_model(model, tmp_path / "m.npz")
    model = load_model(tmp_path / "m.npz")
    n = 400
    f, w = rng.normal(0, 1.0, (n, 3)), rng.normal(0, 2.0, (n, 3))
    a, g = model.state["acc"], model.state["gyr"]
    y_a = f @ a["S"].T + a["b"]
    y_g = (w + f @ g["G"].T) @ g["S"].T + g["b"]
    out = methods.apply(model, Recording(t=np.arange(n) / 100.0, acc=y_a, gyr=y_g))
    # measured max |error| 4.4e-16 g and 1.3e-15 rad/s (float64 rounding of S^{-1})
    np.testing.assert_allclose(out["acc_cal"], f, atol=1e-12)
    np.testing.assert_allclose(out["gyr_cal"], w, atol=1e-12)
    # without G the same state applies as today's affine model: A (y - b)
    plain = CalibrationModel("multipos", model.sensors, {"acc": a, "gyr": {"S": g["S"], "b": g["b"]}}, model.meta)
    got = methods.apply(plain, Recording(t=np.arange(n) / 100.0, acc=y_a, gyr=y_g))["gyr_cal"]
    np.testing.assert_allclose(got, w + f @ g["G"].T, atol=1e-12)


def test_a_recording_without_acc_is_refused_for_a_G_model(tmp_path, capsys):
    model = _random_model(np.random.default_rng(1))
    rec = Recording(t=np.arange(50) / 100.0, gyr=np.zeros((50, 3)))
    with pytest.raises(ModelError, match="g-sensitivity .*needs the recording's 'acc' channel"):
        methods.apply(model, rec)
    save_model(model, tmp_path / "m.npz")
    save_recording(rec, tmp_path / "gyr_only.npz")
    code, out, err = _run(capsys, "apply", tmp_path / "m.npz", tmp_path / "gyr_only.npz", "--out", tmp_path / "o.npz")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1 and "'acc' channel" in err, err
    assert not (tmp_path / "o.npz").exists()


def test_check_accepts_an_optional_finite_3x3_G_only():
    model = _random_model(np.random.default_rng(2))
    check_linear_state(model.state, model.meta, model.sensors)
    g = model.state["gyr"]
    bad = [({**g, "G": np.zeros((2, 3))}, ("acc", "gyr"), "expected (3, 3)"),
           ({**g, "G": np.full((3, 3), np.nan)}, ("acc", "gyr"), "non-finite"),
           (g, ("gyr",), "has no 'acc' calibration")]
    for gyr, sensors, needle in bad:
        state = {**model.state, "gyr": gyr}
        with pytest.raises(ModelError, match=re.escape(needle)):
            check_linear_state(state, model.meta, sensors)
    with pytest.raises(ModelError, match="only the gyroscope"):
        check_linear_state({**model.state, "acc": {**model.state["acc"], "G": np.zeros((3, 3))}}, model.meta, model.sensors)


def test_rest_gyr_baseline_follows_the_pose_and_ignores_turns():
    """Closed form: still samples read ``b + H u`` plus white noise, and a turn about the vertical
    (accelerometer still, gyro at 1000x the noise) is mixed in: the trimmed fit returns ``b + H u``
    to the noise's precision and is not pulled by the turn."""
    from jaxcal.static import rest_gyr_baseline

    rng = np.random.default_rng(4)
    n_pose, per = 12, 200
    u = rng.normal(size=(n_pose, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    b, H = np.array([30.0, -20.0, 5.0]), rng.normal(0, 40, (3, 3))
    acc = np.repeat(u * 16384.0, per, axis=0)
    gyr = np.repeat(b + u @ H.T, per, axis=0) + rng.normal(0, 2.0, (n_pose * per, 3))
    gyr[per:2 * per] += np.array([0.0, 0.0, 3000.0])  # a turn: still to the accelerometer
    still = np.ones(len(gyr), bool)
    base = rest_gyr_baseline(gyr, acc, still, gate=10 * 2.0 * np.sqrt(3))
    want = np.repeat(b + u @ H.T, per, axis=0)
    # measured max |error| 0.14 LSB (noise 2 LSB per sample, 2200 samples in the fit)
    assert np.abs(base - want).max() < 0.5


def test_large_g_sensitivity_keeps_every_rest():
    """With ``--g-sensitivity`` the rest detector's gyro gate lets the rest output follow the pose
    (:func:`~jaxcal.static.rest_gyr_baseline`). At 8x this file's ``G_TRUE`` (entries up to 0.8
    (deg/s)/g) the plain gate found fewer than 9 poses and refused; now all 24 are found and ``G`` is
    recovered (measured max error 0.0009 (deg/s)/g; 0.0010 at 16x)."""
    from jaxcal.multipos import MultiposConfig
    from jaxcal.multipos.detect import fit_multipos_recording_gsens

    rec = multipos_recording(jax.random.PRNGKey(1), n_poses=24, gsens=8 * G_TRUE)
    _, _, G, q = fit_multipos_recording_gsens(rec, MultiposConfig(g_sensitivity=True))
    assert q["n_poses"] == 24
    assert np.degrees(np.abs(G - 8 * G_TRUE)).max() < 0.003


def test_latitude_takes_the_earth_rate_out_of_G(tmp_path, capsys):
    """At rest a gyro reads the vertical Earth rate ``EARTH_RATE sin(lat)`` along gravity, which the
    rests' fit cannot tell from an isotropic g-sensitivity. Simulated at the pole (the rests' output
    is ``b + S (G_TRUE + EARTH_RATE I) f``): without ``--latitude`` ``G``'s diagonal holds the
    0.0042 (deg/s)/g, with ``--latitude 90`` ``G`` is ``G_TRUE`` again (measured max error 0.0008)."""
    from jaxcal.constants import EARTH_RATE

    rec = multipos_recording(jax.random.PRNGKey(1), n_poses=24, gsens=G_TRUE + EARTH_RATE * np.eye(3))
    save_recording(rec, tmp_path / "pole.npz")
    Gs = {}
    for name, extra in (("plain", []), ("lat", ["--latitude", "90"])):
        code, _, err = _run(capsys, "calibrate", "--method", "multipos", tmp_path / "pole.npz", "--g-sensitivity",
                            "--no-held-out", *extra, "--out", tmp_path / f"{name}.npz")
        assert code == 0, err
        Gs[name] = np.asarray(load_model(tmp_path / f"{name}.npz").state["gyr"]["G"])
    np.testing.assert_allclose(Gs["plain"] - Gs["lat"], EARTH_RATE * np.eye(3), atol=1e-15)
    assert np.degrees(np.abs(Gs["lat"] - G_TRUE)).max() < 0.002
    assert np.degrees(np.abs(np.diag(Gs["plain"] - G_TRUE))).min() > 0.002
    code, _, err = _run(capsys, "calibrate", "--method", "multipos", tmp_path / "pole.npz", "--latitude", "48",
                        "--out", tmp_path / "x.npz")
    assert code == 2 and "--latitude" in err and "--g-sensitivity" in err and len(err.strip().splitlines()) == 1, err


def test_summary_says_when_G_made_the_held_out_figure_worse():
    """The printed lines compare the held-out figure with and without G, and say so when G hurt
    (as on the MPU-6050's 10-pose session: 1.93 deg with G, 1.77 without; results/real.md)."""
    from jaxcal.methods.summary import summary_lines

    def desc(with_g: float, without: float) -> dict:
        return {"held_out": {"acc_rms_mg": 0.8, "gyr_median_deg": with_g, "how": "folds",
                             "without_g_sensitivity": {"acc_rms_mg": 0.8, "gyr_median_deg": without, "how": "folds"}}}

    worse = summary_lines(desc(1.93, 1.77))
    assert worse[1].startswith("held out without --g-sensitivity: ") and "1.770 deg" in worse[1]
    assert worse[2].startswith("note: G left the held-out carried-gravity median worse: 1.930 deg against 1.770 deg")
    # a tie (the MPU-6050 through the CLI: 1.555 with G, 1.554 without) is no improvement, not "worse"
    tie = summary_lines(desc(1.555, 1.554))
    assert tie[2].startswith("note: G left the held-out carried-gravity median no better (within 5%): 1.555 deg")
    assert len(summary_lines(desc(0.0055, 0.116))) == 2  # G helped: no note
    assert len(summary_lines({"held_out": {"gyr_median_deg": 0.1, "how": "folds"}})) == 1  # no comparison asked for
