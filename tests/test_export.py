"""``jaxcal export`` and ``jaxcal import-model`` (:mod:`jaxcal.export`).

Each export is checked against an independent reader: the JSON is parsed back and applied with
numpy's ``A @ (y - b)``; the header is compiled with ``gcc -std=c99 -pedantic -Wall -Wextra -Werror``
into a small program that calibrates a recording's raw samples; the Kalibr and OpenVINS YAML are
applied with each tool's own equation, written here from its source; the imucal JSON is loaded and
applied by imucal itself. All must give the calibrated output of ``jaxcal apply``
(``methods.apply``) to float64 rounding. Imports: export -> ``import-model`` -> apply gives the
original model's output, and a file made by imucal itself imports and applies as imucal's
``calibrate``; what a linear model cannot hold is refused with one line.
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
    IMPORT_FORMATS,
    import_model,
    is_linear,
    linear_cals,
    linear_methods,
    lower_times_rotation,
    scale_misalignment,
    to_c_header,
    to_imucal,
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


def _driver_input(imu: dict, y_a: np.ndarray, y_g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The samples the file's equation takes: a ROS driver's (the model's input times the conversion the
    file states, ``jaxcal_ros_per_model_unit_*``) for a ``jaxcal_units: ros`` file, else the model's input."""
    if imu.get("jaxcal_units") != "ros":
        return y_a, y_g
    return tuple(y * np.asarray(imu[f"jaxcal_ros_per_model_unit_{s}"], np.float64) for y, s in ((y_a, "acc"), (y_g, "gyr")))


@pytest.mark.parametrize("units", ["ros", "model"])
@pytest.mark.parametrize("fmt", ["kalibr", "openvins"])
@pytest.mark.parametrize("method", sorted(RECORDINGS))
def test_yaml_round_trip_matches_apply(fmt, method, units, tmp_path, capsys):
    model = _model(method)
    rec = RECORDINGS[method]()
    save_model(model, tmp_path / "m.npz")
    code, out, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--units", units, "--out", tmp_path / "imu.yaml")
    lines = err.strip().splitlines()
    assert code == 0 and out == "" and len(lines) == 2 and lines[1].startswith("jaxcal: not carried into"), err
    text = (tmp_path / "imu.yaml").read_text()
    assert text.startswith(("%YAML:1.0\n" if fmt == "openvins" else "") + "# IMU calibration exported by jaxcal")
    imu = _read_yaml(tmp_path / "imu.yaml")["imu0"]
    assert imu["jaxcal_input_unit_acc"] == ("m/s^2" if units == "ros" else model.meta["units"]["acc"])
    y_a, y_g = _driver_input(imu, *(np.asarray(getattr(rec, s), np.float64)[:300] for s in ("acc", "gyr")))
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


@pytest.mark.parametrize("fmt", ["kalibr", "openvins"])
def test_ros_units_map_a_reading_at_rest_to_gravity(fmt, tmp_path, capsys):
    """By default the file's own equation maps what a ROS driver publishes at rest (9.81 m/s^2 up) to
    ~9.81 m/s^2, not ~96 (a model fitted on g) or ~1.6e5 (a raw one): closed forms of known models."""
    S_a, b_a = np.diag([1.02, 0.98, 1.01]), np.array([0.05, -0.02, 0.01])  # g per g, g
    S_g, b_g = np.diag([1.01, 0.99, 1.0]), np.array([0.01, 0.0, -0.02])  # rad/s
    phys = CalibrationModel("linear", ("acc", "gyr"), {"acc": {"S": S_a, "b": b_a}, "gyr": {"S": S_g, "b": b_g}},
                            {"units": {"acc": "g", "gyr": "rad/s"}})
    k_a, k_g = 16384.0, 131.0 * 180.0 / np.pi  # datasheet LSB/g, LSB/(rad/s)
    raw = CalibrationModel("linear", ("acc", "gyr"), {"acc": {"S": k_a * S_a, "b": k_a * b_a}, "gyr": {"S": k_g * S_g, "b": k_g * b_g}},
                           {"units": {"acc": "LSB", "gyr": "LSB"}})
    f_up = np.array([0.0, 0.0, 1.0])  # g, at rest
    for model, extra, per_unit in ((phys, [], (G0, 1.0)), (raw, ["--acc-lsb-per-g", k_a, "--gyr-lsb-per-rads", k_g], (G0 / k_a, 1.0 / k_g))):
        save_model(model, tmp_path / "m.npz")
        code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, *extra, "--out", tmp_path / "r.yaml")
        assert code == 0 and "not carried into" in err and "constant bias" in err, err
        text = (tmp_path / "r.yaml").read_text()
        assert "# Input (jaxcal_units: ros)" in text and "# Not carried to" in text
        imu = _read_yaml(tmp_path / "r.yaml")["imu0"]
        assert imu["jaxcal_units"] == "ros" and imu["jaxcal_input_unit_acc"] == "m/s^2"
        np.testing.assert_allclose(imu["jaxcal_ros_per_model_unit_acc"], [per_unit[0]] * 3, rtol=1e-15)
        y_a = (S_a @ f_up + b_a) * (k_a if model is raw else 1.0)  # the model's input at rest
        y_ros = y_a * per_unit[0]  # what the driver publishes: ~9.81 m/s^2 up plus the bias
        assert 9.5 < y_ros[2] < 10.5
        apply = _kalibr_apply if fmt == "kalibr" else _openvins_apply
        a, w = apply(imu, y_ros[None], (b_g * (k_g if model is raw else 1.0) * per_unit[1])[None])
        np.testing.assert_allclose(a[0], G0 * f_up, atol=1e-12)  # 9.80665 m/s^2 up, the bias removed
        np.testing.assert_allclose(w[0], 0.0, atol=1e-14)
        assert imu["jaxcal_b_a"] == pytest.approx(list(b_a * G0), rel=1e-12)  # the bias in m/s^2: what the filter's state holds
    # a raw model without datasheet values: the model's own mean scale, said in the file
    save_model(raw, tmp_path / "m.npz")
    assert _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--out", tmp_path / "f.yaml")[0] == 0
    assert "no datasheet acc_lsb_per_g given, so the model's own mean scale" in (tmp_path / "f.yaml").read_text()
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--units", "model", "--acc-lsb-per-g", "1",
                        "--out", tmp_path / "g.yaml")
    assert code == 2 and "go with --units ros" in err
    save_model(phys, tmp_path / "m.npz")
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--acc-lsb-per-g", "16384", "--out", tmp_path / "h.yaml")
    assert code != 0 and "the acc model was fitted on g" in err, err
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", "json", "--units", "ros", "--out", tmp_path / "h.json")
    assert code == 2 and "--units goes with --format" in err, err


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


