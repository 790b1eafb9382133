"""Issue 27: refuse what the data contradict (exit 2, one line, nothing written, nothing earlier touched).

The reference gate of ``align`` / ``diagnose`` is tested on a real rig (BROAD 07, 20 s) made
hostile in the ways the issue names (random or frozen quaternions, mocap 5 s late, millimetres
labelled metres, quaternions xyzw read as wxyz, a pose track covering 2 s), and the real rigs
(BROAD 07 and 21, TUM-VI room1) must pass it. Every refusal comes before any fit, so the file runs
in seconds.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import labelled_poses, linear_model_file, run_cli

from jaxcal.diagnose import prepare
from jaxcal.diagnose.gate import GATE, check_reference, reference_gate, report_gate
from jaxcal.recording import load_recording

DATA = Path(__file__).resolve().parent.parent / "data"
BROAD07 = DATA / "broad_07_undisturbed_fast_rotation_B" / "07_undisturbed_fast_rotation_B.npz"
BROAD21 = DATA / "broad_21_undisturbed_fast_combined" / "21_undisturbed_fast_combined.npz"
TUMVI = DATA / "tumvi_room1_512_16" / "room1.npz"
needs_data = pytest.mark.skipif(not BROAD07.exists(), reason="data not present")


run = run_cli


def refused(capsys, argv: list, *, absent: tuple = (), untouched: tuple = (), needles: tuple = ()) -> str:
    """Exit 2, one stderr line holding every needle, no traceback, ``absent`` paths absent,
    ``untouched`` files byte-identical, no ``.partial`` left beside them."""
    before = {Path(p): Path(p).read_bytes() for p in untouched}
    got, out, err = run(capsys, *argv)
    lines = [ln for ln in err.split("\n") if ln.strip()]
    assert got == 2, (got, err)
    assert len(lines) == 1 and "Traceback" not in err and out == "", err
    for p in map(Path, absent):
        assert not p.exists(), p
    for p, b in before.items():
        assert p.read_bytes() == b, p
    for d in {Path(p).parent for p in (*absent, *untouched)}:
        assert not [q for q in d.iterdir() if ".partial" in q.name], "temporary output left behind"
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


# ----------------------------------------------------------------------------- hostile references


def _crop(seconds: float = 20.0, start: float = 20.0) -> dict[str, np.ndarray]:
    with np.load(BROAD07) as z:
        d = {k: z[k] for k in z.files if k not in ("mag", "movement", "meta_info")}
    t = d["t"]
    keep = (t >= t[0] + start) & (t < t[0] + start + seconds)
    return {k: (v[keep] if v.ndim >= 1 and len(v) == len(t) else v) for k, v in d.items()}


def hostile(name: str, d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The issue's contradicting references, made from a real rig's recording."""
    n = len(d["t"])
    fs = 1.0 / float(np.median(np.diff(d["t"])))
    if name == "ok":
        return d
    if name == "random quaternions":
        q = np.random.default_rng(0).normal(size=(n, 4))
        return d | {"quat_ref": q / np.linalg.norm(q, axis=1, keepdims=True)}
    if name == "constant pose":
        return d | {"quat_ref": np.tile(d["quat_ref"][n // 2], (n, 1)), "pos_ref": np.tile(d["pos_ref"][n // 2], (n, 1))}
    if name == "mocap 5 s late":
        k = int(round(5.0 * fs))
        return d | {f: np.concatenate([np.repeat(d[f][:1], k, 0), d[f][:-k]]) for f in ("pos_ref", "quat_ref")}
    if name == "millimetres labelled metres":
        return d | {"pos_ref": d["pos_ref"] * 1000.0}
    if name == "xyzw read as wxyz":
        return d | {"quat_ref": d["quat_ref"][:, [1, 2, 3, 0]]}
    if name == "world-to-body quaternions":
        return d | {"quat_ref": d["quat_ref"] * [1.0, -1.0, -1.0, -1.0]}
    if name == "centimetres labelled metres":
        return d | {"pos_ref": d["pos_ref"] * 100.0}
    if name == "gyro channel stuck near zero":
        return d | {"gyr": 0.01 * np.random.default_rng(1).normal(size=(n, 3))}
    if name == "pose covers 2 s of 20 s":
        rv = np.zeros(n, bool)
        rv[n // 3: n // 3 + int(2 * fs)] = True
        return d | {"ref_valid": rv, "pos_ref": np.where(rv[:, None], d["pos_ref"], np.nan),
                    "quat_ref": np.where(rv[:, None], d["quat_ref"], np.nan)}
    raise KeyError(name)


HOSTILE = {  # the cause each refusal must name
    "random quaternions": "quaternion order",
    "constant pose": "frozen or constant pose",
    "mocap 5 s late": "reference 5.0 s late",
    "millimetres labelled metres": "positions are in millimetres",
    "xyzw read as wxyz": "stored scalar last",
    "world-to-body quaternions": "world to body (conjugated)",
    "centimetres labelled metres": "positions are in centimetres",
    "gyro channel stuck near zero": "gyroscope barely moves while the reference does",
    "pose covers 2 s of 20 s": "pose track that stops early",
}


@pytest.fixture(scope="module")
def rigs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("rigs")
    if BROAD07.exists():
        base = _crop()
        for name in ("ok", *HOSTILE):
            np.savez(d / (name.replace(" ", "_") + ".npz"), **hostile(name, base))
    return d


@needs_data
@pytest.mark.parametrize("name", list(HOSTILE))
def test_gate_names_the_contradiction(name, rigs):
    """Library: the gate's figures separate the real rig from each contradicting reference."""
    ok = reference_gate(prepare(load_recording(rigs / "ok.npz")))
    assert not ok.problems and ok.sensors["gyr"].ratio < 0.15 and ok.sensors["acc"].ratio < 0.3, ok
    rec = load_recording(rigs / (name.replace(" ", "_") + ".npz"))
    g = reference_gate(prepare(rec))
    assert g.problems, g.sensors
    with pytest.raises(ValueError, match=re.escape(HOSTILE[name])):
        check_reference(rec)
    if name in ("millimetres labelled metres", "centimetres labelled metres"):  # the gyro still fits; the acc sees 1/1000 (1/100)
        assert g.sensors["gyr"].ratio < 0.15 and max(g.sensors["acc"].scales) < 0.05, g.sensors
    elif name in ("xyzw read as wxyz", "world-to-body quaternions"):  # on this stretch the rates half fit, scales far from 1
        sv = g.sensors["gyr"].scales
        assert g.sensors["gyr"].ratio > 0.15 and (min(sv) < 0.6 or max(sv) > 1.2), g.sensors
    elif name != "pose covers 2 s of 20 s":
        assert g.sensors["gyr"].ratio > 0.9, g.sensors  # the residual is the size of the signal
    if name == "mocap 5 s late":
        assert "-5.00 s" in g.problems[0]


@needs_data
@pytest.mark.parametrize("cmd", ["align", "diagnose", "diagnose --model-out"])
@pytest.mark.parametrize("name", list(HOSTILE))
def test_cli_refuses_a_contradicting_reference(name, cmd, rigs, tmp_path, capsys):
    """``align`` and ``diagnose`` (``--model-out`` too) exit 2 before any fit: no report folder,
    no model, an earlier model untouched."""
    rec = rigs / (name.replace(" ", "_") + ".npz")
    out, model = tmp_path / "out", tmp_path / "m.npz"
    argv = [cmd.split()[0], rec, "--out", out]
    untouched: tuple = ()
    if "--model-out" in cmd:
        model.write_bytes(b"earlier model")
        argv += ["--model-out", model]
        untouched = (model,)
    refused(capsys, argv, absent=(out,), untouched=untouched, needles=(rec.name, HOSTILE[name]))


@needs_data
@pytest.mark.parametrize("path", [BROAD07, BROAD21, TUMVI], ids=["broad07", "broad21", "tumvi"])
def test_real_rigs_pass_the_gate(path):
    """Measured: gyro ratios 0.074 / 0.032 / 0.038, acc 0.17 / 0.04 / 0.10, scales within 1 %
    (gyro) and 9 % (acc) of 1; the contradicting references above give 0.7-1.03."""
    g = reference_gate(prepare(load_recording(path)))
    assert not g.problems, g.problems
    assert g.sensors["gyr"].ratio < 0.15 and g.sensors["acc"].ratio < 0.3, g.sensors
    assert all(abs(s - 1) < 0.03 for s in g.sensors["gyr"].scales), g.sensors
    assert abs(g.sensors["gyr"].lag_s) < 0.1


def test_gate_does_not_judge_a_rig_at_rest():
    """Neither sensor nor reference moves: nothing to judge by, so no refusal (the diagnosis reports
    what it can); the same rest with a moving sensor is a frozen reference."""
    from jaxcal.recording import recording_from_dict

    n = 2000
    rng = np.random.default_rng(0)
    rest = {"t": np.arange(n) / 100.0, "acc": np.array([0.0, 0.0, 1.0]) + 1e-3 * rng.normal(size=(n, 3)),
            "gyr": 2e-3 * rng.normal(size=(n, 3)), "acc_unit": "g", "gyr_unit": "rad/s",
            "pos_ref": np.zeros((n, 3)), "quat_ref": np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))}
    assert reference_gate(prepare(recording_from_dict(rest))).problems == []
    moving = rest | {"gyr": np.c_[np.sin(np.arange(n) / 20.0), np.zeros((n, 2))]}
    g = reference_gate(prepare(recording_from_dict(moving)))
    assert g.problems and "frozen or constant pose" in g.problems[0]


def test_gate_judges_jittery_mocap_in_its_trusted_band():
    """100 Hz motion capture with 4 ms time-stamp jitter on TUM-VI's hand-held rig: differentiated
    with the 20 ms kernel, the reference acceleration is mostly noise and the fitted accelerometer
    scales fall to about 0.5 (errors in variables; the stressed TUM-VI rigs of
    results/discrepancy.md were all refused this way, though align met its goals on each).
    ``check_reference`` judges it again in the band where it keeps its gain and lets it through,
    with scales within 2 % of 1 (measured 0.99-1.00)."""
    from jaxcal.diagnose.stress import decimate_reference
    from jaxcal.recording import take_rows

    rec = load_recording(TUMVI)
    rec = take_rows(rec, np.asarray(rec.t) < rec.t[0] + 30.0)
    jittery = decimate_reference(rec, np.random.default_rng(1), 100.0, 0.004, 0.02, (0.02, 0.3))
    narrow = reference_gate(prepare(jittery))
    assert narrow.problems and "accelerometer scales" in narrow.problems[0]
    assert min(narrow.sensors["acc"].scales) < 0.7
    g = check_reference(jittery)
    assert g.problems == []
    np.testing.assert_allclose(g.sensors["acc"].scales, 1.0, atol=0.02)
    np.testing.assert_allclose(g.sensors["gyr"].scales, 1.0, atol=0.02)


def test_gate_fits_the_accelerometers_lever_arm():
    """The reference point 5 cm from the IMU on BROAD 07's fast rotation (20 s): without the lever
    arm's terms the affine fit leaves a held-out ratio of 0.56 and scales 0.02-1.32, a refusal of a
    rig ``align`` is built to align. The gate fits ``y = A x + M(t) r + b`` (``M`` from the sensor's
    own gyroscope): measured ratio 0.14, scales 0.84-1.00. (Measured limit: 11 cm on the same
    20 s still leaves scales 0.65-0.76, refused; on the whole stressed 184 s trial 11 cm passes.)"""
    from jaxcal.diagnose.stress import move_reference_point
    from jaxcal.recording import recording_from_dict

    moved = move_reference_point(recording_from_dict(_crop()), np.array([0.05, 0.0, 0.0]))
    g = reference_gate(prepare(moved))
    assert g.problems == [], g.problems
    assert g.sensors["acc"].ratio < 0.2
    assert 0.8 < min(g.sensors["acc"].scales) and max(g.sensors["acc"].scales) < 1.05


def test_report_gate_ranges():
    """After the fit: |tau| <= 2 s, |r| <= 1 m, finite figures, final residual small against the signal."""
    good = {"baseline": {"gyr": {"rms": 0.3, "heldout_rms": 0.3}}, "final": {"gyr": {"rms": 0.01, "heldout_rms": 0.011}},
            "effects": [{"name": "time_offset", "sensor": "gyr", "params": {"tau": 0.004}},
                        {"name": "lever_arm", "sensor": "acc", "params": {"r": [0.01, 0.0, 0.02]}}]}
    assert report_gate(good, align={"tau": 0.004, "r": [0.01, 0.0, 0.02], "rotation_deg": 0.1}) == []
    bad = report_gate(good, align={"tau": 5.0, "r": [-10.3, 23.8, 154.2], "rotation_deg": float("nan")})
    assert any("beyond 2 s" in b for b in bad) and any("lever arm 156" in b and "millimetres" in b for b in bad)
    assert any("rotation_deg" in b for b in bad)
    nan = good | {"final": {"gyr": {"rms": float("nan"), "heldout_rms": 0.01}}}
    assert any("fit failed" in b for b in report_gate(nan))
    assert GATE.max_lag_s == 2.0 and GATE.max_lever_m == 1.0  # CONVENTIONS.md's plausible ranges
    # the baseline's scales: a gyro scale of 0.0006 (random quaternions) multiplied the gyro by 2000 on apply
    assert report_gate(good, scales={"gyr": np.array([1.01, 0.99, 1.0])}) == []
    bad = report_gate(good, scales={"gyr": np.array([0.0006, 0.001, 0.002])})
    assert len(bad) == 1 and "gyroscope scales are 0.0006" in bad[0]


def test_report_gate_align_consistency():
    """One clock: gyro and acc time offsets 1.4 ms apart (BROAD 21 as recorded) pass; 43 ms apart at
    3 ms standard errors (stressed BROAD 21, align locked on a 170-deg rotation) is refused, and so is
    its 2.9 rad/s gyro bias. A split beyond 20 ms but within 5 standard errors passes (uninformative)."""
    good = {"effects": []}

    def align(tg, ta, se, bias=(0.001, -0.002, 0.0005)):
        return {"tau": tg, "rotation_deg": 170.0, "bias_gyr_rads": list(bias),
                "tau_per_sensor": {"gyr": {"tau": tg, "stderr": se}, "acc": {"tau": ta, "stderr": se}}}

    assert report_gate(good, align=align(4.12e-3, 2.74e-3, 3e-5)) == []
    bad = report_gate(good, align=align(-56.5e-3, -99.6e-3, 3e-3))
    assert len(bad) == 1 and "43.1 ms apart" in bad[0] and "one clock cannot" in bad[0]
    assert report_gate(good, align=align(-56.5e-3, -99.6e-3, 10e-3)) == []
    bad = report_gate(good, align=align(0.0, 0.0, 1e-4, bias=(2.9, 0.1, -0.2)))
    assert len(bad) == 1 and "gyroscope bias found is 2.91 rad/s" in bad[0] and "170 deg" in bad[0]
    assert report_gate(good, align=align(0.0, 0.0, 1e-4, bias=(0.3, 0.1, -0.2))) == []  # an MPU-6050 within its 20 deg/s


# ----------------------------------------------------------------------------- --model-out order


@needs_data
def test_model_out_refused_before_the_diagnosis(rigs, tmp_path, capsys):
    """A missing or read-only folder, or the ``--out`` path itself: refused at once (no report folder)."""
    rec, out = rigs / "ok.npz", tmp_path / "out"
    refused(capsys, ["diagnose", rec, "--out", out, "--model-out", tmp_path / "nope" / "m.npz"],
            absent=(out,), needles=("--model-out", "does not exist"))
    refused(capsys, ["diagnose", rec, "--out", tmp_path / "x.npz", "--model-out", tmp_path / "x.npz"],
            absent=(tmp_path / "x.npz",), needles=("--model-out", "--out folder"))
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(stat.S_IRUSR | stat.S_IXUSR)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("running as root: a read-only folder is writable")
        refused(capsys, ["diagnose", rec, "--out", out, "--model-out", ro / "m.npz"],
                absent=(out,), needles=("--model-out", "not writable"))
    finally:
        ro.chmod(stat.S_IRWXU)


# ----------------------------------------------------------------------------- noise


def _rest(n: int = 3000, lsb_noise: float | None = 3.0, seed: int = 0) -> dict[str, np.ndarray]:
    """A level IMU at rest in integer counts (100 Hz) with ``lsb_noise`` counts of white noise
    (None: every sample identical, a stuck sensor)."""
    rng = np.random.default_rng(seed)
    acc, gyr = np.tile([0.0, 0.0, 16384.0], (n, 1)), np.tile([3.0, -2.0, 1.0], (n, 1))
    if lsb_noise is not None:
        acc, gyr = np.round(acc + lsb_noise * rng.standard_normal((n, 3))), np.round(gyr + lsb_noise * rng.standard_normal((n, 3)))
    return dict(t=np.arange(n) / 100.0, acc=acc, gyr=gyr, acc_lsb_per_g=np.asarray(16384.0),
                gyr_lsb_per_rads=np.asarray(7505.747), fs=np.asarray(100.0))


@pytest.mark.parametrize("stretch", [[], ["--start", "0", "--end", "29"]], ids=["auto", "explicit"])
@pytest.mark.parametrize("case,needle", [("stuck", "never changes"), ("sub-LSB", "below the quantisation floor")])
def test_noise_refuses_a_stuck_or_unresolved_sensor(case, needle, stretch, tmp_path, capsys):
    """A stuck sensor wrote densities of 2e-27 into imu.yaml; noise below one count is not resolved."""
    np.savez(tmp_path / "r.npz", **_rest(lsb_noise=None if case == "stuck" else 0.2))
    if case == "sub-LSB" and not stretch:
        stretch = ["--start", "0", "--end", "29"]  # the detector finds no rest in the flicker; ask for it
    refused(capsys, ["noise", tmp_path / "r.npz", "--out", tmp_path / "o", *stretch], absent=(tmp_path / "o",), needles=(needle,))


def test_noise_above_the_floor_is_written(tmp_path, capsys):
    """Three counts of noise: accepted; the density is the simulated one (3 LSB / sqrt(100 Hz))."""
    import yaml

    np.savez(tmp_path / "r.npz", **_rest(lsb_noise=3.0))
    code, _, err = run(capsys, "noise", tmp_path / "r.npz", "--out", tmp_path / "o", "--start", "0", "--end", "29", "--quiet")
    assert code == 0, err
    y = yaml.safe_load((tmp_path / "o" / "imu.yaml").read_text())
    want = 3.0 / 7505.747 / np.sqrt(100.0)
    assert 0.8 * want < y["gyroscope_noise_density"] < 1.3 * want, y


def test_noise_density_against_the_stretch_spread():
    """A density whose white noise alone would spread the samples 3 x wider than they are is refused."""
    from jaxcal.noise import implausible_noise, sensor_noise

    x = 1e-3 * np.random.default_rng(0).normal(size=(3000, 3))
    nz = sensor_noise(x, 100.0)
    assert implausible_noise("gyr", x, nz, 100.0, "rad/s") is None
    assert 0.8e-4 < float(nz.params.N[0]) < 1.2e-4  # 1e-3 rad/s at 100 Hz: N = 1e-4 rad/s/sqrt(Hz)
    big = nz._replace(params=nz.params._replace(N=np.full(3, 1e-3)))
    why = implausible_noise("gyr", x, big, 100.0, "rad/s")
    assert why is not None and "over 3 x the stretch's own" in why


# ----------------------------------------------------------------------------- output folders


def test_output_folders_get_the_usual_mode(tmp_path, capsys):
    """``--out DIR`` was made 0700 (mkdtemp's mode): others on a shared machine could not read it.
    Through a command that writes a folder (a tiny ``simulate dataset2``)."""
    old = os.umask(0o022)
    try:
        code, _, err = run(capsys, "simulate", "dataset2", "--out", tmp_path / "o", "--n-train", "1", "--n-val", "1")
    finally:
        os.umask(old)
    assert code == 0, err
    assert stat.S_IMODE((tmp_path / "o").stat().st_mode) == 0o755
    assert (tmp_path / "o" / "truth.json").is_file()


# ----------------------------------------------------------------------------- imports: YAML, shapes, rotations


_linear_model_file = linear_model_file


def _exported(fmt: str, tmp_path: Path) -> dict:
    from jaxcal.export import to_kalibr, to_openvins
    from jaxcal.model_file import load_model

    m = load_model(_linear_model_file(tmp_path / "m.npz"))
    return (to_kalibr if fmt == "kalibr" else to_openvins)(m)


BOMB = "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
    f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(8))


def test_safe_yaml_refuses_an_alias_bomb_without_expanding_it():
    from jaxcal.safe_yaml import YamlLimitError, load_yaml

    assert load_yaml("x: &x [1, 2]\ny: *x\n") == {"x": [1, 2], "y": [1, 2]}  # small aliases still load
    with pytest.raises(YamlLimitError, match="alias bomb"):
        load_yaml(BOMB)  # 9^9 = 3.9e8 values if expanded
    with pytest.raises(YamlLimitError, match="deeper"):
        load_yaml("[" * 100 + "]" * 100)
    with pytest.raises(YamlLimitError, match="characters"):
        load_yaml("x: 1\n" * 300_000)


def test_export_noise_alias_bomb_refused(tmp_path, capsys):
    """``export --noise`` grew to 8 GB on ten lines of nested aliases."""
    model = _linear_model_file(tmp_path / "m.npz")
    (tmp_path / "bomb.yaml").write_text(BOMB)
    refused(capsys, ["export", model, "--format", "kalibr", "--noise", tmp_path / "bomb.yaml", "--out", tmp_path / "o.yaml"],
            absent=(tmp_path / "o.yaml",), needles=("--noise", "alias bomb"))


def test_import_model_alias_bomb_and_huge_matrix_refused(tmp_path, capsys):
    """``import-model kalibr`` built a 2.9 GiB array before its shape check."""
    import yaml

    (tmp_path / "bomb.yaml").write_text(BOMB)
    refused(capsys, ["import-model", "kalibr", tmp_path / "bomb.yaml", "--out", tmp_path / "o.npz"],
            absent=(tmp_path / "o.npz",), needles=("alias bomb",))
    d = _exported("kalibr", tmp_path)
    d["imu0"]["gyroscopes"]["M"] = [[1.0] * 3] * 20_000  # a 20000 x 3 "matrix"
    (tmp_path / "big.yaml").write_text(yaml.safe_dump(d))
    refused(capsys, ["import-model", "kalibr", tmp_path / "big.yaml", "--out", tmp_path / "o.npz"],
            absent=(tmp_path / "o.npz",), needles=("gyroscopes", "M has shape (20000, 3), expected (3, 3)"))


ROT_CASES = {
    "kalibr C_gyro_i twice a rotation": ("kalibr", ("gyroscopes", "C_gyro_i"), lambda R: 2.0 * R, "not orthonormal"),
    "kalibr T_i_b determinant -1": ("kalibr", ("T_i_b",), lambda T: np.diag([1.0, 1.0, -1.0, 1.0]) @ T, "reflection"),
    "openvins R_IMUtoACC scaled 1.5": ("openvins", ("R_IMUtoACC",), lambda R: 1.5 * R, "not orthonormal"),
    "openvins R_IMUtoGYRO reflected": ("openvins", ("R_IMUtoGYRO",), lambda R: -R, "reflection"),
}


@pytest.mark.parametrize("name", list(ROT_CASES))
def test_import_rotations_must_be_rotations(name, tmp_path, capsys):
    """Each format defines these as rotations: a scaled one changed the sensor's scale, a reflection
    made a left-handed frame. The unedited file imports (exit 0)."""
    import yaml

    fmt, keys, edit, needle = ROT_CASES[name]
    d = _exported(fmt, tmp_path)
    (tmp_path / "good.yaml").write_text(yaml.safe_dump(d))
    code, _, err = run(capsys, "import-model", fmt, tmp_path / "good.yaml", "--out", tmp_path / "good.npz")
    assert code == 0, err
    node = d["imu0"]
    for k in keys[:-1]:
        node = node[k]
    node[keys[-1]] = edit(np.asarray(node[keys[-1]], float)).tolist()
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(d))
    refused(capsys, ["import-model", fmt, tmp_path / "bad.yaml", "--out", tmp_path / "o.npz"],
            absent=(tmp_path / "o.npz",), needles=(keys[-1], "must be a rotation", needle))


