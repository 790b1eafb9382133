"""The contract every outside format keeps, run over ``formats.REGISTRY`` (as
``test_methods_contract.py`` runs over ``methods.REGISTRY``: the parameter lists are built from the
registry, so a newly registered format is run through it without touching this file).

* A reader (``jaxcal.read``): a file written here from known arrays, in the format's own layout and
  units, reads back as those arrays (exactly where no unit changes, else to float64 rounding); a
  missing file and a wrong number of files are refused with one :class:`ReaderError`. Every reader
  needs a writer in :data:`WRITERS` (a new one fails until it has one). Its ``jaxcal import`` flags
  (``Format.flags``) cover its ``own_options`` and ``needs``, and an option several readers take
  has one flag.
* An export (``jaxcal export``): a linear model, with and without a gyro g-sensitivity, is written;
  where the format imports (``jaxcal import-model``), reading it back gives a model that calibrates
  a recording as the original does (to float64 rounding), with the g-sensitivity kept or dropped as
  asked; a non-linear model is refused. An export-only format must be named in :data:`EXPORT_ONLY`
  with where its output is checked.
* The Kalibr ``imu.yaml`` noise keys (:mod:`jaxcal.formats.noise_yaml`) round-trip through both files
  ``jaxcal noise`` writes and into both YAML exports.

:func:`test_a_new_format_needs_only_a_module_and_a_registry_line` registers ``tests/toy_format.py``
(a reader and an export format in one module) and runs the same contract on it, and through the CLI
(its reader option's flag included).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest
import toy_format

import jaxcal
from jaxcal import formats, methods
from jaxcal.cli import main
from jaxcal.constants import G0
from jaxcal.formats.noise_yaml import (
    kalibr_imu_yaml,
    kalibr_yaml_text,
    missing_noise_keys,
    openvins_imu_chain,
    openvins_yaml_text,
    read_noise_yaml,
)
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.recording import Recording, load_recording, save_recording

N, FS = 40, 100.0
_RNG = np.random.default_rng(11)
ACC_G = np.array([0.0, 0.0, 1.0]) + 0.02 * _RNG.normal(size=(N, 3))  # specific force, g
GYR = 0.3 * _RNG.normal(size=(N, 3))  # rad/s
ACC_C = _RNG.integers(-2000, 2000, (N, 3)) + np.array([0, 0, 16384])  # counts
GYR_C = _RNG.integers(-500, 500, (N, 3))
NS = 1_520_530_308_181_901_700 + 10_000_000 * np.arange(N, dtype=np.int64)  # ns stamps, 100 Hz
DEG = 180.0 / math.pi


class Written(NamedTuple):
    """A file (or files) written in a reader's format and what reading it must give."""

    files: list[Path]
    options: dict[str, Any]
    expect: dict[str, np.ndarray]  # Recording field -> value
    units: tuple[str, str]  # acc_unit, gyr_unit