@pytest.mark.parametrize("fmt", ["kalibr", "openvins"])
def test_bias_standard_errors_go_into_the_yaml_exports_in_the_files_units(fmt, tmp_path, capsys):
    """A fit that recorded its biases' standard errors (``held_out.bias_sd``, the model's input unit,
    as multipos writes it) exports them as ``jaxcal_b_a_sd`` / ``jaxcal_b_g_sd``, converted as the
    biases are (ROS: the driver's m/s^2 and rad/s per LSB times the model's), and says where they
    are; a model without them says that its fit recorded none."""
    m = _model("linear")
    sd = {"acc": [14.0, 9.6, 8.5], "gyr": [4.4, 4.3, 1.2]}
    with_sd = CalibrationModel(m.method, m.sensors, m.state, {**m.meta, "held_out": {"bias_sd": {**sd, "how": "test"}}})
    save_model(with_sd, tmp_path / "m.npz")
    save_model(m, tmp_path / "plain.npz")
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--acc-lsb-per-g", "16384",
                        "--gyr-lsb-per-rads", "7505.7", "--out", tmp_path / "m.yaml")
    assert code == 0, err
    assert "standard error is in jaxcal_b_a_sd / jaxcal_b_g_sd" in err
    imu = _read_yaml(tmp_path / "m.yaml")["imu0"]
    np.testing.assert_allclose(imu["jaxcal_b_a_sd"], np.array(sd["acc"]) * G0 / 16384.0, rtol=1e-12)
    np.testing.assert_allclose(imu["jaxcal_b_g_sd"], np.array(sd["gyr"]) / 7505.7, rtol=1e-12)
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--units", "model", "--out", tmp_path / "u.yaml")
    assert code == 0, err
    np.testing.assert_allclose(_read_yaml(tmp_path / "u.yaml")["imu0"]["jaxcal_b_g_sd"], sd["gyr"], rtol=1e-12)
    code, _, err = _run(capsys, "export", tmp_path / "plain.npz", "--format", fmt, "--out", tmp_path / "p.yaml")
    assert code == 0 and "fit recorded none" in err, err
    assert "jaxcal_b_a_sd" not in _read_yaml(tmp_path / "p.yaml")["imu0"]


def _jackknife(v: np.ndarray) -> np.ndarray:
    """The delete-a-group jackknife standard error, written here from its formula (the test's own copy)."""
    g = len(v)
    return np.sqrt((g - 1) / g * ((v - v.mean(0)) ** 2).sum(0))


@pytest.mark.parametrize("fmt", ["kalibr", "openvins"])
def test_intrinsics_standard_errors_are_the_jackknife_of_the_files_own_numbers(fmt, tmp_path, capsys):
    """Folds with diagonal ``A`` (held_out.fold_cals, the model's raw input) give the file's scale
    matrices diagonal ``1 / (c a_k)`` per fold (c: the driver's conversion with the datasheet
    scales, 1 / G0 for the accelerometer in the model's unit) and identity rotations, so
    ``jaxcal_intrinsics_sd`` holds the closed-form jackknife of those on the diagonal and zero
    elsewhere; the file and stderr say where it is; OpenCV reads the file (with cv2 installed) and
    it still imports."""
    m = _model("linear")
    rng = np.random.default_rng(5)
    a = {"acc": np.array([6.1e-5, 6.0e-5, 6.2e-5]), "gyr": np.array([1.3e-4, 1.35e-4, 1.32e-4])}
    fa = {s: a[s] * (1.0 + 1e-3 * rng.normal(size=(7, 3))) for s in a}
    fold_cals = {s: {"A": [np.diag(v).tolist() for v in fa[s]], "b": rng.normal(0.0, 10.0, (7, 3)).tolist()} for s in a}
    with_sd = CalibrationModel(m.method, m.sensors, m.state, {**m.meta, "held_out": {"fold_cals": {**fold_cals, "how": "test"}}})
    save_model(with_sd, tmp_path / "m.npz")
    try:
        import cv2
    except ImportError:
        cv2 = None
    acc_key, gyr_key = (("accelerometers", "M"), ("gyroscopes", "M")) if fmt == "kalibr" else (("Ta",), ("Tw",))
    rot_key = ("T_i_b",) if fmt == "kalibr" else ("R_IMUtoACC",)

    def at(d, key):
        for k in key:
            d = d[k]
        return np.asarray(d, np.float64)

    phys = {"acc": G0, "gyr": 1.0}  # m/s^2 per g; rad/s
    for units, c in (("ros", {"acc": G0 / 16384.0, "gyr": 1.0 / 7505.7}), ("model", {"acc": 1.0, "gyr": 1.0})):
        extra = ("--acc-lsb-per-g", "16384", "--gyr-lsb-per-rads", "7505.7") if units == "ros" else ()
        out = tmp_path / f"{units}.yaml"
        code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--units", units, *extra, "--out", out)
        assert code == 0, err
        assert "a delete-one-pose jackknife over 7 folds" in err and "are in jaxcal_intrinsics_sd" in err
        sd = _read_yaml(out)["imu0"]["jaxcal_intrinsics_sd"]
        if cv2 is not None:  # what OpenVINS's reader finds: the same tree
            fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
            _assert_same_tree(_opencv_node(fs.getNode("imu0")), _read_yaml(out)["imu0"], "imu0")
            fs.release()
        for s, key in (("acc", acc_key), ("gyr", gyr_key)):
            want = np.diag(_jackknife(1.0 / (fa[s] * phys[s] / c[s])))  # forward scale = 1 / the file's A diagonal
            np.testing.assert_allclose(at(sd, key), want, rtol=1e-9, atol=1e-9 * want.max())
        assert np.max(np.abs(at(sd, rot_key))) < 1e-12  # identity in every fold
        code, _, err = _run(capsys, "import-model", fmt, out, "--out", tmp_path / f"{units}_back.npz")
        assert code == 0, err
    save_model(m, tmp_path / "plain.npz")
    code, _, err = _run(capsys, "export", tmp_path / "plain.npz", "--format", fmt, "--out", tmp_path / "p.yaml")
    assert code == 0 and "recorded no standard errors for them" in err, err
    assert "jaxcal_intrinsics_sd" not in _read_yaml(tmp_path / "p.yaml")["imu0"]


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