def test_imucal_example_with_version_2_0_is_accepted(tmp_path, capsys):
    """imucal's own example calibration says "2.0" (imucal loads it); it was refused for not being "2.0.0"."""
    from jaxcal.model_file import load_model

    src = DATA / "imucal_ferraris_example" / "example_cal.json"
    code, _, err = run(capsys, "import-model", "imucal", src, "--out", tmp_path / "m.npz")
    assert code == 0, err
    m = load_model(tmp_path / "m.npz")
    assert m.method == "linear" and set(m.sensors) == {"acc", "gyr"}
    (tmp_path / "v1.json").write_text(src.read_text().replace('"2.0"', '"1.0"'))
    refused(capsys, ["import-model", "imucal", tmp_path / "v1.json", "--out", tmp_path / "o.npz"],
            absent=(tmp_path / "o.npz",), needles=("_format_version",))


# ----------------------------------------------------------------------------- apply: inside the model's range


def _biased_poses(n: int, max_tilt_deg: float | None, seed: int) -> dict[str, np.ndarray]:
    return labelled_poses(n, max_tilt_deg, seed, bias=(30.0, -20.0, 10.0))


def test_apply_refuses_a_cubic_model_outside_its_input_range(tmp_path, capsys):
    """Fitted within 18 deg of z-up, applied over the sphere: refused (it was off by 1281 g); with
    --allow-extrapolation it runs with a warning; on its own range it runs silently."""
    np.savez(tmp_path / "cap.npz", **_biased_poses(400, 18.0, 0))
    np.savez(tmp_path / "sphere.npz", **_biased_poses(400, None, 1))
    np.savez(tmp_path / "cap2.npz", **_biased_poses(400, 15.0, 2))
    assert run(capsys, "calibrate", "--method", "cubic", tmp_path / "cap.npz", "--out", tmp_path / "m.npz", "-q")[0] == 0
    (tmp_path / "o.npz").write_bytes(b"earlier")
    refused(capsys, ["apply", tmp_path / "m.npz", tmp_path / "sphere.npz", "--out", tmp_path / "o.npz"],
            untouched=(tmp_path / "o.npz",), needles=("outside the cubic model's fitted input range", "--allow-extrapolation"))
    code, _, err = run(capsys, "apply", tmp_path / "m.npz", tmp_path / "sphere.npz", "--out", tmp_path / "o.npz", "-q",
                       "--allow-extrapolation")
    assert code == 0 and "warning" in err and "outside" in err, err
    code, _, err = run(capsys, "apply", tmp_path / "m.npz", tmp_path / "cap2.npz", "--out", tmp_path / "o2.npz", "-q")
    assert code == 0 and err == "", err
    with np.load(tmp_path / "o2.npz") as z:  # inside its range the model is right (mg level)
        assert np.max(np.abs(z["acc_cal"] - _biased_poses(400, 15.0, 2)["acc_ref"])) < 0.01


