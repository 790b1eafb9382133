"""``jaxcal apply`` writes a recording every other command reads (issue 29, point 4), and says what a
model does not carry: the gyro's start-up bias of one power-up (``--rest-bias`` takes the new one's)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli as run

from jaxcal import methods
from jaxcal.cli import main
from jaxcal.model_file import load_model, save_model
from jaxcal.recording import load_recording

ROOT = Path(__file__).resolve().parents[1]
MPU = ROOT / "data" / "tomisuarez_mpu6050"
PHYS = {"acc": "g", "gyr": "rad/s"}



def identity_model(path: Path) -> None:
    """A ``linear`` model that leaves g and rad/s as they are."""
    eye = {"S": np.eye(3), "b": np.zeros(3)}
    save_model(methods.CalibrationModel("linear", ("acc", "gyr"), {"acc": eye, "gyr": eye}, {"units": PHYS}), path)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    d = tmp_path_factory.mktemp("lab")
    assert main(["simulate", "dataset2", "--labels", "--n-train", "12", "--n-val", "4", "--seed", "5",
                 "--out", str(d)]) == 0
    assert main(["calibrate", "--method", "linear", str(d / "train.npz"), "--no-held-out", "-q",
                 "--out", str(d / "lin.npz")]) == 0
    return d


def test_apply_writes_a_recording_that_calibrate_and_score_read_with_the_same_numbers(lab, tmp_path, capsys):
    """The output holds the recording with acc in g and gyr in rad/s (labels and seq ids kept, the
    datasheet values gone) beside acc_cal / gyr_cal. ``linear`` refitted on it is the identity (least
    squares is affine-equivariant), and an identity model scores it exactly as the model scores the raw file."""
    cal = tmp_path / "cal.npz"
    code, _, err = run(capsys, "apply", lab / "lin.npz", lab / "train.npz", "--out", cal)
    assert code == 0, err
    raw, rec = load_recording(lab / "train.npz"), load_recording(cal)
    assert (rec.acc_unit, rec.gyr_unit) == ("g", "rad/s") and rec.acc_lsb_per_g is None and rec.gyr_lsb_per_rads is None
    np.testing.assert_array_equal(rec.acc, rec.extra["acc_cal"])
    np.testing.assert_array_equal(rec.gyr_ref, raw.gyr_ref)
    np.testing.assert_array_equal(rec.seq, raw.seq)
    code, _, err = run(capsys, "calibrate", "--method", "linear", cal, "--no-held-out", "-q", "--out", tmp_path / "again.npz")
    assert code == 0, err
    again = load_model(tmp_path / "again.npz")
    for s in ("acc", "gyr"):
        np.testing.assert_allclose(again.state[s]["S"], np.eye(3), atol=1e-6)
        np.testing.assert_allclose(again.state[s]["b"], 0.0, atol=1e-6)
    identity_model(tmp_path / "identity.npz")
    assert main(["score", str(lab / "lin.npz"), str(lab / "train.npz"), "--out", str(tmp_path / "raw.json")]) == 0
    assert main(["score", str(tmp_path / "identity.npz"), str(cal), "--out", str(tmp_path / "cal.json")]) == 0
    want = json.loads((tmp_path / "raw.json").read_text())["scores"]
    got = json.loads((tmp_path / "cal.json").read_text())["scores"]
    assert set(got) == set(want) == {"labels", "sequences"}
    for row in want:
        for k, v in want[row].items():
            if k != "how":
                assert got[row][k] == pytest.approx(v, rel=1e-9, abs=1e-12), (row, k)


def test_an_implausible_output_is_written_as_the_calibrated_arrays_with_a_warning(lab, tmp_path, capsys):
    """A model whose output is no accelerometer in g (10x too large) still writes t and acc_cal, and
    says in one warning line that the file is not a recording."""
    m = load_model(lab / "lin.npz")
    state = {s: dict(m.state[s]) for s in m.sensors}
    state["acc"]["S"] = 0.1 * np.asarray(state["acc"]["S"])
    save_model(methods.CalibrationModel(m.method, m.sensors, state, dict(m.meta)), tmp_path / "bad.npz")
    code, _, err = run(capsys, "apply", tmp_path / "bad.npz", lab / "test_acc.npz", "--out", tmp_path / "o.npz", "-q")
    assert code == 0, err
    assert "not a recording" in err and len(err.strip().splitlines()) == 1
    with np.load(tmp_path / "o.npz") as z:
        assert set(z.files) == {"t", "acc_cal"}


@pytest.fixture(scope="module")
def mpu_model(tmp_path_factory):
    d = tmp_path_factory.mktemp("mpu")
    assert main(["calibrate", "--method", "multipos", str(MPU / "calibration.npz"), "--no-held-out", "-q",
                 "--out", str(d / "mpu.npz")]) == 0
    return d / "mpu.npz"


def test_noise_and_diagnose_read_the_applied_output(mpu_model, tmp_path, capsys):
    """``noise`` on the applied static recording: the gyro's white-noise density is the raw one's within
    the model's scale change from the datasheet (under 2 %, so 5 %); ``diagnose`` (no reference) reads
    an applied stretch."""
    code, _, err = run(capsys, "apply", mpu_model, MPU / "tinit_calc.npz", "--out", tmp_path / "static.npz", "-q")
    assert code == 0, err
    dens = []
    for name, rec in (("cal", tmp_path / "static.npz"), ("raw", MPU / "tinit_calc.npz")):
        code, _, err = run(capsys, "noise", rec, "--out", tmp_path / name, "--quiet")
        assert code == 0, err
        line = next(x for x in (tmp_path / name / "imu.yaml").read_text().splitlines() if x.startswith("gyroscope_noise_density"))
        dens.append(float(line.split(":")[1].split("#")[0]))
    assert dens[0] == pytest.approx(dens[1], rel=0.05)
    assert main(["crop", str(MPU / "calibration.npz"), "--end", "40", "--out", str(tmp_path / "c40.npz")]) == 0
    code, _, err = run(capsys, "apply", mpu_model, tmp_path / "c40.npz", "--out", tmp_path / "c40_cal.npz", "-q")
    assert code == 0, err
    code, _, err = run(capsys, "diagnose", tmp_path / "c40_cal.npz", "--out", tmp_path / "diag")
    assert code == 0, err
    report = json.loads((tmp_path / "diag" / "report.json").read_text())
    assert report["baseline"]["acc"]["unit"] == "g"


def test_rest_bias_removes_this_power_ups_gyro_bias_and_refuses_a_motion(mpu_model, tmp_path, capsys):
    """Without --rest-bias, apply names the start-up bias in a note; with it, the output is the plain
    one minus a constant, the mean over the first SEC s, which is then zero. A stretch with the 90 deg
    turn in it is no rest: refused naming --rest-bias, nothing written."""
    code, _, err = run(capsys, "apply", mpu_model, MPU / "rot90x.npz", "--out", tmp_path / "plain.npz")
    assert code == 0 and "start-up bias" in err and "--rest-bias" in err
    code, _, err = run(capsys, "apply", mpu_model, MPU / "rot90x.npz", "--out", tmp_path / "rb.npz", "--rest-bias", "5")
    assert code == 0, err
    plain, rb = load_recording(tmp_path / "plain.npz"), load_recording(tmp_path / "rb.npz")
    first = plain.t - plain.t[0] < 5.0
    b = plain.gyr[first].mean(0)
    assert 0.05 < np.degrees(np.abs(b)).max() < 0.2  # the MPU-6050's start-up bias on its next recording, deg/s
    np.testing.assert_allclose(rb.gyr, plain.gyr - b, atol=1e-15)
    np.testing.assert_allclose(rb.gyr[first].mean(0), 0.0, atol=1e-15)
    np.testing.assert_array_equal(rb.acc, plain.acc)
    code, _, err = run(capsys, "apply", mpu_model, MPU / "rot90x.npz", "--out", tmp_path / "moved.npz", "--rest-bias", "60")
    assert code == 2 and "--rest-bias 60" in err and "not at rest" in err
    assert not (tmp_path / "moved.npz").exists()


def test_apply_names_what_the_model_does_not_carry(lab, tmp_path, capsys):
    """A model whose fit found something it does not apply (a diagnosed model's ``meta["not_carried"]``)
    says so in one note line; -q silences it."""
    m = load_model(lab / "lin.npz")
    why = "tied to the fit recording's clock"
    meta = {**m.meta, "not_carried": [{"sensor": "gyr", "name": "bias_drift", "why": why}]}
    save_model(methods.CalibrationModel(m.method, m.sensors, m.state, meta), tmp_path / "m.npz")
    code, _, err = run(capsys, "apply", tmp_path / "m.npz", lab / "test_gyr.npz", "--out", tmp_path / "o.npz")
    assert code == 0, err
    notes = [x for x in err.splitlines() if "does not carry" in x]
    assert len(notes) == 1 and f"gyr bias_drift ({why})" in notes[0]
    code, _, err = run(capsys, "apply", tmp_path / "m.npz", lab / "test_gyr.npz", "--out", tmp_path / "q.npz", "-q")
    assert code == 0 and err == ""