# ----------------------------------------------------------------------------- noise keys in the YAML exports

# The imu0 keys of OpenVINS's own kalibr_imu_chain.yaml, copied from rpng/open_vins
# config/rpng_sim/kalibr_imu_chain.yaml at commit 6b4abfd2c9be2cdfbaf329efcb8d8cb219c6955f (the same keys as
# config/euroc_mav/kalibr_imu_chain.yaml, which adds no others), in that file's order.
OPENVINS_IMU0_KEYS = [
    "T_i_b", "accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
    "gyroscope_random_walk", "rostopic", "time_offset", "update_rate", "model", "Tw", "R_IMUtoGYRO", "Ta",
    "R_IMUtoACC", "Tg",
]

# A Kalibr imu.yaml as Kalibr's wiki ("IMU Noise Model") and `jaxcal noise` write it: flat keys, SI units.
KALIBR_IMU_YAML = """\
#Accelerometers
accelerometer_noise_density: 1.86e-03   #Noise density (continuous-time)
accelerometer_random_walk:   4.33e-04   #Bias random walk
#Gyroscopes
gyroscope_noise_density:     1.87e-04   #Noise density (continuous-time)
gyroscope_random_walk:       2.66e-05   #Bias random walk
rostopic:                    /imu0      #the IMU ROS topic
update_rate:                 200.0      #Hz (for discretization of the values above)
"""
NOISE_VALUES = {"accelerometer_noise_density": 1.86e-03, "accelerometer_random_walk": 4.33e-04,
                "gyroscope_noise_density": 1.87e-04, "gyroscope_random_walk": 2.66e-05,
                "rostopic": "/imu0", "update_rate": 200.0}


@pytest.mark.parametrize("fmt", ["kalibr", "openvins"])
def test_noise_keys_go_into_the_yaml_exports(fmt, tmp_path, capsys):
    save_model(_model("linear"), tmp_path / "m.npz")
    (tmp_path / "imu.yaml").write_text(KALIBR_IMU_YAML)
    code, out, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--noise", tmp_path / "imu.yaml",
                          "--out", tmp_path / "x.yaml")
    assert code == 0 and out == "" and len(err.strip().splitlines()) == 2 and "--noise" not in err, err
    text = (tmp_path / "x.yaml").read_text()
    assert "Missing IMU noise keys" not in text
    imu = _read_yaml(tmp_path / "x.yaml")["imu0"]
    assert {k: imu[k] for k in NOISE_VALUES} == NOISE_VALUES
    if fmt == "openvins":
        assert [k for k in imu if not k.startswith("jaxcal_")] == OPENVINS_IMU0_KEYS  # every key, OpenVINS's order
        assert np.array_equal(np.asarray(imu["T_i_b"]), np.eye(4)) and imu["time_offset"] == 0.0
    # without --noise: the file and the stderr line name the missing keys
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--out", tmp_path / "y.yaml")
    assert code == 0 and len(err.strip().splitlines()) == 2 and "pass --noise" in err, err
    assert "# Missing IMU noise keys (Kalibr imu.yaml, SI units): accelerometer_noise_density" in (tmp_path / "y.yaml").read_text()
    imu = _read_yaml(tmp_path / "y.yaml")["imu0"]
    assert not set(NOISE_VALUES) & set(imu)
    if fmt == "openvins":
        assert set(OPENVINS_IMU0_KEYS) - set(imu) == set(NOISE_VALUES)


def _opencv_node(node):
    """A cv2.FileNode as plain Python: maps -> dict, sequences -> list, numbers -> float, strings -> str."""
    if node.isMap():
        return {k: _opencv_node(node.getNode(k)) for k in node.keys()}
    if node.isSeq():
        return [_opencv_node(node.at(i)) for i in range(node.size())]
    return node.string() if node.isString() else node.real()


