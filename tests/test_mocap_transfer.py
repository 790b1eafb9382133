"""Scoring a calibration on another recording against its mocap (:func:`jaxcal.eval.mocap.calibrated_rms`)
and the helpers of the real-rig part of experiments/apply_effects.py (halves, :func:`jaxcal.eval.mocap.half`;
dropping one effect, :func:`jaxcal.methods.diagnosed.without_effect`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxcal.constants import G0
from jaxcal.eval.mocap import as_recorded_rms, calibrated_rms, half
from jaxcal.methods import CalibrationModel
from jaxcal.methods.diagnosed import without_effect
from jaxcal.recording import recording_from_dict

FS, N, OM = 200.0, 2000, 1.0


def _turn(with_track: bool = False):
    """A body turning at OM rad/s about z on a circle of radius 2 m (closed form): its pose, and its
    true specific force (-2 OM^2 / g0, 0, 1) g and body rate (0, 0, OM) rad/s as the sensor outputs."""
    t = np.arange(N) / FS
    pos = np.stack([2 * np.cos(OM * t), 2 * np.sin(OM * t), np.zeros(N)], 1)
    q = Rotation.from_rotvec(np.stack([np.zeros(N), np.zeros(N), OM * t], 1)).as_quat()[:, [3, 0, 1, 2]]
    f = np.tile([-2 * OM**2 / G0, 0.0, 1.0], (N, 1))
    w = np.tile([0.0, 0.0, OM], (N, 1))
    d = {"t": t, "fs": FS, "acc": f, "gyr": w, "acc_unit": "g", "gyr_unit": "rad/s", "pos_ref": pos, "quat_ref": q}
    if with_track:
        d.update(gt_t=t[::2], gt_pos=pos[::2], gt_quat=q[::2])
    return recording_from_dict(d, "turn"), f, w


def test_calibrated_rms_is_the_offset_of_the_outputs_from_the_true_motion():
    """Outputs = true motion + a known constant error c: the score is rms(c) per component; the true
    motion itself scores (nearly) zero: the pose-derived reference of a closed-form pose is exact up
    to the kernel's discretisation."""
    rec, f, w = _turn()
    sig = {"acc": 0.03, "gyr": 0.02}
    exact = calibrated_rms(rec, {"acc_cal": f, "gyr_cal": w}, sig)
    # measured: acc 1.3e-5 g (x: 2.3e-5 g, the kernel's bias on the 0.2 g centripetal term), gyr 4.6e-7 rad/s
    assert exact["acc"]["rms"] < 5e-5 and exact["gyr"]["rms"] < 2e-6
    ca, cg = np.array([0.004, -0.002, 0.003]), np.array([0.01, 0.0, -0.02])
    got = calibrated_rms(rec, {"acc_cal": f + ca, "gyr_cal": w + cg}, sig)
    # measured deviation from rms(c): acc 9.8e-6 g (per axis 2.3e-5), gyr 7.4e-8 rad/s (per axis 1.4e-7): the reference error above
    for s, c, tol in (("acc", ca, 5e-5), ("gyr", cg, 1e-6)):
        assert abs(got[s]["rms"] - np.sqrt(np.mean(c**2))) < tol
        np.testing.assert_allclose(got[s]["rms_axes"], np.abs(c), rtol=0, atol=tol)
        assert got[s]["sigma_s"] == sig[s] and 0 < got[s]["n_rows"] <= N
    # only the sensors given are scored
    assert set(calibrated_rms(rec, {"gyr_cal": w}, sig)) == {"gyr"}


def test_calibrated_rms_of_the_recording_as_it_is_is_as_recorded_rms():
    """The recording's own outputs in as_recorded_rms's band (pose_sigma 0.02 s): the two scorers agree exactly."""
    rec, f, w = _turn()
    rng = np.random.default_rng(0)
    rec = rec.replace(acc=f + 0.003 * rng.standard_normal((N, 3)), gyr=w + 0.001 * rng.standard_normal((N, 3)))
    a = as_recorded_rms(rec, "diag")
    b = calibrated_rms(rec, {"acc_cal": rec.acc, "gyr_cal": rec.gyr}, {"acc": 0.02, "gyr": 0.02})
    for s in ("acc", "gyr"):
        assert b[s]["rms"] == pytest.approx(a[s], rel=1e-12)  # measured: identical (difference 0.0)


