"""``jaxcal export``: linear models as plain JSON and as a C99 header (:mod:`jaxcal.export`).

Each export is checked against an independent reader: the JSON is parsed back and applied with
numpy's ``A @ (y - b)``; the header is compiled with ``gcc -std=c99 -pedantic -Wall -Wextra -Werror``
into a small program that calibrates a recording's raw samples. Both must give the calibrated
output of ``jaxcal apply`` (``methods.apply``) to float64 rounding.
"""

from __future__ import annotations

import functools
import json
import shutil
import subprocess

import jax
import numpy as np
import pytest
import yaml

from jaxcal import methods
from jaxcal.cli import main
from jaxcal.constants import G0
from jaxcal.export import (
    EQUATION,
    is_linear,
    linear_cals,
    linear_methods,
    lower_times_rotation,
    to_c_header,
    to_json,
    to_kalibr,
    to_openvins,
    yaml_document,
)
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.model_file import load_model, save_model
from jaxcal.recording import Recording, save_recording
from jaxcal.simulate import Dataset2Config
from jaxcal.simulate.recordings import dataset2_recordings, multipos_recording

SEED = 7
# Agreement with jaxcal apply: max |difference| over the largest calibrated value. Measured (acc, gyr):
# the JSON applied sample by sample with numpy, linear 1.1e-16, 1.6e-16, multipos 2.2e-16, 1.5e-16 (as one
# matmul: 0, bit-identical); the compiled C header (gcc -O2), the same 1.1e-16 to 2.2e-16 (at most 1 ulp).
REL_TOL = 1e-14


@functools.cache
def _dataset2() -> Recording:
    """12 labelled rotation sequences of Dataset 2 (1212 samples, raw counts)."""
    recs, _ = dataset2_recordings(SEED, Dataset2Config(n_train=12, n_val=2), True)
    return recs["train"]


@functools.cache
def _multipos() -> Recording:
    """12 static poses joined by rotations (raw counts, no labels)."""
    return multipos_recording(jax.random.PRNGKey(3), n_poses=12)


RECORDINGS = {"linear": _dataset2, "multipos": _multipos}


@functools.cache
def _model(method: str) -> CalibrationModel:
    return methods.fit(method, RECORDINGS[method]())


def _rel_err(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.max(np.abs(a - ref)) / np.max(np.abs(ref)))


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_linear_methods_are_those_applied_as_affine():
    assert set(linear_methods()) == {"linear", "multipos", "online"}


def test_a_is_the_inverse_of_the_stored_forward_model():
    """On a model with a known forward ``S``: the export's ``A`` is ``S^{-1}``, ``b`` unchanged."""
    rng = np.random.default_rng(0)
    S = np.diag([16384.0, 16000.0, 16500.0]) + rng.normal(0, 50, (3, 3))
    b = rng.normal(0, 100, 3)
    model = CalibrationModel("linear", ("acc",), {"acc": {"S": S, "b": b}}, {"units": {"acc": "LSB"}})
    cal = linear_cals(model)["acc"]
    # Measured: |A S - I| = 1.1e-16.
    np.testing.assert_allclose(cal.A @ S, np.eye(3), atol=1e-14)
    np.testing.assert_array_equal(cal.b, b)
    d = json.loads(json.dumps(to_json(model)))
    assert d["equation"] == EQUATION and d["sensors"]["acc"]["input_unit"] == "LSB"
    assert d["sensors"]["acc"]["output_unit"] == "g"
    np.testing.assert_array_equal(np.asarray(d["sensors"]["acc"]["A"]), cal.A)  # repr round-trips exactly


@pytest.mark.parametrize("method", sorted(RECORDINGS))
def test_json_round_trip_matches_apply(method, tmp_path):
    model = _model(method)
    rec = RECORDINGS[method]()
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(to_json(model), indent=2))
    d = json.loads(path.read_text())
    assert d["method"] == method and d["equation"] == "x = A @ (y - b)"
    assert set(d["sensors"]) == set(model.sensors) and json.dumps(d["meta"]) is not None
    ref = methods.apply(model, rec)
    for s, p in d["sensors"].items():
        A, b = np.asarray(p["A"], np.float64), np.asarray(p["b"], np.float64)
        assert A.shape == (3, 3) and b.shape == (3,)
        assert p["input_unit"] == model.meta["units"][s]
        y = np.asarray(getattr(rec, s), np.float64)
        x = np.stack([A @ (row - b) for row in y[:200]])  # the equation as written, sample by sample
        assert _rel_err(x, ref[f"{s}_cal"][:200]) < REL_TOL
        x_all = (y - b) @ A.T
        assert _rel_err(x_all, ref[f"{s}_cal"]) < REL_TOL