@pytest.mark.parametrize("fmt", ["kalibr", "openvins"])
def test_opencv_filestorage_reads_the_yaml_exports(fmt, tmp_path, capsys):
    """OpenVINS reads its configuration with OpenCV's cv::FileStorage, which is stricter than YAML: sequences
    indented under their key, and a string like 0.1.0 quoted. The file, read by OpenCV itself, holds exactly the
    numbers a YAML reader finds."""
    cv2 = pytest.importorskip("cv2")
    save_model(_model("multipos"), tmp_path / "m.npz")
    (tmp_path / "imu.yaml").write_text(KALIBR_IMU_YAML)
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--noise", tmp_path / "imu.yaml",
                        "--out", tmp_path / "x.yaml")
    assert code == 0, err
    fs = cv2.FileStorage(str(tmp_path / "x.yaml"), cv2.FILE_STORAGE_READ)
    via_opencv = _opencv_node(fs.getNode("imu0"))
    fs.release()
    via_yaml = _read_yaml(tmp_path / "x.yaml")["imu0"]
    _assert_same_tree(via_opencv, via_yaml, "imu0")


def _assert_same_tree(got, want, where):
    """Same keys, same strings, and numbers equal exactly (shortest-repr decimals parse to the same doubles)."""
    if isinstance(want, dict):
        assert isinstance(got, dict) and got.keys() == want.keys(), where
        for k in want:
            _assert_same_tree(got[k], want[k], f"{where}.{k}")
    elif isinstance(want, str):
        assert got == want, where
    else:
        assert np.array_equal(np.asarray(got, float), np.asarray(want, float)), where


def test_noise_file_forms_and_bad_noise_files(tmp_path, capsys):
    save_model(_model("linear"), tmp_path / "m.npz")
    # OpenVINS's form: %YAML:1.0 and the keys under imu0 (rostopic optional)
    nested = "%YAML:1.0\nimu0:\n" + "".join(f"  {k}: {v}\n" for k, v in NOISE_VALUES.items() if k != "rostopic")
    (tmp_path / "chain.yaml").write_text(nested)
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", "openvins", "--noise", tmp_path / "chain.yaml",
                        "--out", tmp_path / "o.yaml")
    assert code == 0 and "chain.yaml has no rostopic" in err, err
    imu = _read_yaml(tmp_path / "o.yaml")["imu0"]
    assert imu["gyroscope_random_walk"] == 2.66e-05 and "rostopic" not in imu
    for text, needle in [
        ("accelerometer_noise_density: 1.0e-3\n", "no accelerometer_random_walk"),
        (KALIBR_IMU_YAML.replace("200.0", "0"), "update_rate must be a rate > 0"),
        (KALIBR_IMU_YAML.replace("2.66e-05", "fast"), "gyroscope_random_walk must be a finite number >= 0"),
        ("[1, 2", "not valid YAML"),
    ]:
        (tmp_path / "bad.yaml").write_text(text)
        code, out, err = _run(capsys, "export", tmp_path / "m.npz", "--format", "kalibr", "--noise",
                              tmp_path / "bad.yaml", "--out", tmp_path / "k.yaml")
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
        assert needle in err and "bad.yaml" in err and not (tmp_path / "k.yaml").exists(), err
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", "json", "--noise", tmp_path / "chain.yaml",
                        "--out", tmp_path / "x.json")
    assert code == 2 and "--noise goes with --format kalibr or openvins" in err, err


# ----------------------------------------------------------------------------- imucal CalibrationInfo

# imucal's own calibrate (imucal 2.6.0, FerrarisCalibrationInfo.calibrate: inv(R) @ inv(K) @ (raw - b), then
# the gyro with K_ga) against jaxcal apply converted to m/s^2 (x G0) and deg/s. Max |difference| over the
# largest calibrated value, measured (acc, gyr): linear 3.6e-16, 5.3e-16; multipos 1.8e-16, 3.4e-16.
IMUCAL_REL_TOL = 1e-14


def _imucal_calibrate(path, acc: np.ndarray, gyr: np.ndarray) -> tuple[np.ndarray, np.ndarray, object]:
    """Load ``path`` with imucal itself and calibrate with its own equation."""
    management = pytest.importorskip("imucal.management")
    info = management.load_calibration_info(path)
    a, g = info.calibrate(acc, gyr, acc_unit=info.from_acc_unit, gyr_unit=info.from_gyr_unit)
    return np.asarray(a), np.asarray(g), info


@pytest.mark.parametrize("method", sorted(RECORDINGS))
def test_imucal_export_is_read_by_imucal(method, tmp_path, capsys):
    pytest.importorskip("imucal")
    model, rec = _model(method), RECORDINGS[method]()
    save_model(model, tmp_path / "m.npz")
    code, out, err = _run(capsys, "export", tmp_path / "m.npz", "--format", "imucal", "--out", tmp_path / "cal.json")
    assert code == 0 and out == "" and len(err.strip().splitlines()) == 1, err
    y_a, y_g = (np.asarray(getattr(rec, s), np.float64) for s in ("acc", "gyr"))
    a, g, info = _imucal_calibrate(tmp_path / "cal.json", y_a, y_g)
    assert type(info).__name__ == "FerrarisCalibrationInfo"
    assert (info.acc_unit, info.gyr_unit) == ("m/s^2", "deg/s")
    assert (info.from_acc_unit, info.from_gyr_unit) == (model.meta["units"]["acc"], model.meta["units"]["gyr"])
    assert "inv(R_a) @ inv(K_a)" in info.comment and np.all(info.K_ga == 0.0)
    for K, R in ((info.K_a, info.R_a), (info.K_g, info.R_g)):
        assert np.all(K == np.diag(np.diag(K))) and np.all(np.diag(K) > 0)
        # Measured: row norms of R within 2.2e-16 of 1 (imucal's Ferraris normalisation, one rounding).
        np.testing.assert_allclose(np.linalg.norm(R, axis=1), 1.0, atol=1e-14)
    # the file has exactly the keys imucal itself writes (its from_dict takes no others)
    assert set(json.loads((tmp_path / "cal.json").read_text())) == set(json.loads(info.to_json()))
    ref = methods.apply(model, rec)
    assert _rel_err(a, G0 * ref["acc_cal"]) < IMUCAL_REL_TOL
    assert _rel_err(g, np.rad2deg(ref["gyr_cal"])) < IMUCAL_REL_TOL


