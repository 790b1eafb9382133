"""``jaxcal noise`` on a raw recording without datasheet values takes them as flags (issue 29,
point 4): the same figures as when the file holds them; wrong uses are refused naming the flag."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli as run

from jaxcal.recording import crop, load_recording, save_recording

MPU = Path(__file__).resolve().parents[1] / "data" / "tomisuarez_mpu6050"



@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("noise")
    rec = crop(load_recording(MPU / "tinit_calc.npz"), 0.0, 120.0)
    save_recording(rec, d / "with.npz")
    save_recording(rec.replace(acc_lsb_per_g=None, acc_bias_lsb=None, gyr_lsb_per_rads=None, gyr_bias_lsb=None),
                   d / "without.npz")
    return d, rec


def test_datasheet_flags_give_the_figures_of_a_file_that_holds_them(files, capsys):
    d, rec = files
    code, _, err = run(capsys, "noise", d / "with.npz", "--out", d / "a", "--quiet")
    assert code == 0, err
    code, _, err = run(capsys, "noise", d / "without.npz", "--out", d / "b", "--quiet")
    assert code == 2 and "--acc-lsb-per-g" in err and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "noise", d / "without.npz", "--out", d / "b", "--quiet",
                       "--acc-lsb-per-g", *np.atleast_1d(rec.acc_lsb_per_g), "--gyr-lsb-per-rads", *np.atleast_1d(rec.gyr_lsb_per_rads))
    assert code == 0, err
    assert (d / "a" / "imu.yaml").read_text() == (d / "b" / "imu.yaml").read_text()
    want, got = (json.loads((d / x / "noise.json").read_text()) for x in ("a", "b"))
    assert {k: v for k, v in got.items() if k != "recording"} == {k: v for k, v in want.items() if k != "recording"}


@pytest.mark.parametrize("argv,words", [
    (["--acc-lsb-per-g", "1"], ["--acc-lsb-per-g", "not near 1 g"]),  # 16384 g: the scale is wrong
    (["--gyr-lsb-per-rads", "1", "2"], ["one value or three"]),
])
def test_wrong_datasheet_flags_are_refused_naming_the_flag(files, tmp_path, capsys, argv, words):
    d, _ = files
    code, _, err = run(capsys, "noise", d / "without.npz", "--out", tmp_path / "o", "--quiet", *argv)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert all(w in err for w in words), err
    assert not (tmp_path / "o").exists()


def test_a_datasheet_flag_on_a_physical_recording_is_refused(files, tmp_path, capsys):
    d, rec = files
    phys = rec.replace(acc=np.asarray(rec.acc, np.float64) / rec.acc_lsb_per_g, acc_unit="g", acc_lsb_per_g=None,
                       acc_bias_lsb=None)
    save_recording(phys, tmp_path / "phys.npz")
    code, _, err = run(capsys, "noise", tmp_path / "phys.npz", "--out", tmp_path / "o", "--acc-lsb-per-g", "16384")
    assert code == 2 and "--acc-lsb-per-g" in err and "not raw counts" in err