def _diagnosed_model(path: Path, **acc: Any) -> Path:
    from jaxcal.methods import CalibrationModel
    from jaxcal.model_file import save_model

    state = {"acc": {"S": 16384.0 * np.eye(3), "b": np.zeros(3), **acc}}
    meta = {"baseline": "diag", "effects": {"acc": [k for k in acc if k != "T0"]}, "not_carried": [], "notes": [],
            "units": {"acc": "LSB"}, "temperature_range_degC": {"acc": [20.0, 35.0]}}
    save_model(CalibrationModel("diagnosed", ("acc",), state, meta), path)
    return path


@pytest.mark.parametrize("case", ["Kelvin as degC", "time offset longer than the recording"])
def test_apply_refuses_a_diagnosed_model_outside_its_range(case, tmp_path, capsys):
    d = _biased_poses(400, None, 3)
    if case == "Kelvin as degC":
        m = _diagnosed_model(tmp_path / "m.npz", temperature_bias=np.full(3, 1e-4), T0=np.asarray(27.0))
        d["temp"] = np.full(400, 27.0 + 273.15)
        needle = "Kelvin read as degC"
    else:
        m = _diagnosed_model(tmp_path / "m.npz", time_offset=np.asarray(10.0))
        needle = "time offset 10 s"
    np.savez(tmp_path / "r.npz", **d)
    refused(capsys, ["apply", m, tmp_path / "r.npz", "--out", tmp_path / "o.npz"], absent=(tmp_path / "o.npz",), needles=(needle,))
    if case == "Kelvin as degC":  # in degC it is applied
        np.savez(tmp_path / "r2.npz", **(d | {"temp": np.full(400, 27.0)}))
        code, _, err = run(capsys, "apply", m, tmp_path / "r2.npz", "--out", tmp_path / "o.npz", "-q")
        assert code == 0, err