def test_imucal_export_needs_both_sensors():
    m = _model("linear")
    acc_only = CalibrationModel("linear", ("acc",), {"acc": m.state["acc"]}, {"units": {"acc": "LSB"}})
    with pytest.raises(ModelError, match="no gyr calibration"):
        to_imucal(acc_only)
    with pytest.raises(ModelError, match="is not linear"):
        to_imucal(_fake_model("cubic"))


def test_scale_misalignment():
    worst = 0.0
    for S in _random_matrices():
        K, R = scale_misalignment(S)
        assert np.all(K == np.diag(np.diag(K))) and np.all(np.diag(K) > 0)
        np.testing.assert_allclose(np.linalg.norm(R, axis=1), 1.0, atol=1e-14)  # measured 2.2e-16
        worst = max(worst, float(np.max(np.abs(K @ R - S)) / np.max(np.abs(S))))
    assert worst < 1e-15  # measured 1.2e-16 (one rounding per entry of R)
    with pytest.raises(ModelError, match="zero or non-finite row"):
        scale_misalignment(np.diag([1.0, 0.0, 1.0]))


# ----------------------------------------------------------------------------- import-model

# export -> import-model -> apply against jaxcal apply of the original model. Max |difference| over the
# largest calibrated value, measured (acc, gyr), linear / multipos: imucal 0, 3.2e-16 / 1.1e-16, 1.5e-16;
# json 0, 3.2e-16 / 1.1e-16, 1.5e-16; kalibr 2.2e-16, 6.4e-16 / 1.1e-16, 3.0e-16; openvins 4.5e-16, 4.8e-16 /
# 1.1e-16, 4.5e-16 (a few ulp: S = inv(A) or the tools' factors multiplied back, then inverted by apply).
IMPORT_REL_TOL = 1e-14
_IMPORT_SUFFIX = {"imucal": ".json", "json": ".json", "kalibr": ".yaml", "openvins": ".yaml"}


def test_import_formats_of_the_cli_are_the_library_ones(tmp_path, capsys):
    """``import-model`` offers the registry's importers (``jaxcal.formats.importers``), and no export-only format."""
    assert IMPORT_FORMATS == ("imucal", "json", "kalibr", "openvins")
    code, _, err = _run(capsys, "import-model", "c", tmp_path / "x.h", "--out", tmp_path / "m.npz")
    assert code == 2 and "invalid choice: 'c'" in err and all(repr(f) in err for f in IMPORT_FORMATS), err


@pytest.mark.parametrize("fmt", list(IMPORT_FORMATS))
@pytest.mark.parametrize("method", sorted(RECORDINGS))
def test_export_import_model_apply_round_trip(fmt, method, tmp_path, capsys):
    model, rec = _model(method), RECORDINGS[method]()
    save_model(model, tmp_path / "m.npz")
    f = tmp_path / f"cal{_IMPORT_SUFFIX[fmt]}"
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--out", f)
    assert code == 0, err
    code, out, err = _run(capsys, "import-model", fmt, f, "--out", tmp_path / "back.npz")
    assert code == 0 and out == "" and len(err.strip().splitlines()) == 1, err
    assert "linear model from" in err and "taken as" not in err, err  # nothing assumed: the file says it all
    back = load_model(tmp_path / "back.npz")
    assert back.method == "linear" and back.sensors == ("acc", "gyr")
    assert back.meta["units"] == {s: model.meta["units"][s] for s in back.sensors}
    assert back.meta["imported_from"]["format"] == fmt and back.meta["imported_from"]["file"] == f.name
    ref, got = methods.apply(model, rec), methods.apply(back, rec)
    for k in ("acc_cal", "gyr_cal"):
        assert _rel_err(got[k], ref[k]) < IMPORT_REL_TOL, (k, _rel_err(got[k], ref[k]))


def _unit_rows(M: np.ndarray) -> np.ndarray:
    return M / np.linalg.norm(M, axis=1, keepdims=True)


def _imucal_info(units: str, K_ga: np.ndarray | None = None):
    """A FerrarisCalibrationInfo built by imucal itself with known parameters (raw counts or physical input)."""
    imucal = pytest.importorskip("imucal")
    rng = np.random.default_rng(5)
    if units == "raw":  # MPU-6050-like counts: LSB per m/s^2, LSB per deg/s
        k_a, k_g, b_a, b_g, from_units = 16384.0 / G0, 131.0, rng.normal(0, 200, 3), rng.normal(0, 30, 3), ("a.u.",) * 2
    else:  # an IMU already in physical units, a few % off
        k_a, k_g, b_a, b_g, from_units = 1.0, 1.0, rng.normal(0, 0.1, 3), rng.normal(0, 0.5, 3), ("m/s^2", "deg/s")
    return imucal.FerrarisCalibrationInfo(
        K_a=np.diag(k_a * (1 + rng.normal(0, 0.02, 3))), R_a=_unit_rows(np.eye(3) + rng.normal(0, 0.02, (3, 3))),
        b_a=b_a, K_g=np.diag(k_g * (1 + rng.normal(0, 0.02, 3))),
        R_g=_unit_rows(np.eye(3) + rng.normal(0, 0.02, (3, 3))),
        K_ga=np.zeros((3, 3)) if K_ga is None else K_ga, b_g=b_g,
        from_acc_unit=from_units[0], from_gyr_unit=from_units[1], comment="made by imucal in a jaxcal test",
    )