C_MAIN = r"""
#include <stdio.h>
#include <string.h>
#include "cal.h"

/* usage: prog acc|gyr FILE (raw float64 samples, 3 per row); prints x = A (y - b) per row */
int main(int argc, char **argv)
{
    double y[3], x[3], z[3];
    FILE *f;
    int acc, i;
    if (argc != 3) return 2;
    acc = strcmp(argv[1], "acc") == 0;
    f = fopen(argv[2], "rb");
    if (!f) return 3;
    while (fread(y, sizeof(double), 3, f) == 3) {
        for (i = 0; i < 3; ++i) z[i] = y[i];
        if (acc) { jaxcal_cal_apply_acc(y, x); jaxcal_cal_apply_acc(z, z); }
        else { jaxcal_cal_apply_gyr(y, x); jaxcal_cal_apply_gyr(z, z); }
        if (memcmp(x, z, sizeof x) != 0) return 4; /* in place must equal out of place */
        printf("%.17g %.17g %.17g\n", x[0], x[1], x[2]);
    }
    fclose(f);
    return 0;
}
"""


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no gcc on this machine to compile the exported C header")
def test_c_header_compiles_and_matches_jaxcal_apply(tmp_path, capsys):
    model = _model("linear")
    rec = _dataset2()
    save_model(model, tmp_path / "lin.npz")
    save_recording(rec, tmp_path / "rec.npz")
    code, _, err = _run(capsys, "export", tmp_path / "lin.npz", "--format", "c", "--out", tmp_path / "cal.h")
    assert code == 0, err
    (tmp_path / "main.c").write_text(C_MAIN)
    exe = tmp_path / "calib"
    cc = subprocess.run(["gcc", "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(exe),
                         str(tmp_path / "main.c")], capture_output=True, text=True, cwd=tmp_path)
    assert cc.returncode == 0, cc.stderr
    code, _, err = _run(capsys, "apply", tmp_path / "lin.npz", tmp_path / "rec.npz", "--out", tmp_path / "out.npz")
    assert code == 0, err
    with np.load(tmp_path / "out.npz") as z:
        ref = {k: z[k] for k in z.files}
    for s in model.sensors:
        raw = tmp_path / f"{s}.bin"
        np.ascontiguousarray(getattr(rec, s), dtype="<f8").tofile(raw)
        res = subprocess.run([str(exe), s, str(raw)], capture_output=True, text=True)
        assert res.returncode == 0, (res.returncode, res.stderr)
        x = np.loadtxt(res.stdout.splitlines(), dtype=np.float64)
        assert x.shape == (rec.n, 3)
        assert _rel_err(x, ref[f"{s}_cal"]) < REL_TOL


def test_cli_export_c_and_json(tmp_path, capsys):
    save_model(_model("linear"), tmp_path / "model.npz")
    code, out, err = _run(capsys, "export", tmp_path / "model.npz", "--format", "c", "--out", tmp_path / "x.h")
    assert code == 0 and out == "" and len(err.strip().splitlines()) == 1, err
    text = (tmp_path / "x.h").read_text()
    for needle in ("#ifndef JAXCAL_CAL_H", "static const double jaxcal_cal_acc_A[3][3]",
                   "static inline void jaxcal_cal_apply_gyr(const double y[3], double x[3])", EQUATION):
        assert needle in text
    code, _, err = _run(capsys, "export", tmp_path / "model.npz", "--format", "c", "--name", "imu0",
                        "--out", tmp_path / "imu0.h")
    assert code == 0, err
    assert "imu0_apply_acc" in (tmp_path / "imu0.h").read_text()
    code, _, err = _run(capsys, "export", tmp_path / "model.npz", "--format", "json", "--out", tmp_path / "x.json")
    assert code == 0, err
    d = json.loads((tmp_path / "x.json").read_text())
    assert d["method"] == "linear" and "\n  " in (tmp_path / "x.json").read_text()  # indented