# ----------------------------------------------------------------------------- sweep


SWEEP_CASES = {  # spec, needle; each refused before any expansion or compilation
    "random.n = 1e9": ({"random": {"n": 10**9, "params": {"acc_lr": [1e-4, 1e-2, "log"]}}}, "1e+09 runs"),
    "40^6 grid": ({"grid": {k: [0.1 + 0.001 * i for i in range(40)] for k in
                            ("acc_lr", "gyr_lr", "init_lr", "w", "init_epochs", "gyr_steps")}}, "4.1e+09 runs"),
    "dataset fs 0": ({"dataset": {"fs": 0}}, "dataset.fs = 0 must be > 0"),
    "dataset fs in the grid 0": ({"grid": {"dataset.fs": [100.0, 0.0]}}, "dataset.fs = 0.0 must be > 0"),
    "heatmap a string": ({"grid": {"w": [0.5, 0.9]}, "heatmap": "w"}, "heatmap: expected a list"),
    "heatmap a number": ({"grid": {"w": [0.5, 0.9]}, "heatmap": 3}, "heatmap: expected a list"),
}


@pytest.mark.parametrize("name", list(SWEEP_CASES))
def test_sweep_spec_refused_before_expansion(name, tmp_path, capsys):
    import json

    spec, needle = SWEEP_CASES[name]
    if name == "40^6 grid":  # integer-valued names need integers
        spec["grid"]["init_epochs"] = spec["grid"]["gyr_steps"] = list(range(40))
        spec["grid"]["w"] = [i / 40 for i in range(40)]
    (tmp_path / "s.json").write_text(json.dumps(spec))
    refused(capsys, ["sweep", tmp_path / "s.json", "--out", tmp_path / "out"], absent=(tmp_path / "out",),
            needles=(str(tmp_path / "s.json"), needle))


