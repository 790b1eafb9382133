"""Errors name flags, never Python arguments (issue 29, point 4): bad inputs driven through the
command line; each refusal is one line on stderr naming the ``--flag`` to fix and no Python
argument name (``fs``, ``acc_unit``, ``skip_rows``, ``init_duration``, a keyword-argument error)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from jaxcal import methods
from jaxcal.cli import main
from jaxcal.model_file import save_model
from jaxcal.recording import crop, load_recording, save_recording

DATA = Path(__file__).resolve().parents[1] / "data"
PYTHON_NAMES = re.compile(r"(?<![-\w'])(fs|acc_unit|gyr_unit|time_unit|skip_rows|init_duration|rest_window|turns|"
                          r"acc_lsb_per_g|gyr_lsb_per_rads)(?![-\w'])|keyword argument|=None")


def _csv(tmp_path: Path, header: str) -> Path:
    p = tmp_path / "imu.csv"
    rows = [f"{0.01 * i:.2f},0,0,1,0,0,0" for i in range(300)]
    p.write_text(header + "\n" + "\n".join(rows) + "\n")
    return p


def _raw_model(tmp_path: Path) -> Path:
    eye = {"S": np.eye(3), "b": np.zeros(3)}
    p = tmp_path / "g_model.npz"
    save_model(methods.CalibrationModel("linear", ("acc", "gyr"), {"acc": eye, "gyr": eye},
                                        {"units": {"acc": "g", "gyr": "rad/s"}}), p)
    return p


def _mpu_crop(tmp_path: Path) -> Path:
    p = tmp_path / "mpu40.npz"
    save_recording(crop(load_recording(DATA / "tomisuarez_mpu6050" / "calibration.npz"), 0.0, 40.0), p)
    return p


CASES = {
    "csv without time or rate": (lambda d: ["import", "csv", _csv(d, "time,ax,ay,az,gx,gy,gz"), "--columns",
                                            "acc_x=ax,acc_y=ay,acc_z=az,gyr_x=gx,gyr_y=gy,gyr_z=gz",
                                            "--units", "acc=g,gyr=rad/s", "--out", d / "o.npz"], "--fs"),
    "csv time without unit": (lambda d: ["import", "csv", _csv(d, "time,ax,ay,az,gx,gy,gz"), "--columns",
                                         "t=time,acc_x=ax,acc_y=ay,acc_z=az,gyr_x=gx,gyr_y=gy,gyr_z=gz",
                                         "--units", "acc=g,gyr=rad/s", "--out", d / "o.npz"], "--units"),
    "imucal without rate": (lambda d: ["import", "imucal", DATA / "imucal_ferraris_example" / "example_ferraris_session_head.csv",
                                       "--out", d / "o.npz"], "--fs"),
    "noise on raw counts without a scale": (lambda d: ["noise", _strip_spec(d), "--out", d / "n"], "--acc-lsb-per-g"),
    "export datasheet on a g model": (lambda d: ["export", _raw_model(d), "--format", "kalibr", "--acc-lsb-per-g", "16384",
                                                 "--out", d / "k.yaml"], "--acc-lsb-per-g"),
    "turns outside the recording": (lambda d: ["calibrate", "--method", "multipos", DATA / "tomisuarez_mpu6050" /
                                               "calibration.npz", "--turns", "500-510",
                                               "--out", d / "m.npz"], "--turns"),
    "initial rest shorter than a window": (lambda d: ["calibrate", "--method", "online", _mpu_crop(d), "--init-duration",
                                                      "0.5", "--out", d / "m.npz"], "--init-duration"),
}


def _strip_spec(d: Path) -> Path:
    rec = crop(load_recording(DATA / "tomisuarez_mpu6050" / "tinit_calc.npz"), 0.0, 60.0)
    p = d / "raw.npz"
    save_recording(rec.replace(acc_lsb_per_g=None, acc_bias_lsb=None, gyr_lsb_per_rads=None, gyr_bias_lsb=None), p)
    return p


@pytest.mark.parametrize("name", list(CASES))
def test_refusal_names_the_flag_not_the_python_argument(name, tmp_path, capsys):
    argv, flag = CASES[name]
    code = main([str(a) for a in argv(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert flag in lines[0], lines[0]
    assert not PYTHON_NAMES.search(lines[0]), lines[0]


@pytest.mark.parametrize("fmt", ["kalibr", "openvins", "json"])
def test_a_diagnosed_model_is_refused_naming_the_format_asked_and_what_it_would_lose(fmt):
    """The refusal names the format asked for (not 'json and c'), the effects the model carries and, for
    the ROS-fed formats, why their IMU file cannot hold a time offset against a reference."""
    from jaxcal import formats
    from jaxcal.methods import ModelError

    model = methods.CalibrationModel("diagnosed", ("acc", "gyr"), {}, {"effects": {"acc": ["lever_arm", "time_offset"],
                                                                                   "gyr": ["time_offset"]}})
    with pytest.raises(ModelError) as e:
        formats.export(fmt, model)
    msg = str(e.value)
    assert f"the {fmt} export holds" in msg and "json and c" not in msg
    assert "acc: lever_arm, time_offset; gyr: time_offset" in msg
    assert ("timeshift_cam_imu" in msg) == (fmt in ("kalibr", "openvins"))
    assert "\n" not in msg