def _fake_model(method: str) -> CalibrationModel:
    """A model file of a non-linear method (the export refuses on the method, before reading its state)."""
    return CalibrationModel(method, ("acc",), {"acc": {"w": np.zeros((3, 3))}}, {"units": {"acc": "LSB"}})


@pytest.mark.parametrize("method", ["nn", "cubic", "online-thesis"])
def test_nonlinear_model_is_refused(method, tmp_path, capsys):
    model = _fake_model(method)
    assert not is_linear(model)
    with pytest.raises(ModelError, match="is not linear"):
        to_json(model)
    if method != "nn":
        return
    save_model(model, tmp_path / "nn.npz")
    assert load_model(tmp_path / "nn.npz").method == "nn"
    code, out, err = _run(capsys, "export", tmp_path / "nn.npz", "--format", "c", "--out", tmp_path / "nn.h")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
    assert "nn.npz" in err and "'nn' is not linear" in err and "only the methods" in err
    assert all(m in err for m in linear_methods())
    assert not (tmp_path / "nn.h").exists()


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--format", "yaml", "--out", "{t}/x.yaml"], "invalid choice: 'yaml'"),
        (["--format", "c", "--out", "{t}/x.json"], "the c export is written as .h"),
        (["--format", "json", "--out", "{t}/model.npz"], "is written as .json"),
        (["--format", "c", "--out", "{t}/x.h", "--name", "9bad"], "expected a C identifier"),
    ],
)
def test_cli_export_bad_input(argv, needle, tmp_path, capsys):
    save_model(_model("linear"), tmp_path / "model.npz")
    code, out, err = _run(capsys, "export", tmp_path / "model.npz", *(a.format(t=tmp_path) for a in argv))
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
    assert needle in err, err


def test_cli_export_refuses_to_overwrite_its_input(tmp_path, capsys):
    save_model(_model("linear"), tmp_path / "m.npz")
    shutil.copy(tmp_path / "m.npz", tmp_path / "m.h")  # a model file named like the output (load_model reads it)
    before = (tmp_path / "m.h").read_bytes()
    code, _, err = _run(capsys, "export", tmp_path / "m.h", "--format", "c", "--out", tmp_path / "m.h")
    assert code == 2 and "would overwrite the input" in err, err
    assert (tmp_path / "m.h").read_bytes() == before


def test_bad_c_name_is_refused_by_the_library():
    with pytest.raises(ValueError, match="not an identifier"):
        to_c_header(_model("linear"), name="a-b")


# ----------------------------------------------------------------------------- Kalibr and OpenVINS (YAML)
# Each file is read back with yaml.safe_load and applied with that tool's own equation, written here from
# its source, independently of jaxcal.export; the result must be jaxcal apply's output in m/s^2 and rad/s.
# Measured max |difference| over the largest calibrated value (acc, gyr), first 300 samples: kalibr linear
# 5.5e-16, 4.9e-16, multipos 1.8e-16, 5.2e-16; openvins linear 4.5e-16, 3.2e-16, multipos 1.8e-16, 4.2e-16
# (a few ulp: the tools' equations invert triangular factors, jaxcal applies S^{-1} directly).
YAML_REL_TOL = 1e-14


def _read_yaml(path) -> dict:
    text = path.read_text()
    if text.startswith("%YAML:1.0"):  # OpenVINS/OpenCV directive; not YAML 1.1 syntax, so a YAML reader skips it
        text = text.split("\n", 1)[1]
    return yaml.safe_load(text)