def test_sweep_unwritable_out_refused(tmp_path, capsys):
    import json

    (tmp_path / "s.json").write_text(json.dumps({"grid": {"w": [0.5]}}))
    (tmp_path / "file").write_text("x")
    refused(capsys, ["sweep", tmp_path / "s.json", "--out", tmp_path / "file" / "sub"], untouched=(tmp_path / "file",),
            needles=("--out", "is not a directory"))



# ----------------------------------------------------------------------------- the contract as a property

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

PROP = settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _contract(capsys, argv: list, out: Path, earlier: bytes | None) -> int:
    """Exit 0 or 2 only; exit 2: one line, ``out`` absent or holding exactly the earlier bytes, no partial file."""
    code, stdout, err = run(capsys, *argv)
    assert code in (0, 2) and "Traceback" not in err, (code, err)
    if code == 2:
        assert len([ln for ln in err.splitlines() if ln.strip()]) == 1, err
        assert (out.read_bytes() == earlier) if earlier is not None else not out.exists()
        assert not [q for q in out.parent.iterdir() if ".partial" in q.name]
    return code


@PROP
@given(fmt=st.sampled_from(["kalibr", "openvins"]), scale=st.sampled_from([1.0, 1.0 + 1e-9, 1.0 + 1e-4, 1.5, -1.0, 0.0]),
       key=st.sampled_from(["C_gyro_i", "T_i_b", "R_IMUtoACC", "R_IMUtoGYRO"]), earlier=st.booleans())
