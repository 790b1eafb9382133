"""Recording I/O: npz <-> csv round trips and the validation errors of CONVENTIONS.md."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxcal.recording import (
    Recording,
    RecordingError,
    load_recording,
    recording_from_dict,
    save_recording,
    sequence_slices,
    validate_recording,
)


def full_recording(n: int = 12, seed: int = 0) -> Recording:
    """A recording with every field set, plus extras of several shapes."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    m = 7  # samples of the original pose track
    qg = rng.normal(size=(m, 4))
    return Recording(
        t=np.cumsum(rng.uniform(0.005, 0.015, n)),
        acc=np.round(rng.normal(0, 8000, (n, 3))).astype(np.int32),
        gyr=rng.normal(0, 300, (n, 3)),
        temp=25 + rng.normal(0, 0.1, n),
        seq=np.repeat(np.arange(3), [4, 5, n - 9]),
        static=rng.uniform(size=n) < 0.3,
        acc_ref=rng.normal(size=(n, 3)),
        gyr_ref=rng.normal(size=(n, 3)),
        pos_ref=rng.normal(size=(n, 3)),
        quat_ref=q / np.linalg.norm(q, axis=1, keepdims=True),
        fs=100.0,
        acc_lsb_per_g=np.asarray(16384.0),
        acc_bias_lsb=np.asarray([1.0, -2.0, 3.5]),
        gyr_lsb_per_rads=np.asarray([7505.7, 7500.0, 7510.0]),
        gyr_bias_lsb=np.asarray(0.0),
        mag=rng.normal(0, 40, (n, 3)),
        ref_valid=rng.uniform(size=n) < 0.8,
        section=rng.integers(-1, 3, n),
        section_names=np.array(["x_p", "x_n", "y_p"]),
        gt_t=np.sort(rng.uniform(-0.1, 0.2, m)),
        gt_pos=rng.normal(size=(m, 3)),
        gt_quat=qg / np.linalg.norm(qg, axis=1, keepdims=True),
        t0=1.7e9 + 0.123456,
        extra={"wind": rng.normal(size=(n, 3)), "pressure": rng.normal(size=n), "device": np.asarray("mpu6050")},
    )


def assert_same(a: Recording, b: Recording) -> None:
    da, db = a.to_dict(), b.to_dict()
    assert set(da) == set(db)
    for k in da:
        va, vb = np.asarray(da[k]), np.asarray(db[k])
        if va.dtype.kind in "US":
            assert str(va) == str(vb), k
        else:
            np.testing.assert_array_equal(va.astype(np.float64), vb.astype(np.float64), err_msg=k)


@pytest.mark.parametrize("first,second", [("npz", "csv"), ("csv", "npz"), ("csv", "csv"), ("npz", "npz")])
def test_round_trip_is_exact(tmp_path, first, second):
    rec = full_recording()
    p1, p2 = tmp_path / f"a.{first}", tmp_path / f"b.{second}"
    save_recording(rec, p1)
    r1 = load_recording(p1)
    save_recording(r1, p2)
    r2 = load_recording(p2)
    assert_same(rec, r1)
    assert_same(rec, r2)
    assert r2.acc_unit == "LSB" and r2.gyr_unit == "LSB" and r2.fs == 100.0
    assert r2.seq.dtype.kind == "i" and r2.static.dtype == np.bool_
    assert r2.ref_valid.dtype == np.bool_ and r2.section.dtype.kind == "i" and list(r2.section_names) == ["x_p", "x_n", "y_p"]
    assert r2.gt_pos.shape == (7, 3) and r2.gt_quat.shape == (7, 4) and r2.t0 == rec.t0
    assert r2.extra["wind"].shape == (rec.n, 3) and str(r2.extra["device"]) == "mpu6050"