def _kalibr_apply(imu: dict, alpha: np.ndarray, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kalibr's scale-misalignment model inverted, per sample.

    ethz-asl/kalibr aslam_offline_calibration/kalibr/python/kalibr_imu_camera_calibration/IccSensors.py,
    class IccScaledMisalignedImu: addAccelerometerErrorTerms predicts ``a = M * (C_i_b * a_b) + b_i``
    (lever arm r_b = 0), addGyroscopeErrorTerms ``w = M * (C_gyro_b * w_b) + Ma * (C_gyro_b * a_b) + b_i``
    with ``C_gyro_b = C_gyro_i * C_i_b``; getTransformationFromBodyToImu gives T_i_b's rotation C_i_b.
    """
    C_i_b = np.asarray(imu["T_i_b"], np.float64)[:3, :3]
    M_a = np.asarray(imu["accelerometers"]["M"], np.float64)
    M_g = np.asarray(imu["gyroscopes"]["M"], np.float64)
    A_g = np.asarray(imu["gyroscopes"]["A"], np.float64)
    C_gyro_i = np.asarray(imu["gyroscopes"]["C_gyro_i"], np.float64)
    b_a, b_g = np.asarray(imu["jaxcal_b_a"], np.float64), np.asarray(imu["jaxcal_b_g"], np.float64)
    C_gyro_b = C_gyro_i @ C_i_b
    a_b = np.stack([C_i_b.T @ np.linalg.solve(M_a, y - b_a) for y in alpha])
    w_b = np.stack([C_gyro_b.T @ np.linalg.solve(M_g, y - b_g - A_g @ (C_gyro_b @ a)) for y, a in zip(omega, a_b)])
    return a_b, w_b


def _openvins_apply(imu: dict, a_m: np.ndarray, w_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenVINS's correction of raw IMU samples, per sample.

    rpng/open_vins ov_msckf/src/core/VioManagerOptions.h (print_and_load_state): ``Dw = Tw^{-1}``,
    ``Da = Ta^{-1}``, ``R_GYROtoIMU = R_IMUtoGYRO^T``, ``R_ACCtoIMU = R_IMUtoACC^T``, and the "kalibr" IMU
    model keeps the lower triangle of Dw, Da (vec_dw << Dw.block<3,1>(0,0), Dw.block<2,1>(1,1), Dw(2,2));
    ov_msckf/src/state/Propagator.cpp: ``a_hat = R_ACCtoIMU * Da * (a_m - b_a)``,
    ``w_hat = R_GYROtoIMU * Dw * (w_m - b_g - Tg * a_hat)`` (docs.openvins.com/propagation_analytical.html).
    """
    Dw = np.tril(np.linalg.inv(np.asarray(imu["Tw"], np.float64)))
    Da = np.tril(np.linalg.inv(np.asarray(imu["Ta"], np.float64)))
    R_GYROtoIMU = np.asarray(imu["R_IMUtoGYRO"], np.float64).T
    R_ACCtoIMU = np.asarray(imu["R_IMUtoACC"], np.float64).T
    Tg = np.asarray(imu["Tg"], np.float64)
    b_a, b_g = np.asarray(imu["jaxcal_b_a"], np.float64), np.asarray(imu["jaxcal_b_g"], np.float64)
    a_hat = np.stack([R_ACCtoIMU @ Da @ (y - b_a) for y in a_m])
    w_hat = np.stack([R_GYROtoIMU @ Dw @ (y - b_g - Tg @ a) for y, a in zip(w_m, a_hat)])
    return a_hat, w_hat


def _check_rotation(C: np.ndarray) -> None:
    # Measured (random matrices of test_lower_times_rotation): |C C^T - I| <= 8.9e-16, |det C - 1| <= 6.7e-16.
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-14)
    assert abs(np.linalg.det(C) - 1.0) < 1e-14