def test_property_imported_rotations(fmt, scale, key, earlier, tmp_path_factory, capsys):
    """exit 0 => every rotation the file defines is one (so the imported scales are the file's M / T);
    exit 2 => nothing written, an earlier model untouched."""
    import yaml

    from jaxcal.model_file import load_model

    d_ = tmp_path_factory.mktemp("prop")
    doc = _exported(fmt, d_)
    imu = doc["imu0"]
    node, k = {"C_gyro_i": (imu.get("gyroscopes"), "C_gyro_i"), "T_i_b": (imu, "T_i_b")}.get(key, (imu, key))
    if node is not None and k in node:
        M = np.asarray(node[k], float)
        M[:3, :3] *= scale
        node[k] = M.tolist()
    (d_ / "f.yaml").write_text(yaml.safe_dump(doc))
    out = d_ / "o.npz"
    if earlier:
        out.write_bytes(b"earlier")
    code = _contract(capsys, ["import-model", fmt, d_ / "f.yaml", "--out", out], out, b"earlier" if earlier else None)
    read = {"kalibr": ("C_gyro_i", "T_i_b"), "openvins": ("R_IMUtoACC", "R_IMUtoGYRO")}[fmt]  # OpenVINS ignores T_i_b
    is_rotation = abs(scale - 1.0) <= 1e-7 or key not in read
    assert (code == 0) == is_rotation, (fmt, key, scale, code)
    if code == 0:
        m = load_model(out)
        for s in ("acc", "gyr"):  # the imported scales are those of the exported model (to 1e-6)
            sv = np.linalg.svd(np.asarray(m.state[s]["S"]), compute_uv=False)
            assert np.all(np.abs(sv / sv.mean() - 1) < 0.05), sv


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(noise=st.sampled_from([0.0, 0.05, 0.3, 1.0, 4.0]), offset=st.floats(-100, 100), earlier=st.booleans())
def test_property_noise(noise, offset, earlier, tmp_path_factory, capsys):
    """exit 0 => every density written is finite, positive and above the quantisation floor;
    exit 2 => nothing written, an earlier folder untouched."""
    import yaml

    d_ = tmp_path_factory.mktemp("propn")
    rec = _rest(lsb_noise=noise if noise > 0 else None, seed=int(abs(offset)))
    rec["gyr"] = rec["gyr"] + np.round(offset)
    np.savez(d_ / "r.npz", **rec)
    out = d_ / "o"
    if earlier:
        out.mkdir()
        (out / "keep.txt").write_text("earlier")
    code, _, err = run(capsys, "noise", d_ / "r.npz", "--out", out, "--start", "0", "--end", "29", "--quiet")
    assert code in (0, 2) and "Traceback" not in err, err
    if code == 2:
        assert len(err.strip().splitlines()) == 1
        assert (sorted(p.name for p in out.iterdir()) == ["keep.txt"]) if earlier else not out.exists()
        assert noise < 1.0, err  # a resolved sensor is never refused
        return
    y = yaml.safe_load((out / "imu.yaml").read_text())
    floor_g = (1.0 / 7505.747) / np.sqrt(12 * 100.0)
    assert np.isfinite(y["gyroscope_noise_density"]) and y["gyroscope_noise_density"] >= floor_g, (noise, y)
    assert y["accelerometer_noise_density"] >= (9.80665 / 16384.0) / np.sqrt(12 * 100.0), (noise, y)