def _text(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _rows(*cols: np.ndarray) -> str:
    """CSV rows of the columns, each number as its shortest round-trip ``repr`` (integers stay integers)."""
    cols2 = [c[:, None] if c.ndim == 1 else c for c in cols]
    return "".join(",".join(repr(c[i, j].item()) for c in cols2 for j in range(c.shape[1])) + "\n" for i in range(N))


def _imu_tk(d: Path) -> Written:
    t = np.arange(N) / FS
    files = [_text(d / f"{s}.txt", "".join(f"{float(ti)!r} {x} {y} {z}\n" for ti, (x, y, z) in zip(t, c)))
             for s, c in (("acc", ACC_C), ("gyr", GYR_C))]
    return Written(files, {}, {"t": t, "acc": ACC_C, "gyr": GYR_C}, ("LSB", "LSB"))


def _imucal(d: Path) -> Written:
    f = _text(d / "session.csv", "n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n"
              + _rows(np.arange(N), GYR * DEG, ACC_G * G0))
    return Written([f], {"fs": FS, "acc_unit": "m/s^2", "gyr_unit": "deg/s"},
                   {"t": np.arange(N) / FS, "acc": ACC_G, "gyr": GYR}, ("g", "rad/s"))


def _euroc(d: Path) -> Written:
    f = _text(d / "data.csv", "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n" + _rows(NS, GYR, ACC_G * G0))
    return Written([f], {}, {"t": (NS - NS[0]) * 1e-9, "acc": ACC_G, "gyr": GYR}, ("g", "rad/s"))


def _tumvi(d: Path) -> Written:
    names = "Time," + ",".join(f"angular_velocity.{a}" for a in "xyz") + "," + ",".join(f"linear_acceleration.{a}" for a in "xyz")
    t = 1520530308.0 + np.arange(N) / FS
    f = _text(d / "imu.csv", names + "\n" + _rows(t, GYR, ACC_G * G0))
    return Written([f], {}, {"t": t - t[0], "acc": ACC_G, "gyr": GYR}, ("g", "rad/s"))


def _mpu6050(d: Path) -> Written:
    f = _text(d / "log.csv", f"Fs,{FS}\nax,ay,az,gx,gy,gz\n" + _rows(ACC_C, GYR_C))
    return Written([f], {}, {"t": np.arange(N) / FS, "acc": ACC_C, "gyr": GYR_C}, ("LSB", "LSB"))


def _fusion(d: Path) -> Written:
    head = ("Time (s)," + ",".join(f"Gyroscope {a} (deg/s)" for a in "XYZ") + ","
            + ",".join(f"Accelerometer {a} (g)" for a in "XYZ"))
    f = _text(d / "sensor_data.csv", head + "\n" + _rows(np.arange(N) / FS, GYR * DEG, ACC_G))
    return Written([f], {}, {"t": np.arange(N) / FS, "acc": ACC_G, "gyr": GYR}, ("g", "rad/s"))


def _broad(d: Path) -> Written:
    import scipy.io

    q = np.tile([1.0, 0.0, 0.0, 0.0], (N, 1))
    f = d / "01_trial.mat"
    scipy.io.savemat(f, {"imu_acc": ACC_G * G0, "imu_gyr": GYR, "opt_quat": q, "opt_pos": np.zeros((N, 3)),
                         "sampling_rate": FS})
    return Written([f], {}, {"t": np.arange(N) / FS, "acc": ACC_G, "gyr": GYR, "quat_ref": q}, ("g", "rad/s"))


def _csv(d: Path) -> Written:
    """jaxcal's own recording CSV (:func:`save_recording`) read by the generic reader."""
    rec = Recording(t=np.arange(N) / FS, acc=ACC_G, gyr=GYR, acc_unit="g", gyr_unit="rad/s")
    save_recording(rec, d / "rec.csv")
    cols = {"t": "t", **{f"{s}_{a}": f"{s}_{a}" for s in ("acc", "gyr") for a in "xyz"}}
    return Written([d / "rec.csv"], {"columns": cols, "units": {"t": "s", "acc": "g", "gyr": "rad/s"}},
                   {"t": rec.t, "acc": ACC_G, "gyr": GYR}, ("g", "rad/s"))


def _rosbag(d: Path) -> Written:
    pytest.importorskip("rosbags")
    import test_rosbag as tr

    ts = tr._typestore("ros1")
    msgs = [(int(s), tr.imu_msg(ts, int(s), a, g)) for s, a, g in zip(NS, ACC_G * G0, GYR)]
    bag = tr.write_bag(d / "b", "ros1", {"/imu0": ("sensor_msgs/msg/Imu", msgs)})
    return Written([bag], {"imu_topic": "/imu0"}, {"t": (NS - NS[0]) / 1e9, "acc": ACC_G * G0 / G0, "gyr": GYR},
                   ("g", "rad/s"))


def _toy(d: Path) -> Written:
    rec = Recording(t=np.arange(N) / FS, acc=ACC_G, gyr=GYR, acc_unit="g", gyr_unit="rad/s")
    f = _text(d / "rec.toy", toy_format.recording_text(rec))
    return Written([f], {}, {"t": rec.t, "acc": ACC_G, "gyr": GYR}, ("g", "rad/s"))


WRITERS: dict[str, Callable[[Path], Written]] = {
    "imu_tk": _imu_tk, "imucal": _imucal, "euroc": _euroc, "tumvi": _tumvi, "mpu6050": _mpu6050,
    "fusion": _fusion, "broad": _broad, "csv": _csv, "rosbag": _rosbag, "toy": _toy,
}
"""Per reader: a file written here from the known arrays, in its own layout and units."""

EXPORT_ONLY = {"c": "compiled with gcc and run against `jaxcal apply` in tests/test_export.py"}
"""Export formats without an import, and where their output is checked instead."""

G_NEVER_DROPPED = {"json"}
"""Imports that keep a g-sensitivity even when asked to drop it (jaxcal's own JSON: ``G`` is jaxcal's term)."""


def check_read(fmt: str, tmp_path: Path) -> None:
    """Known arrays written in ``fmt`` read back as themselves; bad paths refused with one ReaderError."""
    assert fmt in WRITERS, f"reader {fmt!r} has no writer in WRITERS: add one (a file from known arrays)"
    w = WRITERS[fmt](tmp_path)
    rec = jaxcal.read(fmt, w.files, **w.options)
    assert isinstance(rec, Recording) and rec.n == N
    assert (rec.acc_unit, rec.gyr_unit) == w.units
    for k, v in w.expect.items():
        got = np.asarray(getattr(rec, k))
        if np.asarray(v).dtype.kind in "iu":  # raw counts: exact, kept as integers
            assert got.dtype.kind in "iu", (k, got.dtype)
            np.testing.assert_array_equal(got, v)
        else:  # a unit conversion (m/s^2 -> g, deg/s -> rad/s, ns -> s) is one or two roundings
            np.testing.assert_allclose(got, v, rtol=1e-13, atol=1e-15, err_msg=k)
    f = formats.get(fmt)
    missing = tmp_path / "missing.file"
    with pytest.raises(formats.ReaderError, match="no such file"):
        jaxcal.read(fmt, [missing, *w.files[1:]], **w.options)
    lo, hi = f.files
    if hi < 10:
        with pytest.raises(formats.ReaderError, match=f"takes {lo}..{hi} files"):
            jaxcal.read(fmt, [w.files[0]] * (hi + 1), **w.options)


@pytest.mark.parametrize("fmt", formats.readers())
def test_reader_contract(fmt, tmp_path):
    check_read(fmt, tmp_path)


def test_reader_flags_are_declared_once():
    """Every reader's CLI flags: an option several readers take has one flag (``SHARED_FLAGS``), no two
    options share a flag, and the options the CLI refuses elsewhere or needs have flags."""
    seen: dict[str, Any] = {}
    for f in formats.REGISTRY.values():
        declared = dict(f.flags or {})
        assert f.read is not None or not declared, f"{f.name}: flags without a reader"
        missing = (set(f.own_options) | set(f.needs or {})) - set(declared)
        assert not missing, f"{f.name}: own_options / needs without a flag: {sorted(missing)}"
        for opt, spec in declared.items():
            assert spec.flag.startswith("--") and spec.help, (f.name, opt)
            assert seen.setdefault(opt, spec) == spec, f"{f.name}: {opt} declared twice: use formats.base.SHARED_FLAGS"
    by_flag = [spec.flag for spec in seen.values()]
    assert len(by_flag) == len(set(by_flag)), by_flag


def _linear(gsens: bool) -> CalibrationModel:
    rng = np.random.default_rng(2)
    state = {"acc": {"S": 16384.0 * (np.eye(3) + 0.02 * rng.normal(size=(3, 3))), "b": rng.normal(0, 50, 3)},
             "gyr": {"S": 7505.7 * (np.eye(3) + 0.02 * rng.normal(size=(3, 3))), "b": rng.normal(0, 20, 3)}}
    if gsens:
        state["gyr"]["G"] = 2e-3 * rng.normal(size=(3, 3))
    return CalibrationModel("linear", ("acc", "gyr"), state, {"units": {"acc": "LSB", "gyr": "LSB"}})


def _counts() -> Recording:
    return Recording(t=np.arange(N) / FS, acc=ACC_C.astype(np.int32), gyr=GYR_C.astype(np.int32))


def check_export(fmt: str) -> None:
    """Export -> import gives a model that calibrates as the original (to float64 rounding)."""
    f = formats.get(fmt)
    assert f.suffix.startswith(".")
    for gsens in (False, True):
        model = _linear(gsens)
        out = formats.export(fmt, model)
        assert isinstance(out.text, str) and out.text.endswith("\n")
        if f.import_model is None:
            assert fmt in EXPORT_ONLY, f"export {fmt!r} has no import: add it to EXPORT_ONLY, saying where it is checked"
            continue
        want = methods.apply(model, _counts())
        for drop in (False, True):
            imp = formats.import_model(fmt, formats.read_document(fmt, out.text), drop)
            assert imp.model.method == "linear" and imp.model.sensors == ("acc", "gyr")
            has_g = "G" in imp.model.state["gyr"]
            assert has_g == (gsens and not (drop and fmt not in G_NEVER_DROPPED))
            got = methods.apply(imp.model, _counts())
            if gsens and not has_g:  # dropped as asked: the gyroscope as without G, and a note says so
                assert any("dropped" in n for n in imp.notes)
                got["gyr_cal"] = got["gyr_cal"] - want["acc_cal"] @ model.state["gyr"]["G"].T
            for k in want:
                # measured, max |diff| / max |value|: imucal 9.7e-17, json 3.9e-16, kalibr 5.1e-16, openvins 4.1e-16
                np.testing.assert_allclose(got[k], want[k], rtol=1e-12, atol=1e-12 * np.max(np.abs(want[k])))
    with pytest.raises(ModelError, match="not linear"):
        formats.export(fmt, CalibrationModel("cubic", ("acc", "gyr"), {}, {}))


@pytest.mark.parametrize("fmt", formats.exporters())
def test_export_contract(fmt):
    check_export(fmt)


def test_unknown_formats_are_refused_by_name(tmp_path):
    with pytest.raises(formats.ReaderError, match="unknown format 'nope'"):
        jaxcal.read("nope", [])
    with pytest.raises(ModelError, match="unknown export format 'nope'"):
        formats.export("nope", _linear(False))
    with pytest.raises(ModelError, match="unknown import format 'c'"):
        formats.read_document("c", "")
    with pytest.raises(formats.ReaderError, match="needs imu_topic="):
        jaxcal.read("rosbag", [tmp_path])


def test_noise_yaml_round_trips_through_both_files_and_both_exports():
    """``jaxcal noise``'s imu.yaml and openvins_noise.yaml read back (``export --noise``) as the numbers
    written, largest over the axes; with them a YAML export lacks no noise key."""
    from jaxcal.allan import NoiseParams

    def params(n: float, k: float) -> NoiseParams:
        a = np.array([1.0, 3.0, 2.0])
        return NoiseParams(n * a, n * a, n * a, a, a, a, k * a, k * a, k * a, a, a, a, 0.95)

    pa, pg = params(2.1e-3, 3.3e-4), params(1.7e-4, 2.2e-6)
    want = {"accelerometer_noise_density": 6.3e-3, "accelerometer_random_walk": 9.9e-4, "gyroscope_noise_density": 5.1e-4,
            "gyroscope_random_walk": 6.6e-6, "rostopic": "/imu0", "update_rate": 200.0}
    texts = (kalibr_yaml_text(kalibr_imu_yaml(pa, pg, 200.0, "/imu0")), openvins_yaml_text(openvins_imu_chain(pa, pg, 200.0, "/imu0")))
    for text in texts:
        got = read_noise_yaml(text)
        assert got.keys() == want.keys() and got["rostopic"] == "/imu0"
        for k in want:
            if k != "rostopic":
                assert got[k] == pytest.approx(want[k], rel=1e-15)
        for fmt in ("kalibr", "openvins"):
            out = formats.export(fmt, _linear(False), formats.ExportOptions(noise=got))
            assert out.missing_noise == () and not missing_noise_keys(formats.read_document(fmt, out.text))
    assert formats.export("kalibr", _linear(False)).missing_noise == tuple(want)
    with pytest.raises(ValueError, match="no gyroscope_random_walk"):
        read_noise_yaml("accelerometer_noise_density: 1\naccelerometer_random_walk: 1\ngyroscope_noise_density: 1\nupdate_rate: 1\n")


def test_noise_yaml_one_digit_values_read_back():
    """A one-digit value (repr '6e-06', which YAML 1.1 reads as a string) is written '6.0e-06' and read back
    by PyYAML (Kalibr's reader) as the float written; an exact yaml.safe_load of each written value agrees."""
    import yaml

    from jaxcal.allan import NoiseParams
    from jaxcal.formats.noise_yaml import yaml_float

    a = np.ones(3)
    p = NoiseParams(6e-6 * a, a, a, a, a, a, 6e-6 * a, a, a, a, a, a, 0.95)
    text = kalibr_yaml_text(kalibr_imu_yaml(p, p, 200.0, "/imu0"))
    assert "gyroscope_random_walk: 6.0e-06" in text
    got = read_noise_yaml(text)
    assert got["gyroscope_random_walk"] == 6e-6 and got["accelerometer_noise_density"] == 6e-6
    for v in (6e-6, 1e-300, 5e-324, 1e22, 2.5e-7, 0.0, 200.0, 1.7e-4):
        assert yaml.safe_load(f"k: {yaml_float(v)}")["k"] == v


def test_a_new_format_needs_only_a_module_and_a_registry_line(tmp_path, capsys):
    """``tests/toy_format.py`` is a reader and an export format in one module; one line registers
    it; then it passes both contracts and works from the command line."""
    formats.register(toy_format.FORMAT)  # the one registry line
    try:
        assert "toy" in formats.readers() and "toy" in formats.exporters() and "toy" in formats.importers()
        check_read("toy", tmp_path)
        check_export("toy")
        w = _toy(tmp_path)
        out = tmp_path / "rec.npz"
        assert main(["import", "toy", str(w.files[0]), "--out", str(out)]) == 0
        np.testing.assert_array_equal(load_recording(out).gyr, GYR)
        # its reader option, declared in FORMAT.flags alone, reaches its reader from the command line
        assert main(["import", "toy", str(w.files[0]), "--toy-time-scale", "2", "--out", str(tmp_path / "t2.npz")]) == 0
        np.testing.assert_allclose(load_recording(tmp_path / "t2.npz").t, 2 * load_recording(out).t, rtol=1e-15)
        capsys.readouterr()
        assert main(["import", "euroc", str(w.files[0]), "--toy-time-scale", "2", "--out", str(tmp_path / "e.npz")]) == 2
        assert "format 'euroc' does not take --toy-time-scale" in capsys.readouterr().err
        assert main(["import", "toy", str(w.files[0]), "--fs", "100", "--out", str(tmp_path / "f.npz")]) == 2
        assert "format 'toy' does not take --fs" in capsys.readouterr().err
        from jaxcal.model_file import save_model

        save_model(_linear(False), tmp_path / "m.npz")
        assert main(["export", str(tmp_path / "m.npz"), "--format", "toy", "--out", str(tmp_path / "m.toy")]) == 0
        assert main(["import-model", "toy", str(tmp_path / "m.toy"), "--out", str(tmp_path / "back.npz")]) == 0
        assert main(["export", str(tmp_path / "m.npz"), "--format", "toy", "--out", str(tmp_path / "m.json")]) == 2
        assert "written as .toy" in capsys.readouterr().err
    finally:
        formats.REGISTRY.pop("toy")
    assert "toy" not in formats.names()