@pytest.mark.parametrize("fmt", ["kalibr", "openvins"])
@pytest.mark.parametrize("method", sorted(RECORDINGS))
def test_yaml_round_trip_matches_apply(fmt, method, tmp_path, capsys):
    model = _model(method)
    rec = RECORDINGS[method]()
    save_model(model, tmp_path / "m.npz")
    code, out, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--out", tmp_path / "imu.yaml")
    assert code == 0 and out == "" and len(err.strip().splitlines()) == 1, err
    text = (tmp_path / "imu.yaml").read_text()
    assert text.startswith(("%YAML:1.0\n" if fmt == "openvins" else "") + "# IMU calibration exported by jaxcal")
    imu = _read_yaml(tmp_path / "imu.yaml")["imu0"]
    assert imu["jaxcal_input_unit_acc"] == model.meta["units"]["acc"]
    y_a, y_g = (np.asarray(getattr(rec, s), np.float64)[:300] for s in ("acc", "gyr"))
    if fmt == "kalibr":
        assert imu["model"] == "scale-misalignment"
        for M in (imu["accelerometers"]["M"], imu["gyroscopes"]["M"]):
            assert np.all(np.triu(np.asarray(M), 1) == 0.0)  # lower triangular, as Kalibr's M_*_Dv pattern
        _check_rotation(np.asarray(imu["gyroscopes"]["C_gyro_i"]))
        _check_rotation(np.asarray(imu["T_i_b"])[:3, :3])
        assert np.all(np.asarray(imu["gyroscopes"]["A"]) == 0.0)
        a, w = _kalibr_apply(imu, y_a, y_g)
    else:
        assert imu["model"] == "kalibr"
        for T in (imu["Tw"], imu["Ta"]):
            assert np.all(np.triu(np.asarray(T), 1) == 0.0)
        _check_rotation(np.asarray(imu["R_IMUtoGYRO"]))
        _check_rotation(np.asarray(imu["R_IMUtoACC"]))
        assert np.all(np.asarray(imu["Tg"]) == 0.0)
        a, w = _openvins_apply(imu, y_a, y_g)
    ref = methods.apply(model, rec)
    assert _rel_err(a, G0 * np.asarray(ref["acc_cal"], np.float64)[:300]) < YAML_REL_TOL
    assert _rel_err(w, np.asarray(ref["gyr_cal"], np.float64)[:300]) < YAML_REL_TOL


def _random_matrices() -> list[np.ndarray]:
    rng = np.random.default_rng(11)
    mats = [rng.normal(size=(3, 3)) for _ in range(40)]  # about half with det < 0
    mats += [np.diag([16384.0, 16000.0, 16500.0]) + rng.normal(0, 300, (3, 3)) for _ in range(10)]
    mats += [np.eye(3), np.diag([2.0, -3.0, 4.0]), np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])]
    return mats


def test_lower_times_rotation():
    worst = 0.0
    for X in _random_matrices():
        T, C = lower_times_rotation(X)
        assert np.all(np.triu(T, 1) == 0.0)
        _check_rotation(C)
        d = np.diag(T)
        assert np.all(d[:2] > 0) and (d[2] > 0) == (np.linalg.det(X) > 0)
        worst = max(worst, float(np.max(np.abs(T @ C - X)) / np.max(np.abs(X))))
    assert worst < 1e-14  # measured 8.4e-16


def test_lower_times_rotation_refuses_a_singular_matrix():
    with pytest.raises(ModelError, match="singular"):
        lower_times_rotation(np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]]) * 0.0)


def test_yaml_exports_need_both_sensors_and_keep_their_keys(tmp_path, capsys):
    m = _model("linear")
    acc_only = CalibrationModel("linear", ("acc",), {"acc": m.state["acc"]}, {"units": {"acc": "LSB"}})
    for f in (to_kalibr, to_openvins):
        with pytest.raises(ModelError, match="no gyr calibration"):
            f(acc_only)
        with pytest.raises(ValueError, match="may not replace"):
            f(m, {"jaxcal_b_a": [0, 0, 0]})
    d = to_kalibr(m, {"rostopic": "/imu0", "update_rate": 100.0})["imu0"]
    assert d["rostopic"] == "/imu0" and d["update_rate"] == 100.0
    with pytest.raises(ValueError, match="unknown YAML export format"):
        yaml_document("vins", d)
    save_model(acc_only, tmp_path / "a.npz")
    code, out, err = _run(capsys, "export", tmp_path / "a.npz", "--format", "openvins", "--out", tmp_path / "o.yaml")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
    assert "a.npz" in err and "no gyr calibration" in err and not (tmp_path / "o.yaml").exists()
    code, _, err = _run(capsys, "export", tmp_path / "a.npz", "--format", "kalibr", "--out", tmp_path / "o.json")
    assert code == 2 and "the kalibr export is written as .yaml" in err, err