def test_sweep_lock_and_a_sweep_whose_every_run_diverges(tmp_path, capsys):
    """Two concurrent sweeps into one folder overwrote each other: the second is refused while the
    first's process lives; a lock left by a killed sweep (its process gone) is taken over. That run
    (learning rates that diverge: every run NaN) exits 2, not 0: no table, no checkpoint, no folder,
    the lock released.

    The diverging sweep runs the toy target of ``tests/toy_sweep_target.py`` (the exit-2 path is the
    shared sweep command's, whatever the target): gradient descent with ``lr`` 0.9 and 1.0 on
    curvature 4 multiplies the error by -2.6 and -3 per step, so 500 float32 steps overflow to inf
    and then NaN in both metrics. (Before: online-thesis with learning rates of 1e30, 12.9 s of
    compiles on the 2-core machine for the same exit-2 path.)"""
    import json

    import toy_sweep_target

    from jaxcal.cli.sweep import sweep_lock, sweep_lock_path
    from jaxcal.sweep import targets

    (tmp_path / "s.json").write_text(json.dumps({"target": "toy-gd", "grid": {"lr": [0.9, 1.0]}, "fixed": {"steps": 500}}))
    out = tmp_path / "out"
    f = sweep_lock_path(out)
    targets.register(toy_sweep_target.TARGET)
    try:
        with sweep_lock(out):  # this process holds it; a second writer must be refused: fake one with our parent's pid
            assert f.read_text() == str(os.getpid())
            f.write_text(str(os.getppid()))  # a live process that is not us
            refused(capsys, ["sweep", tmp_path / "s.json", "--out", out, "--quiet"], absent=(out,),
                    needles=("another sweep", "process"))
            f.write_text(str(os.getpid()))
        assert not f.exists()
        f.write_text("999999999")  # a process that does not exist: stale, taken over (the run then fails on its NaNs)
        refused(capsys, ["sweep", tmp_path / "s.json", "--out", out, "--quiet"], absent=(out,),
                needles=("every one of the 2 runs gave non-finite results",))
        assert not f.exists()
    finally:
        del targets.TARGETS["toy-gd"]