def test_csv_layout_follows_conventions(tmp_path):
    rec = full_recording()
    save_recording(rec, tmp_path / "r.csv")
    header = (tmp_path / "r.csv").read_text().splitlines()[0].split(",")
    assert header[:7] == ["t", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"]
    assert header[-13:] == ["quat_ref_w", "quat_ref_x", "quat_ref_y", "quat_ref_z", "mag_x", "mag_y", "mag_z",
                            "ref_valid", "section", "wind_x", "wind_y", "wind_z", "pressure"]
    meta = json.loads((tmp_path / "r.json").read_text())
    assert meta["fs"] == 100.0 and meta["acc_bias_lsb"] == [1.0, -2.0, 3.5]
    assert meta["section_names"] == ["x_p", "x_n", "y_p"] and len(meta["gt_t"]) == 7 and meta["t0"] == rec.t0


def test_minimal_csv_without_sidecar_and_physical_units(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("t,gyr_x,gyr_y,gyr_z,static\n0,0.1,0.2,0.3,true\n0.5,0.1,0.2,0.3,false\n")
    rec = load_recording(p)
    assert rec.acc is None and rec.gyr.shape == (2, 3) and rec.static.tolist() == [True, False]
    assert rec.sensors() == ("gyr",)
    (tmp_path / "m.json").write_text('{"gyr_unit": "rad/s", "fs": 2}')
    assert load_recording(p).gyr_unit == "rad/s"


def test_sequence_slices():
    rec = full_recording()
    assert sequence_slices(rec) == [slice(0, 4), slice(4, 9), slice(9, 12)]
    assert sequence_slices(rec.replace(seq=None)) == [slice(0, 12)]


def _csv(tmp_path, text: str, name: str = "bad.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


GOOD_HEAD = "t,acc_x,acc_y,acc_z\n"


@pytest.mark.parametrize(
    "text,needles",
    [
        ("acc_x,acc_y,acc_z\n1,2,3\n", ["'t'"]),
        ("t,temp\n0,20\n1,20\n", ["neither 'acc' nor 'gyr'"]),
        (GOOD_HEAD + "0,1,2,3\n1,1,nan,3\n", ["acc_y", "row 1", "line 3", "non-finite"]),
        (GOOD_HEAD + "0,1,2,3\n1,1,2,3\n1,1,2,3\n", ["'t'", "row 2", "increasing"]),
        (GOOD_HEAD + "0,1,2,3\n1,1,abc,3\n", ["acc_y", "row 1", "'abc'"]),
        (GOOD_HEAD + "0,1,2,3\n1,1,2\n", ["row 1", "cells"]),
        ("t,acc_x,acc_y\n0,1,2\n", ["acc_z", "missing"]),
        (GOOD_HEAD.strip() + ",seq\n0,1,2,3,0\n1,1,2,3,1\n2,1,2,3,0\n", ["seq", "row 2", "contiguous"]),
        (GOOD_HEAD.strip() + ",seq\n0,1,2,3,0.5\n", ["seq", "row 0", "integer"]),
        (GOOD_HEAD.strip() + ",static\n0,1,2,3,2\n", ["static", "row 0"]),
        ("", ["empty"]),
    ],
)
def test_bad_csv_messages_say_what_and_where(tmp_path, text, needles):
    p = _csv(tmp_path, text)
    with pytest.raises(RecordingError) as e:
        load_recording(p)
    msg = str(e.value)
    assert "\n" not in msg and str(p) in msg
    for n in needles:
        assert n in msg, (n, msg)


def test_bad_unit_in_sidecar(tmp_path):
    p = _csv(tmp_path, GOOD_HEAD + "0,1,2,3\n")
    (tmp_path / "bad.json").write_text('{"acc_unit": "m/s^2"}')
    with pytest.raises(RecordingError, match="acc_unit.*m/s\\^2"):
        load_recording(p)


def test_bad_npz_and_files(tmp_path):
    n = 5
    good = dict(t=np.arange(n) * 0.01, acc=np.zeros((n, 3)))
    cases = {
        "shape": (dict(good, acc=np.zeros((n, 2))), "expected shape (N, 3)"),
        "length": (dict(good, gyr=np.zeros((n + 1, 3))), "does not match len(t)"),
        "quat": (dict(good, quat_ref=np.zeros((n, 3))), "(N, 4)"),
        "inf": (dict(good, temp=np.array([0, 1, np.inf, 2, 3.0])), "'temp' row 2"),
        "unit": (dict(good, gyr_unit=np.asarray("deg/s"), gyr=np.zeros((n, 3))), "unknown unit 'deg/s'"),
        "spec": (dict(good, acc_lsb_per_g=np.ones(2)), "acc_lsb_per_g"),
        "fs": (dict(good, fs=np.asarray(-1.0)), "'fs'"),
        "no_t": ({"acc": np.zeros((n, 3))}, "'t'"),
    }
    for name, (d, needle) in cases.items():
        p = tmp_path / f"{name}.npz"
        np.savez(p, **d)
        with pytest.raises(RecordingError) as e:
            load_recording(p)
        assert needle in str(e.value) and str(p) in str(e.value), (name, str(e.value))
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(RecordingError, match="cannot read"):
        load_recording(tmp_path / "junk.npz")
    with pytest.raises(RecordingError, match="no such file"):
        load_recording(tmp_path / "missing.npz")
    with pytest.raises(RecordingError, match="extension"):
        load_recording(tmp_path / "x.txt")


def test_valid_inputs_pass_and_validation_is_strict():
    rec = recording_from_dict({"t": [0.0, 1.0], "gyr": [[0, 0, 0], [1, 1, 1]], "foo": [1, 2]})
    assert rec.extra["foo"].tolist() == [1, 2]
    validate_recording(rec)
    with pytest.raises(RecordingError, match="increasing"):
        validate_recording(rec.replace(t=np.array([1.0, 0.0])))
    with pytest.raises(RecordingError, match="neither"):
        validate_recording(rec.replace(gyr=None))


@pytest.mark.parametrize("change,needle", [
    ({"ref_valid": np.array([0, 2, 1, 1])}, "key 'ref_valid' row 1: expected a boolean"),
    ({"section": np.array([0.0, 0.5, 1, 1])}, "key 'section' row 1: section label 0.5 is not an integer"),
    ({"section": np.array([0, 1, 3, -1])}, "key 'section' row 2: label 3 names none of the 2 'section_names'"),
    ({"section_names": np.array([1.0, 2.0])}, "key 'section_names': expected a list of strings"),
    ({"mag": np.ones((3, 3))}, "key 'mag': length 3 does not match len"),
    ({"gt_t": np.array([0.0, 0.2, 0.1])}, "key 'gt_t' row 2: times not strictly increasing"),
    ({"gt_pos": np.zeros((2, 3))}, r"key 'gt_pos': expected shape \(M, 3\) with M = len\(gt_t\) = 3"),
    ({"gt_quat": np.full((3, 4), np.nan)}, "key 'gt_quat' row 0: non-finite"),
    ({"t0": np.inf}, "key 't0': must be finite"),
    ({"extra": {"mag": np.zeros((4, 3))}}, "key 'mag' is a field of Recording"),
])
def test_optional_fields_are_validated(change, needle):
    """The readers' optional keys (mag, ref_valid, section/section_names, the pose track gt_*, t0)
    are fields with their own checks; an extra may not shadow a field."""
    ok = recording_from_dict({"t": np.arange(4) * 0.01, "gyr": np.zeros((4, 3)), "gyr_unit": "rad/s",
                              "mag": np.ones((4, 3)), "ref_valid": np.array([True, False, True, True]),
                              "section": np.array([0, 1, 1, -1]), "section_names": np.array(["a", "b"]),
                              "gt_t": np.array([0.0, 0.1, 0.2]), "gt_pos": np.zeros((3, 3)),
                              "gt_quat": np.tile([1.0, 0, 0, 0], (3, 1)), "t0": 1.7e9, "meta_x": 2.0})
    assert ok.t0 == 1.7e9 and ok.ref_valid.dtype == bool and set(ok.extra) == {"meta_x"}
    with pytest.raises(RecordingError, match=needle):
        validate_recording(ok.replace(**change))
    with pytest.raises(RecordingError, match="key 't0': expected a scalar time in s"):
        recording_from_dict({"t": [0.0, 1.0], "gyr": np.zeros((2, 3)), "t0": [1.0, 2.0]})


def test_nan_rows_in_reference_keys_are_gaps():
    """A whole row of NaN in acc_ref / gyr_ref / pos_ref / quat_ref marks a reference gap and is
    kept (npz and csv); inf, a partly-NaN row and NaN in t / acc / gyr are still refused."""
    n = 6
    q = np.tile([1.0, 0, 0, 0], (n, 1))
    good = dict(t=np.arange(n) * 0.01, acc=np.tile([0, 0, 1.0], (n, 1)), acc_unit=np.asarray("g"),
                gyr=np.zeros((n, 3)), gyr_unit=np.asarray("rad/s"), acc_ref=np.tile([0, 0, 1.0], (n, 1)),
                gyr_ref=np.zeros((n, 3)), pos_ref=np.zeros((n, 3)), quat_ref=q)
    gappy = {k: (v.astype(np.float64).copy() if k.endswith("_ref") else v) for k, v in good.items()}
    for k in ("acc_ref", "gyr_ref", "pos_ref", "quat_ref"):
        gappy[k][[1, 2]] = np.nan
    rec = recording_from_dict(gappy)
    assert np.isnan(rec.pos_ref[1]).all() and np.isnan(rec.quat_ref[2]).all()
    for name, ref in (("partly NaN", np.nan), ("inf", np.inf), ("-inf", -np.inf)):
        for k in ("acc_ref", "gyr_ref", "pos_ref", "quat_ref"):
            bad = dict(gappy, **{k: gappy[k].copy()})
            bad[k][4, 1] = ref
            with pytest.raises(RecordingError, match=f"'{k}' column 1 row 4: non-finite value"):
                recording_from_dict(bad)
    for k in ("acc", "gyr"):
        a = good[k].astype(np.float64)
        a[3] = np.nan
        with pytest.raises(RecordingError, match=f"'{k}' column 0 row 3: non-finite value$"):
            recording_from_dict(dict(gappy, **{k: a}))
    with pytest.raises(RecordingError, match="'t' row 0: non-finite"):
        recording_from_dict(dict(gappy, t=np.r_[np.nan, gappy["t"][1:]]))
    # a gap row and a non-unit quaternion elsewhere: the norm check skips only the gap
    q2 = gappy["quat_ref"].copy()
    q2[5] *= 2
    with pytest.raises(RecordingError, match="'quat_ref' row 5"):
        recording_from_dict(dict(gappy, quat_ref=q2))


def test_nan_reference_gaps_round_trip(tmp_path):
    n = 6
    pos = np.arange(n * 3, dtype=np.float64).reshape(n, 3) / 10
    pos[2] = np.nan
    rec = recording_from_dict(dict(t=np.arange(n) * 0.01, gyr=np.zeros((n, 3)), gyr_unit=np.asarray("rad/s"),
                                   pos_ref=pos))
    for name in ("r.npz", "r.csv"):
        save_recording(rec, tmp_path / name)
        back = load_recording(tmp_path / name)
        np.testing.assert_array_equal(back.pos_ref, pos)
        assert np.isnan(back.pos_ref[2]).all() and np.isfinite(back.pos_ref[[0, 1, 3, 4, 5]]).all()
