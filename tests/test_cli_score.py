"""``jaxcal score MODEL REC`` (issue 29, point 4): a model's figures on another recording, through the
CLI, checked against a second computation of the same figure (the method's own held-out or in-sample
row) and, against mocap, against a closed form (a known bias offset adds its square to the mean square)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli as run

from jaxcal import methods
from jaxcal.cli import main
from jaxcal.eval.transfer import mocap_row, score_outputs
from jaxcal.methods.base import holdout_mask
from jaxcal.methods.quality import refit_quality
from jaxcal.model_file import load_model, save_model
from jaxcal.recording import crop, load_recording, save_recording, take_rows

ROOT = Path(__file__).resolve().parents[1]
MPU = ROOT / "data" / "tomisuarez_mpu6050"
BROAD07 = ROOT / "data" / "broad_07_undisturbed_fast_rotation_B" / "07_undisturbed_fast_rotation_B.npz"



def test_score_of_a_refitted_linear_model_on_its_held_out_rows_is_the_methods_held_out_figure(tmp_path, capsys):
    """``linear``'s held-out figure is its model refitted without the validation rows, scored on
    them; ``jaxcal score`` of that refitted model on a file of those rows gives the same numbers."""
    d = tmp_path / "d2"
    assert main(["simulate", "dataset2", "--labels", "--n-train", "12", "--n-val", "4", "--seed", "3",
                 "--out", str(d)]) == 0
    rec = load_recording(d / "train.npz")
    opts = methods.LinearOptions()
    model = methods.fit("linear", rec, opts)
    _, want = refit_quality(rec, opts, model)
    val = holdout_mask(rec, 0.15)
    save_recording(take_rows(rec, ~val), tmp_path / "fit_rows.npz")
    save_recording(take_rows(rec, val), tmp_path / "val_rows.npz")
    assert main(["calibrate", "--method", "linear", str(tmp_path / "fit_rows.npz"), "--no-held-out", "-q",
                 "--out", str(tmp_path / "sub.npz")]) == 0
    capsys.readouterr()
    code, out, err = run(capsys, "score", tmp_path / "sub.npz", tmp_path / "val_rows.npz", "--out", tmp_path / "s.json")
    assert code == 0, err
    got = json.loads((tmp_path / "s.json").read_text())["scores"]["labels"]
    for k in ("acc_rms_mg", "gyr_rms_degs"):
        assert got[k] == pytest.approx(want[k], rel=1e-9)
    assert "labels:" in out


def test_score_of_multipos_on_its_own_recording_is_its_in_sample_row_and_scores_the_next_recording(tmp_path, capsys):
    """On the recording it was fitted on, the rests' score is ``multipos``'s in-sample row (same rests,
    the fit's own summary); on the MPU-6050's next recording (rot90x: two rests and a 90 deg turn) the
    score is held out, and ``--rest-bias`` (this power-up's gyro bias) improves the turn."""
    model = tmp_path / "mpu.npz"
    assert main(["calibrate", "--method", "multipos", str(MPU / "calibration.npz"), "--no-held-out", "-q",
                 "--out", str(model)]) == 0
    capsys.readouterr()
    code, out, err = run(capsys, "score", model, MPU / "calibration.npz", "--out", tmp_path / "own.json")
    assert code == 0, err
    got = json.loads((tmp_path / "own.json").read_text())["scores"]["rests"]
    want = load_model(model).meta["fit_quality"]
    assert got["acc_rms_mg"] == pytest.approx(want["acc_rms_mg"], rel=1e-6)
    assert got["gyr_median_deg"] == pytest.approx(want["gyr_median_deg"], rel=1e-6)
    got = {}
    for extra in ([], ["--rest-bias", "5"]):
        code, out, err = run(capsys, "score", model, MPU / "rot90x.npz", "--out", tmp_path / "next.json", *extra)
        assert code == 0, err
        assert "rests:" in out and "2 rests" in out
        got[bool(extra)] = json.loads((tmp_path / "next.json").read_text())["scores"]["rests"]
    # The start-up bias of rot90x's power-up (up to 0.10 deg/s) carried over the 90 deg turn: the
    # initial-rest bias more than halves the carried-gravity error (1.24 -> 0.46 deg when written).
    assert got[True]["gyr_median_deg"] < 0.5 * got[False]["gyr_median_deg"]
    assert got[True]["acc_rms_mg"] == got[False]["acc_rms_mg"]


@pytest.fixture(scope="module")
def broad_crop(tmp_path_factory):
    d = tmp_path_factory.mktemp("broad")
    rec = crop(load_recording(BROAD07), 20.0, 32.0)
    save_recording(rec, d / "b07.npz")
    return d, rec


def test_score_against_mocap_adds_a_known_bias_in_quadrature(broad_crop, tmp_path, capsys):
    """Against the BROAD crop's mocap: the CLI's row is the library's; a gyro bias of +d and -d on every
    axis changes the mean square by d^2 on average (the band's kernel keeps constants)."""
    d, rec = broad_crop
    eye = {"S": np.eye(3), "b": np.zeros(3)}
    model = methods.CalibrationModel("linear", ("acc", "gyr"), {"acc": eye, "gyr": eye},
                                     {"units": {"acc": "g", "gyr": "rad/s"}})
    save_model(model, tmp_path / "identity.npz")
    code, out, err = run(capsys, "score", tmp_path / "identity.npz", d / "b07.npz", "--out", tmp_path / "s.json")
    assert code == 0, err
    got = json.loads((tmp_path / "s.json").read_text())["scores"]["mocap"]
    outputs = model.apply(rec)
    lib = mocap_row(rec, outputs)
    assert got["acc_rms_mg"] == pytest.approx(lib["acc_rms_mg"], rel=1e-12)
    assert got["gyr_rms_degs"] == pytest.approx(lib["gyr_rms_degs"], rel=1e-12)
    bias = 0.01  # rad/s on every axis: the mean square over all elements grows by bias**2
    ms = []
    for sign in (1.0, -1.0):
        shifted = dict(outputs, gyr_cal=outputs["gyr_cal"] + sign * bias)
        ms.append((np.radians(score_outputs(rec, shifted)["mocap"]["gyr_rms_degs"])) ** 2)
    r0 = np.radians(lib["gyr_rms_degs"]) ** 2
    assert 0.5 * (ms[0] + ms[1]) == pytest.approx(r0 + bias**2, rel=1e-9)


def test_score_refuses_a_recording_with_nothing_to_score_against(tmp_path, capsys):
    """A gyro-only recording without labels, seq ids or pose: exit 2, one line, nothing written."""
    rec = load_recording(MPU / "rot90x.npz")
    save_recording(rec.replace(acc=None, acc_lsb_per_g=None, acc_bias_lsb=None), tmp_path / "gyr_only.npz")
    eye = {"S": np.eye(3) * 131.0 * 180 / np.pi, "b": np.zeros(3)}
    save_model(methods.CalibrationModel("linear", ("gyr",), {"gyr": eye}, {"units": {"gyr": "LSB"}}), tmp_path / "m.npz")
    code, out, err = run(capsys, "score", tmp_path / "m.npz", tmp_path / "gyr_only.npz", "--out", tmp_path / "s.json")
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "nothing to score against" in err
    assert not (tmp_path / "s.json").exists()