# imucal's calibrate on the imucal-made file against jaxcal apply of the imported model, in m/s^2 and deg/s.
# Measured max |difference| over the largest calibrated value (acc, gyr): raw 1.9e-16, 3.7e-16; physical
# 3.9e-16, 2.9e-16.
@pytest.mark.parametrize("units", ["raw", "physical"])
def test_import_model_of_a_file_written_by_imucal(units, tmp_path, capsys):
    info = _imucal_info(units)
    info.to_json_file(tmp_path / "imucal.json")
    code, out, err = _run(capsys, "import-model", "imucal", tmp_path / "imucal.json", "--out", tmp_path / "m.npz")
    assert code == 0 and out == "" and len(err.strip().splitlines()) == 1, err
    model = load_model(tmp_path / "m.npz")
    rng = np.random.default_rng(6)
    n = 500
    if units == "raw":
        assert "from_acc_unit 'a.u.' taken as raw numbers" in err and model.meta["units"] == {"acc": "LSB", "gyr": "LSB"}
        acc, gyr = rng.normal(0, 16384.0, (n, 3)), rng.normal(0, 3000.0, (n, 3))
        acc_in, gyr_in = acc, gyr
    else:  # jaxcal records physical input in g and rad/s; imucal's file says m/s^2 and deg/s
        assert "taken as" not in err and model.meta["units"] == {"acc": "g", "gyr": "rad/s"}
        acc, gyr = rng.normal(0, 1.0, (n, 3)), rng.normal(0, 2.0, (n, 3))
        acc_in, gyr_in = acc * G0, np.rad2deg(gyr)
    rec = Recording(t=np.arange(n) / 100.0, acc=acc, gyr=gyr, acc_unit=model.meta["units"]["acc"],
                    gyr_unit=model.meta["units"]["gyr"])
    a, g, _ = _imucal_calibrate(tmp_path / "imucal.json", acc_in, gyr_in)
    got = methods.apply(model, rec)
    assert _rel_err(G0 * got["acc_cal"], a) < IMPORT_REL_TOL
    assert _rel_err(np.rad2deg(got["gyr_cal"]), g) < IMPORT_REL_TOL


# imucal's own calibrate (with K_ga) on an imucal-made file with a g-sensitivity, against jaxcal apply of the
# imported model (state/gyr/G). Measured max |difference| over the largest calibrated value: acc 2.2e-16, gyr 5.0e-16.
def test_import_model_reads_g_sensitivity_or_drops_it(tmp_path, capsys):
    K_ga = np.full((3, 3), 0.01)
    K_ga[0, 1] = -0.02
    _imucal_info("raw", K_ga).to_json_file(tmp_path / "kga.json")
    code, out, err = _run(capsys, "import-model", "imucal", tmp_path / "kga.json", "--out", tmp_path / "m.npz")
    assert code == 0 and out == "" and len(err.strip().splitlines()) == 1, err
    assert "with the gyroscope g-sensitivity (state/gyr/G)" in err, err
    model = load_model(tmp_path / "m.npz")
    assert model.method == "linear" and model.state["gyr"]["G"].shape == (3, 3)
    rng = np.random.default_rng(8)
    acc, gyr = rng.normal(0, 16384.0, (300, 3)), rng.normal(0, 3000.0, (300, 3))
    a, g, _ = _imucal_calibrate(tmp_path / "kga.json", acc, gyr)
    got = methods.apply(model, Recording(t=np.arange(300) / 100.0, acc=acc, gyr=gyr, acc_unit="LSB", gyr_unit="LSB"))
    assert _rel_err(G0 * got["acc_cal"], a) < IMPORT_REL_TOL
    assert _rel_err(np.rad2deg(got["gyr_cal"]), g) < IMPORT_REL_TOL, _rel_err(np.rad2deg(got["gyr_cal"]), g)
    code, _, err = _run(capsys, "import-model", "imucal", tmp_path / "kga.json", "--out", tmp_path / "d.npz",
                        "--drop-g-sensitivity")
    assert code == 0 and "dropped the gyroscope g-sensitivity K_ga (max |K_ga| = 0.02)" in err, err
    dropped = load_model(tmp_path / "d.npz")
    assert dropped.meta["imported_from"]["notes"][-1].startswith("dropped") and "G" not in dropped.state["gyr"]
    # Kalibr's A and OpenVINS's Tg: read into G, or dropped
    m = _model("linear")
    k = json.loads(json.dumps(to_kalibr(m)))
    k["imu0"]["gyroscopes"]["A"][0][1] = 1e-4
    o = json.loads(json.dumps(to_openvins(m)))
    o["imu0"]["Tg"][2][0] = 1e-4
    for fmt, doc, name in (("kalibr", k, "A"), ("openvins", o, "Tg")):
        imp = import_model(fmt, doc)
        assert imp.notes == () and np.any(imp.model.state["gyr"]["G"])
        dropped = import_model(fmt, doc, drop_g_sensitivity=True)
        assert dropped.notes[0].startswith(f"dropped the gyroscope g-sensitivity {name}") and "G" not in dropped.model.state["gyr"]


# ----------------------------------------------------------------------------- gyro g-sensitivity (state/gyr/G)

