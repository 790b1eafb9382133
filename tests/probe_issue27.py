"""A probe of hostile but well-formed inputs across the commands (issue 27), with a table of outcomes.

Not a test (pytest does not collect it): ``python tests/probe_issue27.py [OUT.md]`` runs every case
through ``jaxcal.cli.main`` in-process and classifies it: ``refused`` (exit 2, one line, nothing
left, an earlier output untouched), ``accepted`` (exit 0 where the input is valid), or a failure:
``traceback``, ``silent`` (exit 0 where the input contradicts itself), ``false refusal``,
``left behind`` (exit 2 with output or a partial file left, or an earlier output changed).
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))  # this checkout's jaxcal, not an installed one
DATA = HERE.parent / "data"

from helpers import labelled_poses, linear_model_file  # noqa: E402

from jaxcal.cli import main  # noqa: E402

Case = tuple[str, str, bool, Callable[[Path], tuple[list, Path]]]  # command, name, valid, build -> (argv, out)


def _call(argv: list) -> tuple[int, str, bool]:
    err = io.StringIO()
    tb = False
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as e:
            code = int(e.code or 0)
        except BaseException:  # noqa: BLE001 - a traceback is what the probe looks for
            traceback.print_exc()
            code, tb = 1, True
    text = err.getvalue()
    return code, text, tb or "Traceback" in text


def classify(valid: bool, build: Callable[[Path], tuple[list, Path]], d: Path) -> tuple[str, str]:
    argv, out = build(d)
    earlier = b"earlier output"
    if out.suffix:  # a file output: an earlier one must survive a refusal
        out.write_bytes(earlier)
    code, err, tb = _call(argv)
    last = [ln for ln in err.splitlines() if ln.strip()]
    line = last[-1] if last else ""
    if tb:
        return "traceback", line
    if code == 0:
        return ("accepted" if valid else "silent"), line
    if code != 2:
        return f"exit {code}", line
    left = (out.suffix and out.read_bytes() != earlier) or (not out.suffix and out.exists())
    base = out.parent if out.parent.is_dir() else out.parent.parent
    partial = [p for p in base.iterdir() if ".partial" in p.name]
    if left or partial:
        return "left behind", line
    if len(last) != 1 and not argv[0] == "sweep":
        return "left behind", f"{len(last)} lines: {line}"
    return ("refused" if not valid else "false refusal"), line


# ----------------------------------------------------------------------------- cases


def _crop(path: Path, seconds: float = 20.0, start: float = 20.0) -> dict:
    with np.load(path) as z:
        d = {k: z[k] for k in z.files if k not in ("mag", "movement", "meta_info")}
    t = d["t"]
    keep = (t >= t[0] + start) & (t < t[0] + start + seconds)
    out = {k: (v[keep] if v.ndim >= 1 and len(v) == len(t) else v) for k, v in d.items()}
    if "gt_t" in out:  # TUM-VI: keep its track over the crop
        g = (d["gt_t"] >= out["t"][0] - 0.5) & (d["gt_t"] <= out["t"][-1] + 0.5)
        out.update(gt_t=d["gt_t"][g], gt_pos=d["gt_pos"][g], gt_quat=d["gt_quat"][g])
    return out


def _shift(d: dict, seconds: float) -> dict:
    fs = 1.0 / float(np.median(np.diff(d["t"])))
    k = int(round(abs(seconds) * fs))
    out = dict(d)
    for f in ("pos_ref", "quat_ref"):
        a = d[f]
        out[f] = np.concatenate([np.repeat(a[:1], k, 0), a[:-k]]) if seconds > 0 else np.concatenate([a[k:], np.repeat(a[-1:], k, 0)])
    out.pop("gt_t", None), out.pop("gt_pos", None), out.pop("gt_quat", None)
    return out


def _no_track(d: dict) -> dict:
    return {k: v for k, v in d.items() if k not in ("gt_t", "gt_pos", "gt_quat")}


def reference_variants(d: dict, other: dict) -> dict[str, dict]:
    n = len(d["t"])
    rng = np.random.default_rng(0)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    rv = np.zeros(n, bool)
    fs = 1.0 / float(np.median(np.diff(d["t"])))
    rv[n // 3: n // 3 + int(2 * fs)] = True
    rv4 = np.zeros(n, bool)
    rv4[n // 3: n // 3 + int(4 * fs)] = True
    b = _no_track(d)
    m = min(n, len(other["t"]))
    return {
        "random quaternions": b | {"quat_ref": q},
        "constant pose": b | {"quat_ref": np.tile(d["quat_ref"][n // 2], (n, 1)), "pos_ref": np.tile(d["pos_ref"][n // 2], (n, 1))},
        "mocap 3 s late": _shift(d, 3.0),
        "mocap 5 s late": _shift(d, 5.0),
        "mocap 5 s early": _shift(d, -5.0),
        "millimetres as metres": b | {"pos_ref": d["pos_ref"] * 1000.0},
        "centimetres as metres": b | {"pos_ref": d["pos_ref"] * 100.0},
        "xyzw read as wxyz": b | {"quat_ref": d["quat_ref"][:, [1, 2, 3, 0]]},
        "conjugate quaternions": b | {"quat_ref": d["quat_ref"] * [1, -1, -1, -1]},
        "another recording's pose": {k: (v[:m] if np.ndim(v) >= 1 and len(v) == n else v) for k, v in b.items()}
                                   | {"pos_ref": other["pos_ref"][:m], "quat_ref": other["quat_ref"][:m]},
        "pose covers 2 s of 20 s": b | {"ref_valid": rv, "pos_ref": np.where(rv[:, None], d["pos_ref"], np.nan),
                                        "quat_ref": np.where(rv[:, None], d["quat_ref"], np.nan)},
        "pose covers 4 s of 20 s": b | {"ref_valid": rv4, "pos_ref": np.where(rv4[:, None], d["pos_ref"], np.nan),
                                        "quat_ref": np.where(rv4[:, None], d["quat_ref"], np.nan)},
        "time-reversed pose": b | {"pos_ref": d["pos_ref"][::-1], "quat_ref": d["quat_ref"][::-1]},
        "gyro replaced by noise": b | {"gyr": 0.05 * rng.normal(size=(n, 3))},
    }


def cases(d: Path) -> list[Case]:
    out: list[Case] = []
    rigs = {"BROAD 07": DATA / "broad_07_undisturbed_fast_rotation_B" / "07_undisturbed_fast_rotation_B.npz",
            "TUM-VI": DATA / "tumvi_room1_512_16" / "room1.npz"}
    crops = {k: _crop(p) for k, p in rigs.items()}
    names = list(crops)
    for i, (rig, base) in enumerate(crops.items()):
        for vname, v in reference_variants(base, crops[names[1 - i]]).items():
            f = d / f"{rig.replace(' ', '')}_{vname.replace(' ', '_')}.npz"
            np.savez(f, **v)
            for cmd in ("align", "diagnose"):
                out.append((cmd, f"{rig}: {vname}", False, lambda dd, f=f, cmd=cmd: ([cmd, f, "--out", dd / "out"], dd / "out")))
            out.append(("diagnose --model-out", f"{rig}: {vname}", False,
                        lambda dd, f=f: (["diagnose", f, "--out", dd / "out", "--model-out", dd / "m.npz"], dd / "m.npz")))
    ok = d / "ok.npz"
    np.savez(ok, **crops["BROAD 07"])
    out += [
        ("diagnose --model-out", "model-out in a missing folder", False,
         lambda dd: (["diagnose", ok, "--out", dd / "out", "--model-out", dd / "no" / "m.npz"], dd / "out")),
        ("diagnose --model-out", "model-out onto --out", False,
         lambda dd: (["diagnose", ok, "--out", dd / "x.npz", "--model-out", dd / "x.npz"], dd / "x.npz")),
        ("diagnose --model-out", "model-out under a file", False,
         lambda dd: (["diagnose", ok, "--out", dd / "out", "--model-out", _w(dd / "f", "x") / "m.npz"], dd / "out")),
        ("diagnose --model-out", "model-out .txt", False,
         lambda dd: (["diagnose", ok, "--out", dd / "out", "--model-out", dd / "m.txt"], dd / "out")),
    ]
    out += _noise_cases(d) + _import_cases(d) + _export_cases(d) + _apply_cases(d) + _sweep_cases() + _rosbag_cases()
    return out


def _w(p: Path, text: str | bytes) -> Path:
    (p.write_bytes if isinstance(text, bytes) else p.write_text)(text)
    return p


def _rest(n: int = 3000, lsb: float | None = 3.0, seed: int = 0, **kw) -> dict:
    rng = np.random.default_rng(seed)
    acc, gyr = np.tile([0.0, 0.0, 16384.0], (n, 1)), np.tile([3.0, -2.0, 1.0], (n, 1))
    if lsb is not None:
        acc, gyr = np.round(acc + lsb * rng.standard_normal((n, 3))), np.round(gyr + lsb * rng.standard_normal((n, 3)))
    return dict(t=np.arange(n) / 100.0, acc=acc, gyr=gyr, acc_lsb_per_g=np.asarray(16384.0),
                gyr_lsb_per_rads=np.asarray(7505.747), fs=np.asarray(100.0)) | kw


def _noise_cases(d: Path) -> list[Case]:
    recs = {
        "stuck sensor": (_rest(lsb=None), False), "sub-LSB noise (0.2 LSB)": (_rest(lsb=0.2), False),
        "one stuck gyro axis": (_rest() | {"gyr": np.c_[_rest()["gyr"][:, :2], np.full(3000, 5.0)]}, False),
        "stuck except one glitch": (_rest(lsb=None) | {"gyr": np.tile([3.0, -2.0, 1.0], (3000, 1)) + (np.arange(3000) == 7)[:, None]}, False),
        "3 LSB noise": (_rest(), True), "1 LSB noise": (_rest(lsb=1.0), True),
        "acc in g (float), 1e-4 g noise": ({k: v for k, v in _rest().items() if k != "acc_lsb_per_g"}
                                           | {"acc": np.tile([0, 0, 1.0], (3000, 1)) + 1e-4 * np.random.default_rng(1).normal(size=(3000, 3)),
                                              "acc_unit": np.asarray("g")}, True),
    }
    out: list[Case] = []
    for name, (r, valid) in recs.items():
        f = d / f"noise_{name.replace(' ', '_')}.npz"
        np.savez(f, **r)
        for stretch in ([], ["--start", "0", "--end", "29"]):
            out.append(("noise", name + (" (auto stretch)" if not stretch else ""), valid if stretch else valid or False,
                        lambda dd, f=f, s=stretch: (["noise", f, "--out", dd / "out", *s], dd / "out")))
    # the automatic stretch may legitimately find no rest in a short flat recording: valid cases need --start/--end
    return [c for c in out if not (c[2] and "auto" in c[1])]


_linear_model = linear_model_file


BOMB = "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
    f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(8))


def _import_cases(d: Path) -> list[Case]:
    from jaxcal.export import to_imucal, to_kalibr, to_openvins
    from jaxcal.model_file import load_model

    m = load_model(_linear_model(d / "lin.npz"))
    k, o, i = to_kalibr(m), to_openvins(m), to_imucal(m)

    def edit(doc: dict, path: tuple, fn) -> dict:
        doc = json.loads(json.dumps(doc))
        node = doc
        for p in path[:-1]:
            node = node[p]
        node[path[-1]] = fn(node[path[-1]])
        return doc

    def rot(c):
        return lambda M: (np.asarray(M, float) * c).tolist()

    def t_fix(fn):
        return lambda T: (lambda A: (A.__setitem__((slice(0, 3), slice(0, 3)), fn(A[:3, :3])), A)[1].tolist())(np.asarray(T, float))

    ys = {
        "kalibr alias bomb": ("kalibr", BOMB, False),
        "kalibr 100-deep nesting": ("kalibr", "[" * 100 + "]" * 100, False),
        "kalibr 2 MB file": ("kalibr", "x: 1\n" * 500_000, False),
        "kalibr 20000x3 M": ("kalibr", yaml.safe_dump(edit(k, ("imu0", "gyroscopes", "M"), lambda _: [[1.0] * 3] * 20000)), False),
        "kalibr C_gyro_i x2": ("kalibr", yaml.safe_dump(edit(k, ("imu0", "gyroscopes", "C_gyro_i"), rot(2.0))), False),
        "kalibr C_gyro_i x(1+1e-4)": ("kalibr", yaml.safe_dump(edit(k, ("imu0", "gyroscopes", "C_gyro_i"), rot(1 + 1e-4))), False),
        "kalibr C_gyro_i x(1+1e-9)": ("kalibr", yaml.safe_dump(edit(k, ("imu0", "gyroscopes", "C_gyro_i"), rot(1 + 1e-9))), True),
        "kalibr T_i_b det -1": ("kalibr", yaml.safe_dump(edit(k, ("imu0", "T_i_b"), t_fix(lambda R: R @ np.diag([1, 1, -1])))), False),
        "kalibr T_i_b last row [0,0,0,2]": ("kalibr", yaml.safe_dump(edit(k, ("imu0", "T_i_b"), lambda T: T[:3] + [[0, 0, 0, 2]])), False),
        "kalibr T_i_b sheared": ("kalibr", yaml.safe_dump(edit(k, ("imu0", "T_i_b"), t_fix(lambda R: R + 1e-3 * np.triu(np.ones((3, 3)), 1)))), False),
        "kalibr as exported": ("kalibr", yaml.safe_dump(k), True),
        "openvins R_IMUtoACC x1.5": ("openvins", yaml.safe_dump(edit(o, ("imu0", "R_IMUtoACC"), rot(1.5))), False),
        "openvins R_IMUtoGYRO reflected": ("openvins", yaml.safe_dump(edit(o, ("imu0", "R_IMUtoGYRO"), rot(-1.0))), False),
        "openvins R_IMUtoGYRO zero": ("openvins", yaml.safe_dump(edit(o, ("imu0", "R_IMUtoGYRO"), rot(0.0))), False),
        "openvins alias bomb": ("openvins", BOMB, False),
        "openvins as exported": ("openvins", yaml.safe_dump(o), True),
    }
    js = {
        "imucal example (version 2.0)": ((DATA / "imucal_ferraris_example" / "example_cal.json").read_text(), True),
        "imucal version '2'": (json.dumps(i | {"_format_version": "2"}), True),
        "imucal version '3.0'": (json.dumps(i | {"_format_version": "3.0"}), False),
        "imucal version 2.0 (a number)": (json.dumps(i | {"_format_version": 2.0}), False),
        "imucal K_a 4x4": (json.dumps(i | {"K_a": np.eye(4).tolist()}), False),
        "imucal K_a singular": (json.dumps(i | {"K_a": np.zeros((3, 3)).tolist()}), False),
    }
    out: list[Case] = []
    for name, (fmt, text, valid) in ys.items():
        f = _w(d / f"imp_{len(out)}.yaml", text)
        out.append(("import-model", name, valid, lambda dd, f=f, fmt=fmt: (["import-model", fmt, f, "--out", dd / "m.npz"], dd / "m.npz")))
    for name, (text, valid) in js.items():
        f = _w(d / f"imp_{len(out)}.json", text)
        out.append(("import-model", name, valid, lambda dd, f=f: (["import-model", "imucal", f, "--out", dd / "m.npz"], dd / "m.npz")))
    return out


def _export_cases(d: Path) -> list[Case]:
    lin = _linear_model(d / "lin2.npz")
    good = {"accelerometer_noise_density": 1e-3, "accelerometer_random_walk": 1e-4, "gyroscope_noise_density": 1e-4,
            "gyroscope_random_walk": 1e-5, "update_rate": 200.0, "rostopic": "/imu0"}
    noises = {"alias bomb": (BOMB, False), "2 MB": ("x: 1\n" * 500_000, False),
              "negative density": (yaml.safe_dump(good | {"gyroscope_noise_density": -1e-4}), False),
              "NaN density": (yaml.safe_dump(good).replace("0.0001\n", ".nan\n", 1), False),
              "a list": ("[1, 2, 3]\n", False), "valid": (yaml.safe_dump(good), True)}
    out: list[Case] = []
    for name, (text, valid) in noises.items():
        f = _w(d / f"noise_{len(out)}.yaml", text)
        out.append(("export --noise", name, valid, lambda dd, f=f: (["export", lin, "--format", "kalibr", "--noise", f, "--out", dd / "o.yaml"], dd / "o.yaml")))
    return out


def _apply_cases(d: Path) -> list[Case]:
    from jaxcal.methods import CalibrationModel
    from jaxcal.model_file import save_model

    np.savez(d / "cap.npz", **labelled_poses(400, 18.0, 0))
    cub = d / "cubic.npz"
    assert _call(["calibrate", "--method", "cubic", d / "cap.npz", "--out", cub, "-q"])[0] == 0

    def diag(p: Path, **acc) -> Path:
        st = {"acc": {"S": 16384.0 * np.eye(3), "b": np.zeros(3), **acc}}
        meta = {"baseline": "diag", "effects": {"acc": [k for k in acc if k != "T0"]}, "not_carried": [], "notes": [],
                "units": {"acc": "LSB"}, "temperature_range_degC": {"acc": [20.0, 35.0]}}
        save_model(CalibrationModel("diagnosed", ("acc",), st, meta), p)
        return p

    temp_m = diag(d / "dt.npz", temperature_bias=np.full(3, 1e-4), T0=np.asarray(27.0))
    tau_m = diag(d / "dtau.npz", time_offset=np.asarray(10.0))
    tau_ok = diag(d / "dtau2.npz", time_offset=np.asarray(0.004))
    recs = {
        "cubic over the sphere": (cub, labelled_poses(400, None, 1), False),
        "cubic within 15 deg": (cub, labelled_poses(400, 15.0, 2), True),
        "cubic tilted to 40 deg": (cub, labelled_poses(400, 40.0, 3), False),
        "temperature model, Kelvin as degC": (temp_m, labelled_poses(400, None, 4, temp=np.full(400, 300.15)), False),
        "temperature model, -40 degC": (temp_m, labelled_poses(400, None, 5, temp=np.full(400, -40.0)), False),
        "temperature model, 27 degC": (temp_m, labelled_poses(400, None, 6, temp=np.full(400, 27.0)), True),
        "time offset 10 s on a 4 s recording": (tau_m, labelled_poses(400, None, 7), False),
        "time offset 4 ms on a 4 s recording": (tau_ok, labelled_poses(400, None, 8), True),
    }
    out: list[Case] = []
    for name, (m, r, valid) in recs.items():
        f = d / f"apply_{len(out)}.npz"
        np.savez(f, **r)
        out.append(("apply", name, valid, lambda dd, m=m, f=f: (["apply", m, f, "--out", dd / "o.npz", "-q"], dd / "o.npz")))
    return out


def _sweep_cases() -> list[Case]:
    specs = {
        "random.n = 1e9": {"random": {"n": 10**9, "params": {"acc_lr": [1e-4, 1e-2, "log"]}}},
        "40^6 grid": {"grid": {"acc_lr": [1e-3] * 40, "gyr_lr": [1e-3] * 40, "init_lr": [1e-3] * 40, "w": [0.5] * 40,
                               "init_epochs": [1] * 40, "gyr_steps": [1] * 40}},
        "200000 seeds": {"seeds": list(range(200_000))},
        "dataset fs 0": {"dataset": {"fs": 0}},
        "dataset fs -100": {"dataset": {"fs": -100.0}},
        "dataset acc_lsb_per_g 0 in the grid": {"grid": {"dataset.acc_lsb_per_g": [16384.0, 0.0]}},
        "heatmap a string": {"grid": {"w": [0.5, 0.9]}, "heatmap": "w"},
        "heatmap a number": {"grid": {"w": [0.5, 0.9]}, "heatmap": 3},
        "heatmap an object": {"grid": {"w": [0.5, 0.9]}, "heatmap": {"a": 1}},
    }
    out: list[Case] = []
    for name, spec in specs.items():
        def build(dd, spec=spec):
            f = _w(dd / "s.json", json.dumps(spec))
            return ["sweep", f, "--out", dd / "out"], dd / "out"
        out.append(("sweep", name, False, build))

    def under_file(dd):
        f = _w(dd / "s.json", json.dumps({"grid": {"w": [0.5]}}))
        return ["sweep", f, "--out", _w(dd / "file", "x") / "sub"], dd / "file" / "sub"
    out.append(("sweep", "--out under a file", False, under_file))
    return out


def _rosbag_cases() -> list[Case]:
    try:
        import test_rosbag as tr
    except Exception:  # noqa: BLE001 - rosbags missing
        return []
    out: list[Case] = []

    def two_frames(dd):
        t = tr.Truth(5)
        ts = tr._typestore("ros1")
        msgs = t.imu_msgs(ts)
        for _, m in msgs[1::2]:
            m.header.frame_id = "imu_b"
        bag = tr.write_bag(dd / "b", "ros1", {"/imu0": ("sensor_msgs/msg/Imu", msgs)})
        return ["import", "rosbag", bag, "--imu-topic", "/imu0", "--out", dd / "r.npz"], dd / "r.npz"

    def clock_step(dd, receive=False):
        t = tr.Truth(6)
        ts = tr._typestore("sqlite3")
        msgs = [(int(r), tr.imu_msg(ts, int(s) + (3600 * 10**9 if k >= tr.N // 2 else 0), a, g))
                for k, (r, s, a, g) in enumerate(zip(t.recv, t.ns, t.acc, t.gyr))]
        bag = tr.write_bag(dd / "b", "sqlite3", {"/imu0": ("sensor_msgs/msg/Imu", msgs)})
        return ["import", "rosbag", bag, "--imu-topic", "/imu0", *(["--time", "receive"] if receive else []),
                "--out", dd / "r.npz"], dd / "r.npz"

    def pose_shift(dd, shift_ns):
        t = tr.Truth(7)
        ts = tr._typestore("sqlite3")
        poses = [(int(r) + shift_ns, tr.pose_msg(ts, "geometry_msgs/msg/PoseStamped", int(s) + shift_ns, p, np.r_[q[1:], q[0]]))
                 for (r, _), s, p, q in zip(t.pose_msgs(ts, "geometry_msgs/msg/PoseStamped"), t.pose_ns, t.pos, t.q_wxyz)]
        bag = tr.write_bag(dd / "b", "sqlite3", {"/imu0": ("sensor_msgs/msg/Imu", t.imu_msgs(ts)),
                                                 "/mocap": ("geometry_msgs/msg/PoseStamped", poses)})
        return ["import", "rosbag", bag, "--imu-topic", "/imu0", "--pose-topic", "/mocap", "--out", dd / "r.npz"], dd / "r.npz"

    out += [("import rosbag", "two frame_ids on one IMU topic", False, two_frames),
            ("import rosbag", "one-hour header clock step", False, clock_step),
            ("import rosbag", "one-hour header clock step, --time receive", True, lambda dd: clock_step(dd, True)),
            ("import rosbag", "pose track an hour late", False, lambda dd: pose_shift(dd, 3600 * 10**9)),
            ("import rosbag", "pose track 50 ms late (overlaps)", True, lambda dd: pose_shift(dd, 50_000_000))]
    return out


def main_(out_md: str | None = None) -> int:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "inputs").mkdir()
        all_cases = cases(d / "inputs")
        for k, (cmd, name, valid, build) in enumerate(all_cases):
            dd = d / f"c{k}"
            dd.mkdir()
            t0 = time.perf_counter()
            outcome, line = classify(valid, build, dd)
            rows.append((cmd, name, "valid" if valid else "hostile", outcome, time.perf_counter() - t0, line))
            print(f"{k + 1}/{len(all_cases)} {cmd} | {name} | {outcome} | {line[:160]}", file=sys.__stderr__, flush=True)
    counts: dict[str, int] = {}
    for r in rows:
        counts[r[3]] = counts.get(r[3], 0) + 1
    md = ["| command | input | kind | outcome | s | message |", "|---|---|---|---|---|---|"]
    md += [f"| {c} | {n} | {v} | {o} | {t:.1f} | {line.replace('|', '/')[:220]} |" for c, n, v, o, t, line in rows]
    md += ["", "Outcomes: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + f" (of {len(rows)})"]
    text = "\n".join(md) + "\n"
    if out_md:
        Path(out_md).write_text(text)
    print(text)
    return 0 if set(counts) <= {"refused", "accepted"} else 1


if __name__ == "__main__":
    sys.exit(main_(sys.argv[1] if len(sys.argv) > 1 else None))