def test_half_partitions_the_samples_and_keeps_the_track_over_each_half():
    rec, _, _ = _turn(with_track=True)
    h0, h1 = half(rec, 0), half(rec, 1)
    assert h0.n + h1.n == N and h0.t[-1] < h1.t[0]
    np.testing.assert_array_equal(np.concatenate([h0.acc, h1.acc]), rec.acc)
    np.testing.assert_array_equal(np.concatenate([h0.quat_ref, h1.quat_ref]), rec.quat_ref)
    for h in (h0, h1):
        assert h.gt_t[0] >= h.t[0] - 0.05 and h.gt_t[-1] <= h.t[-1] + 0.05
        assert h.gt_t[0] <= h.t[0] + 0.01 and h.gt_t[-1] >= h.t[-1] - 0.01  # the track spans the half
        assert len(h.gt_pos) == len(h.gt_t) == len(h.gt_quat)


def test_without_drops_one_effect_and_t0_with_the_last_temperature_term():
    st = {"acc": {"S": np.eye(3), "b": np.zeros(3), "lever_arm": np.ones(3) * 0.01, "temperature_bias": np.ones(3) * 1e-4,
                  "T0": np.asarray(30.0)},
          "gyr": {"S": np.eye(3), "b": np.zeros(3), "time_offset": np.asarray(0.004)}}
    m = CalibrationModel("diagnosed", ("acc", "gyr"), st, {"effects": {"acc": ["lever_arm", "temperature_bias"], "gyr": ["time_offset"]}})
    a = without_effect(m, "acc", "temperature_bias")
    assert set(a.state["acc"]) == {"S", "b", "lever_arm"} and "T0" in m.state["acc"]  # the original is untouched
    g = without_effect(m, "gyr", "time_offset")
    assert set(g.state["gyr"]) == {"S", "b"} and a.state["gyr"]["time_offset"] == 0.004


TUMVI = Path(__file__).resolve().parent.parent / "data" / "tumvi_room1_512_16" / "room1.npz"


def _baseline_model_scores_the_residual(rec):
    """Diagnose ``rec``; its baseline-only model applied to ``rec`` and scored by calibrated_rms:
    residual x fitted scale = diagnose's own baseline residual, row for row."""
    from jaxcal.diagnose import diagnose_banded, prepare
    from jaxcal.diagnose import effects as E
    from jaxcal.diagnose.select import linearize_baseline
    from jaxcal.methods.diagnosed import diagnosed_model_state

    preps, res = diagnose_banded(rec, "diag")
    fit = diagnosed_model_state(preps, res, "diag", rec, baseline_only=True)
    out = CalibrationModel("diagnosed", fit.sensors, fit.state, fit.meta).apply(rec)
    cal = rec.replace(acc=out["acc_cal"], gyr=out["gyr_cal"])
    for s in ("acc", "gyr"):
        sig = preps[s].sigma_by_sensor[s]
        sd = prepare(cal, pose_sigma=sig).sensors[s]
        _, z = linearize_baseline("diag", sd, E.identity_beta("diag"), np.zeros(E.N_THETA[s]))
        rows = res[s].fit_rows
        scale = np.asarray(res[s].base_all.beta)[:3]
        # measured: 5.5e-16 g (acc), 1.2e-15 rad/s (gyr) on the first half of room1;
        # 1.3e-15 g, 7.7e-16 rad/s on its first 4000 rows (489 of them fitted)
        np.testing.assert_allclose(z[rows] * scale, np.asarray(res[s].base_all.resid)[rows], rtol=0, atol=1e-12)
        r = calibrated_rms(rec, out, {s: sig})[s]
        assert r["rms"] == pytest.approx(float(np.sqrt(np.mean(z[sd.valid] ** 2))), rel=1e-12)


@pytest.mark.skipif(not TUMVI.exists(), reason="TUM-VI copy not present")
def test_baseline_model_scores_the_diagnosis_own_residual_on_a_short_recording():
    """The check below on TUM-VI room1's first 4000 samples (20 s; as many rows as the diagnose
    tests' simulated recordings, whose compiled code it shares)."""
    from jaxcal.recording import load_recording, take_rows

    rec = load_recording(TUMVI)
    _baseline_model_scores_the_residual(take_rows(rec, np.arange(rec.n) < 4000))


@pytest.mark.slow
@pytest.mark.skipif(not TUMVI.exists(), reason="TUM-VI copy not present")
def test_baseline_model_scores_the_diagnosis_own_residual_on_its_recording():
    """The first half of TUM-VI room1 diagnosed; its baseline-only model applied to the same half and
    scored by calibrated_rms: residual x fitted scale = diagnose's own baseline residual, row for row
    (the scorer is input-referred, diagnose output-referred).

    Fast cover: tests/test_mocap_transfer.py::test_baseline_model_scores_the_diagnosis_own_residual_on_a_short_recording
    (the same check on the first 4000 samples).
    """
    from jaxcal.recording import load_recording

    _baseline_model_scores_the_residual(half(load_recording(TUMVI), 0))