# A multipos model with a known g-sensitivity G ((rad/s)/g, entries ~0.3 (deg/s)/g) put into its state: every
# export writes G in its format's term, read back with that format's own equation (numpy; imucal itself)
# and through import-model, it gives jaxcal apply's output. Measured max |difference| over the largest
# calibrated value (acc, gyr), 300 samples over rests and moves: json 1.8e-16, 1.5e-16; kalibr 1.8e-16, 6.0e-16;
# openvins 1.8e-16, 6.0e-16; imucal 1.8e-16, 3.0e-16; after import-model at most 1.1e-16, 6.0e-16.
@functools.cache
def _gsens_model() -> CalibrationModel:
    m = _model("multipos")
    G = np.radians(np.random.default_rng(4).normal(0, 0.3, (3, 3)))
    state = {"acc": dict(m.state["acc"]), "gyr": {**m.state["gyr"], "G": G}}
    return CalibrationModel("multipos", m.sensors, state, m.meta)


@pytest.mark.parametrize("fmt", ["json", "kalibr", "openvins", "imucal"])
def test_g_sensitivity_export_round_trips(fmt, tmp_path, capsys):
    model, rec = _gsens_model(), _multipos()
    G = model.state["gyr"]["G"]
    save_model(model, tmp_path / "m.npz")
    f = tmp_path / f"cal{_IMPORT_SUFFIX[fmt]}"
    code, _, err = _run(capsys, "export", tmp_path / "m.npz", "--format", fmt, "--out", f)
    assert code == 0, err
    sel = np.arange(0, rec.n, rec.n // 300)[:300]  # rests and moves
    y_a, y_g = (np.asarray(getattr(rec, s), np.float64)[sel] for s in ("acc", "gyr"))
    if fmt in ("kalibr", "openvins"):  # their files take a ROS driver's input (the conversion they state)
        y_a, y_g = _driver_input(_read_yaml(f)["imu0"], y_a, y_g)
    ref = methods.apply(model, rec)
    ref_a, ref_w = G0 * ref["acc_cal"][sel], ref["gyr_cal"][sel]
    # the G term is not negligible: measured max |G f| 0.64 % of the largest calibrated rate (a wrong sign,
    # frame or unit in an export would miss by ~1e-2, far above the tolerance)
    assert np.max(np.abs(ref["acc_cal"][sel] @ G.T)) > 1e-3 * np.max(np.abs(ref_w))
    if fmt == "json":
        d = json.loads(f.read_text())
        assert d["equation_gyr"] == "x_gyr = A_gyr @ (y_gyr - b_gyr) - G @ x_acc" and d["sensors"]["gyr"]["G_unit"] == "(rad/s)/g"
        p_a, p_g = d["sensors"]["acc"], d["sensors"]["gyr"]
        x_a = np.stack([np.asarray(p_a["A"]) @ (y - np.asarray(p_a["b"])) for y in y_a])
        x_g = np.stack([np.asarray(p_g["A"]) @ (y - np.asarray(p_g["b"])) - np.asarray(p_g["G"]) @ xa for y, xa in zip(y_g, x_a)])
        a, w = G0 * x_a, x_g
    elif fmt == "kalibr":
        imu = _read_yaml(f)["imu0"]
        assert np.any(np.asarray(imu["gyroscopes"]["A"]))
        a, w = _kalibr_apply(imu, y_a, y_g)
    elif fmt == "openvins":
        imu = _read_yaml(f)["imu0"]
        assert np.any(np.asarray(imu["Tg"]))
        a, w = _openvins_apply(imu, y_a, y_g)
    else:
        a, g, info = _imucal_calibrate(f, y_a, y_g)
        assert np.any(info.K_ga)
        w = np.deg2rad(g)
    assert _rel_err(a, ref_a) < YAML_REL_TOL, _rel_err(a, ref_a)
    assert _rel_err(w, ref_w) < YAML_REL_TOL, _rel_err(w, ref_w)
    code, _, err = _run(capsys, "import-model", fmt, f, "--out", tmp_path / "back.npz")
    assert code == 0 and "with the gyroscope g-sensitivity" in err, err
    back = load_model(tmp_path / "back.npz")
    got = methods.apply(back, rec)
    for k in ("acc_cal", "gyr_cal"):
        assert _rel_err(got[k], ref[k]) < IMPORT_REL_TOL, (k, _rel_err(got[k], ref[k]))
    # Measured |G_back - G| <= 5.2e-18 (rad/s)/g (a few ulp of S^{-1} S; G ~ 5e-3)
    np.testing.assert_allclose(back.state["gyr"]["G"], G, rtol=0, atol=1e-15)


C_MAIN_GSENS = r"""
#include <stdio.h>
#include "cal.h"

/* usage: prog FILE (raw float64 samples, 6 per row: acc then gyr); prints the calibrated gyro per row */
int main(int argc, char **argv)
{
    double y[6], a[3], x[3];
    FILE *f;
    if (argc != 2) return 2;
    f = fopen(argv[1], "rb");
    if (!f) return 3;
    while (fread(y, sizeof(double), 6, f) == 6) {
        jaxcal_cal_apply_acc(y, a);
        jaxcal_cal_apply_gyr(y + 3, a, x);
        printf("%.17g %.17g %.17g\n", x[0], x[1], x[2]);
    }
    fclose(f);
    return 0;
}
"""


# Measured: the compiled gyro output within 1.5e-16 of jaxcal apply's largest value (at most 1 ulp).
@pytest.mark.skipif(shutil.which("gcc") is None, reason="no gcc on this machine to compile the exported C header")
def test_c_header_with_g_sensitivity_compiles_and_matches(tmp_path):
    model, rec = _gsens_model(), _multipos()
    (tmp_path / "cal.h").write_text(to_c_header(model))
    assert "jaxcal_cal_apply_gyr(const double y[3], const double acc_cal[3], double x[3])" in (tmp_path / "cal.h").read_text()
    (tmp_path / "main.c").write_text(C_MAIN_GSENS)
    exe = tmp_path / "calib"
    cc = subprocess.run(["gcc", "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(exe),
                         str(tmp_path / "main.c")], capture_output=True, text=True, cwd=tmp_path)
    assert cc.returncode == 0, cc.stderr
    raw = tmp_path / "y.bin"
    np.ascontiguousarray(np.hstack([rec.acc, rec.gyr]), dtype="<f8").tofile(raw)
    res = subprocess.run([str(exe), str(raw)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    x = np.loadtxt(res.stdout.splitlines(), dtype=np.float64)
    assert _rel_err(x, methods.apply(model, rec)["gyr_cal"]) < REL_TOL


def _edited(doc: dict, path: tuple, value) -> dict:
    doc = json.loads(json.dumps(doc))
    d = doc
    for key in path[:-1]:
        d = d[key]
    if value is None:
        del d[path[-1]]
    else:
        d[path[-1]] = value
    return doc


def test_import_model_refuses_what_a_linear_model_cannot_hold():
    m = _model("linear")
    k, o, j, i = to_kalibr(m), to_openvins(m), to_json(m), to_imucal(m)
    T = np.eye(4)
    T[0, 3] = 0.05
    upper = np.tril(np.asarray(o["imu0"]["Tw"])) + np.triu(np.ones((3, 3)), 1) * 1e-3
    cases = [
        ("kalibr", _edited(k, ("imu0", "model"), "calibrated"), "is not 'scale-misalignment'"),
        ("kalibr", _edited(k, ("imu0", "T_i_b"), T.tolist()), "T_i_b has a translation"),
        ("kalibr", _edited(k, ("imu0", "accelerometers", "M"), [[1.0, 0.0], [0.0, 1.0]]), "has shape (2, 2)"),
        ("kalibr", {"imu1": {}}, "no 'imu0' mapping"),
        ("openvins", _edited(o, ("imu0", "model"), "rpng"), "is not 'kalibr' or 'calibrated'"),
        ("openvins", _edited(o, ("imu0", "Tw"), upper.tolist()), "Tw is not lower triangular"),
        ("openvins", _edited(o, ("imu0", "Ta"), None), "no Ta"),
        ("json", _edited(j, ("format",), "other/1"), "is not 'jaxcal-linear-calibration/1'"),
        ("json", _edited(j, ("sensors", "acc", "output_unit"), "m/s^2"), "output_unit 'm/s^2' is not 'g'"),
        ("json", _edited(j, ("sensors", "gyr", "A"), [[0.0] * 3] * 3), "singular"),
        ("imucal", _edited(i, ("cal_type",), "Custom"), "cal_type 'Custom' is not one jaxcal reads"),
        ("imucal", _edited(i, ("_format_version",), "1.0.0"), "_format_version '1.0.0' is not 2.0.0"),
        ("imucal", _edited(i, ("gyr_unit",), "rpm"), "gyr_unit 'rpm' is not one jaxcal converts"),
        ("imucal", _edited(i, ("b_a",), [1.0, "x", 2.0]), "b_a is not a 3 array of numbers"),
        ("imucal", _edited(i, ("R_g",), None), "no R_g"),
    ]
    for fmt, doc, needle in cases:
        with pytest.raises(ModelError) as e:
            import_model(fmt, doc)
        assert needle in str(e.value) and "\n" not in str(e.value), (fmt, needle, str(e.value))


def test_import_model_notes_what_a_foreign_yaml_lacks():
    """A Kalibr/OpenVINS file without jaxcal's keys: bias 0 and raw input, said in the notes."""
    m = _model("linear")
    doc = json.loads(json.dumps(to_openvins(m, units="model")))
    for key in ("jaxcal_b_a", "jaxcal_b_g", "jaxcal_input_unit_acc", "jaxcal_input_unit_gyr"):
        del doc["imu0"][key]
    imp = import_model("openvins", doc)
    assert imp.model.meta["units"] == {"acc": "LSB", "gyr": "LSB"}
    assert any("no jaxcal_b_a" in n for n in imp.notes) and any("input unit None taken as raw" in n for n in imp.notes)
    assert np.all(imp.model.state["acc"]["b"] == 0.0)
    # the matrices are still the exported ones: forward S_a equals jaxcal's to float precision
    S = np.asarray(m.state["acc"]["S"], np.float64)
    assert _rel_err(imp.model.state["acc"]["S"], S) < 1e-14  # measured 4.4e-16


def test_cli_import_model_bad_input(tmp_path, capsys):
    (tmp_path / "x.json").write_text("{not json")
    code, out, err = _run(capsys, "import-model", "json", tmp_path / "x.json", "--out", tmp_path / "m.npz")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1 and "not valid JSON" in err, err
    code, _, err = _run(capsys, "import-model", "yaml", tmp_path / "x.json", "--out", tmp_path / "m.npz")
    assert code == 2 and "invalid choice: 'yaml'" in err, err
    code, _, err = _run(capsys, "import-model", "json", tmp_path / "x.json", "--out", tmp_path / "m.h5")
    assert code == 2 and "model files are .npz" in err, err
    code, _, err = _run(capsys, "import-model", "json", tmp_path / "nope.json", "--out", tmp_path / "m.npz")
    assert code == 2 and "cannot read" in err, err
    assert not (tmp_path / "m.npz").exists()