def test_sweep_results_published_together(tmp_path, monkeypatch):
    """A failure while the heatmap is drawn leaves the earlier sweep.json / sweep.md whole (they were
    replaced with new files and the heatmap dropped)."""
    from matplotlib.figure import Figure

    from jaxcal import sweep as sw

    spec = sw.SweepSpec(grid={"w": [0.5, 0.9], "acc_lr": [1e-3, 2e-3]})
    rows = [{"group": "g", "w": w, "acc_lr": a, "seed": 0, **{k: 1.0 for k, _ in sw.TARGETS["online-thesis"].metrics}}
            for w in (0.5, 0.9) for a in (1e-3, 2e-3)]
    res = sw.SweepResult(spec, ("w", "acc_lr"), rows, {"total_s": 1.0})
    written = sw.write_sweep(tmp_path, res)
    assert [p.name for p in written] == ["sweep.json", "sweep.md", "sweep_heatmap.png"]
    before = {p.name: p.read_bytes() for p in written}

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(Figure, "savefig", boom)  # interrupted while the heatmap is saved
    rows2 = [r | {"test_gyr_mrads": 2.0} for r in rows]
    with pytest.raises(KeyboardInterrupt):
        sw.write_sweep(tmp_path, res._replace(rows=rows2))
    assert {p.name: p.read_bytes() for p in written} == before
    assert not [p for p in tmp_path.iterdir() if ".partial" in p.name]
