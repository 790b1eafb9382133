"""Readers on the repository's byte-for-byte format excerpts (``data/*/*_head.*``) and on
hand-written files: shapes, units, sample rates, quaternion order, and errors that name the column.

Truth comes from the datasets' READMEs (first lines, sample rates, reference scales) and from
values written into the synthetic files here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from jaxcal.readers import ReaderError, read
from jaxcal.recording import Recording, load_recording, save_recording

DATA = Path(__file__).resolve().parent.parent / "data"
G0 = 9.80665


def test_imu_tk_ascii_counts_rate_and_factory_norm():
    d = DATA / "imu_tk_xsens_multipos"
    rec = read("imu_tk", [d / "xsens_acc_head.txt", d / "xsens_gyro_head.txt"])
    assert rec.acc.shape == (400, 3) and rec.gyr.shape == (400, 3)
    assert rec.acc.dtype.kind == "i" and rec.acc_unit == "LSB"
    # README: first lines and 100 Hz
    np.testing.assert_array_equal(rec.acc[0], [33108, 33329, 36429])
    np.testing.assert_array_equal(rec.gyr[0], [32786, 32429, 32499])
    assert rec.t[0] == pytest.approx(0.02984)
    assert rec.fs == pytest.approx(100.0, rel=1e-3)
    # at rest: factory offsets and 415 counts per m/s^2 give |f| = local g (9.817 m/s^2) within 1 %
    f = (rec.acc - np.array([33123, 33276, 32360])) / np.array([415.0, 413.0, 415.0])
    assert np.median(np.linalg.norm(f, axis=1)) == pytest.approx(9.81744, rel=0.01)


def test_imucal_physical_session_units_and_missing_unit_error():
    d = DATA / "imucal_ferraris_example"
    f = d / "example_ferraris_session_head.csv"
    rec = read("imucal", [f], fs=102.4, acc_unit="m/s^2", gyr_unit="deg/s")
    assert rec.acc.shape == (399, 3) and rec.acc_unit == "g" and rec.gyr_unit == "rad/s"
    np.testing.assert_allclose(np.diff(rec.t), 1 / 102.4, rtol=1e-9)
    # README first line: acc_x 10.3321 m/s^2, gyr_x -0.61035 deg/s
    assert rec.acc[0, 0] == pytest.approx(10.332114257812501 / G0)
    assert rec.gyr[0, 0] == pytest.approx(math.radians(-0.6103515625))
    # the x_p hold is uncalibrated: norm 10.34 m/s^2 (README)
    assert np.median(np.linalg.norm(rec.acc, axis=1)) == pytest.approx(10.34 / G0, rel=0.01)
    with pytest.raises(ReaderError, match="acc_x"):
        read("imucal", [f], fs=102.4)
    with pytest.raises(ReaderError, match="fs"):
        read("imucal", [f], acc_unit="m/s^2", gyr_unit="deg/s")
    with pytest.raises(ReaderError, match="acc_x.*unknown acc unit"):
        read("imucal", [f], fs=102.4, acc_unit="m/s", gyr_unit="deg/s")


def test_imucal_annotated_raw_counts_sections():
    d = DATA / "imucal_ferraris_example"
    rec = read("imucal", [d / "annotated_session_head.csv"], fs=204.8)
    assert rec.acc_unit == "LSB" and rec.acc.dtype.kind == "i"
    assert list(rec.section_names) == ["x_a"]
    np.testing.assert_array_equal(rec.acc[0], [-2052, -28, -73])
    assert rec.t[0] == pytest.approx(1028 / 204.8)
    # x_a hold: x reads about -1 g at ~208.5 counts per m/s^2 (example_cal.json K_a)
    assert np.median(rec.acc[:, 0]) / 208.5 == pytest.approx(-9.81, rel=0.02)


def test_mpu6050_header_lines_rate_and_datasheet_scale():
    rec = read("mpu6050", [DATA / "tomisuarez_mpu6050" / "example_data_calibration_head.csv"])
    assert rec.acc.shape == (395, 3) and rec.fs == 100.0
    np.testing.assert_allclose(np.diff(rec.t), 0.01)
    np.testing.assert_array_equal(rec.acc[0], [-12, -812, 15032])
    assert rec.extra["meta_initialization_time"] == 36.5
    # static start, datasheet 16384 LSB/g: |f| within 10 % of 1 g (uncalibrated chip)
    norm = np.median(np.linalg.norm(rec.acc / rec.acc_lsb_per_g, axis=1))
    assert 0.9 < norm < 1.1
    assert rec.gyr_lsb_per_rads == pytest.approx(131 * 180 / math.pi)


def test_mpu6050_missing_fs(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("Logging Type,0\nax,ay,az,gx,gy,gz\n1,2,3,4,5,6\n1,2,3,4,5,6\n")
    with pytest.raises(ReaderError, match="Fs"):
        read("mpu6050", [p])


def test_tumvi_quaternion_order_and_units():
    d = DATA / "tumvi_room1_512_16"
    rec = read("tumvi", [d / "imu_head.csv", d / "gt_head.csv"])
    assert rec.acc_unit == "g" and rec.gyr_unit == "rad/s"
    assert rec.acc[0, 2] == pytest.approx(9.92376030285343 / G0)
    assert np.median(np.linalg.norm(rec.acc, axis=1)) == pytest.approx(1.0, abs=0.05)
    assert np.median(np.diff(rec.t)) == pytest.approx(1 / 200, rel=0.01)
    # ROS (x, y, z, w) -> conventions (w, x, y, z)
    np.testing.assert_allclose(rec.gt_quat[0], [0.9996498117006686, 0.0037373092773871,
                                                   0.00971696346904, -0.024328319036143], atol=1e-9)
    q = rec.quat_ref
    ok = rec.ref_valid
    assert ok.mean() > 0.9 and not ok[0]  # gt starts 7.8 ms after the IMU
    np.testing.assert_allclose(np.linalg.norm(q[ok], axis=1), 1.0, atol=1e-9)
    assert np.all(q[ok, 0] > 0.99)  # near identity at the start, scalar first


def test_fusion_uneven_time_and_deg_to_rad():
    rec = read("fusion", [DATA / "xio_fusion_sensor_data" / "sensor_data_head.csv"])
    assert rec.acc.shape == (399, 3) and rec.mag.shape == (399, 3)
    assert rec.gyr[0, 0] == pytest.approx(math.radians(0.01644619))
    assert rec.acc[0, 2] == pytest.approx(0.9970807)
    dt = np.diff(rec.t)
    assert dt.min() < 0.0095 or dt.max() > 0.0105 or np.median(dt) == pytest.approx(0.01008, rel=1e-3)
    assert np.median(np.linalg.norm(rec.acc, axis=1)) == pytest.approx(1.0, abs=0.05)


def test_euroc_ns_time_and_scalar_first_pose(tmp_path):
    imu = tmp_path / "imu.csv"
    imu.write_text(
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
        "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
        + "".join(f"{1403636579758555392 + 5000000 * k},0.1,0,0,0,0,9.80665\n" for k in range(5))
    )
    pose = tmp_path / "pose.csv"
    c, s = math.cos(0.1), math.sin(0.1)
    pose.write_text(
        "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []\n"
        + "".join(f"{1403636579758555392 + 10000000 * k},1,2,3,{c},{s},0,0\n" for k in range(3))
    )
    rec = read("euroc", [imu, pose])
    np.testing.assert_allclose(rec.t, np.arange(5) * 0.005, atol=1e-9)
    np.testing.assert_allclose(rec.acc, [[0, 0, 1]] * 5, atol=1e-12)
    np.testing.assert_allclose(rec.quat_ref, [[c, s, 0, 0]] * 5, atol=1e-9)
    np.testing.assert_allclose(rec.pos_ref, [[1, 2, 3]] * 5)


def _write(tmp_path, header, rows):
    p = tmp_path / "g.csv"
    p.write_text(header + "\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    return p


def test_generic_csv_mapping_and_units(tmp_path):
    p = _write(tmp_path, "time_ms,ax,ay,az,wx,wy,wz",
               [[0, 0, 0, 9.80665, 180, 0, 0], [12.5, 0, 9.80665, 0, 0, 90, 0], [20, 9.80665, 0, 0, 0, 0, 0]])
    cols = {"t": "time_ms", "acc_x": "ax", "acc_y": "ay", "acc_z": "az", "gyr_x": "wx", "gyr_y": "wy", "gyr_z": "wz"}
    rec = read("csv", [p], columns=cols, units={"t": "ms", "acc": "m/s^2", "gyr": "deg/s"})
    np.testing.assert_allclose(rec.t, [0, 0.0125, 0.02])  # uneven kept
    np.testing.assert_allclose(rec.acc, np.eye(3)[[2, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(rec.gyr[0], [math.pi, 0, 0])
    # declared g for m/s^2 data: the error names the column and says why
    with pytest.raises(ReaderError, match=r"column 'ax'.*9\.81 g.*m/s\^2"):
        read("csv", [p], columns=cols, units={"t": "ms", "acc": "g", "gyr": "deg/s"})
    with pytest.raises(ReaderError, match=r"column 'wx'.*unknown gyr unit 'deg'"):
        read("csv", [p], columns=cols, units={"t": "ms", "acc": "m/s^2", "gyr": "deg"})
    with pytest.raises(ReaderError, match=r"column 'time_ms'.*no time unit"):
        read("csv", [p], columns=cols, units={"acc": "m/s^2", "gyr": "deg/s"})


def test_generic_csv_header_units_conflict_and_raw(tmp_path):
    p = _write(tmp_path, "t (s),ax (g),ay (g),az (g),wx (LSB),wy (LSB),wz (LSB)",
               [[0, 0, 0, 1, 5, -3, 2], [0.01, 0, 0, 1, 4, -2, 2]])
    cols = {"t": "t (s)", "acc_x": "ax (g)", "acc_y": "ay (g)", "acc_z": "az (g)",
            "gyr_x": "wx (LSB)", "gyr_y": "wy (LSB)", "gyr_z": "wz (LSB)"}
    rec = read("csv", [p], columns=cols)
    assert rec.acc_unit == "g" and rec.gyr_unit == "LSB" and rec.gyr.dtype.kind == "i"
    with pytest.raises(ReaderError, match=r"column 'ax \(g\)'.*header says 'g'.*ambiguous"):
        read("csv", [p], columns=cols, units={"acc": "m/s^2"})
    p2 = _write(tmp_path, "t,ax,ay,az", [[0, 0.5, 0, 1], [0.01, 0.25, 0, 1]])
    with pytest.raises(ReaderError, match="not integers"):
        read("csv", [p2], columns={"t": "t", "acc_x": "ax", "acc_y": "ay", "acc_z": "az"},
             units={"t": "s", "acc": "LSB"})


def test_read_rejects_unknown_format_missing_file_and_time_order(tmp_path):
    with pytest.raises(ReaderError, match="unknown format"):
        read("nope", [])
    with pytest.raises(ReaderError, match="no such file"):
        read("fusion", [tmp_path / "missing.csv"])
    p = _write(tmp_path, "t,ax,ay,az", [[0, 0, 0, 1], [0, 0, 0, 1]])
    with pytest.raises(ReaderError, match="not strictly increasing"):
        read("csv", [p], columns={"t": "t", "acc_x": "ax", "acc_y": "ay", "acc_z": "az"}, units={"t": "s", "acc": "g"})


def test_npz_round_trip(tmp_path):
    rec = read("mpu6050", [DATA / "tomisuarez_mpu6050" / "example_data_calibration_head.csv"])
    save_recording(rec, tmp_path / "r.npz")
    back = load_recording(tmp_path / "r.npz")
    np.testing.assert_array_equal(back.acc, rec.acc)
    np.testing.assert_array_equal(back.t, rec.t)
    assert back.acc_unit == "LSB" and back.fs == 100.0
    assert back.extra["meta_initialization_time"] == 36.5


@pytest.mark.parametrize("name", ["imu_tk_xsens_multipos/xsens.npz", "tomisuarez_mpu6050/calibration.npz",
                                  "imucal_ferraris_example/session.npz", "tumvi_room1_512_16/room1.npz",
                                  "xio_fusion_sensor_data/sensor_data.npz",
                                  "broad_07_undisturbed_fast_rotation_B/07_undisturbed_fast_rotation_B.npz",
                                  "broad_21_undisturbed_fast_combined/21_undisturbed_fast_combined.npz"])
def test_compact_data_files_follow_conventions(name):
    rec = load_recording(DATA / name)
    n = rec.n
    assert rec.t.dtype == np.float64 and np.all(np.diff(rec.t) > 0)
    assert rec.acc.shape == (n, 3) and rec.gyr.shape == (n, 3)
    assert rec.acc_unit in ("g", "LSB") and rec.gyr_unit in ("rad/s", "LSB")


def test_read_returns_validated_recording():
    d = DATA / "tumvi_room1_512_16"
    rec = read("tumvi", [d / "imu_head.csv", d / "gt_head.csv"])
    assert isinstance(rec, Recording) and rec.acc_unit == "g" and rec.quat_ref.shape == (rec.n, 4)
    assert rec.gt_quat.shape[1] == 4 and rec.gt_pos.shape == (rec.gt_t.shape[0], 3)
    assert rec.ref_valid.dtype == bool and rec.t0 > 1e9  # Unix time of t = 0


# ----------------------------------------------------------------------------- BROAD (.mat)

BROAD_FS = 285.714  # README: sampling_rate 285.714 Hz, t = k / 285.714 s


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v' = q v q* for Hamilton [w, x, y, z] quaternions (numpy, independent of jaxcal)."""
    w, u = q[:, :1], q[:, 1:]
    c = 2.0 * np.cross(u, v)
    return v + w * c + np.cross(u, c)


def _broad_mat(tmp_path, n: int = 40, drop: str | None = None, **change) -> Path:
    """A tiny BROAD-like file: at rest with the IMU's y axis up (90 deg about x), mocap gaps."""
    c = math.sqrt(0.5)
    q = np.tile([c, c, 0.0, 0.0], (n, 1))
    q[[4, 10, 11, 12]] = np.nan
    pos = np.tile([0.1, -0.5, 1.2], (n, 1))
    pos[[3, 4, 5]] = np.nan
    v = {"imu_acc": np.tile([0.0, G0, 0.0], (n, 1)), "imu_gyr": np.full((n, 3), 1e-3),
         "imu_mag": np.tile([0.0, 15.0, -40.0], (n, 1)), "opt_quat": q, "opt_pos": pos,
         "sampling_rate": np.array([[100.0]]), "movement": (np.arange(n)[:, None] >= n // 2).astype(np.uint8),
         "info": "synthetic BROAD-like trial"}
    v.update(change)
    v.pop(drop, None)
    p = tmp_path / "tiny.mat"
    scipy_io().savemat(p, v)
    return p


def scipy_io():
    import scipy.io

    return scipy.io


@pytest.mark.parametrize("trial,first_valid", [("07_undisturbed_fast_rotation_B", 791),
                                                ("21_undisturbed_fast_combined", 1372)])
def test_broad_real_format_excerpt_units_time_gaps_and_quaternion_convention(trial, first_valid):
    rec = read("broad", [DATA / f"broad_{trial}" / f"{trial}_head.mat"])
    assert rec.acc.shape == (2000, 3) and rec.gyr.shape == (2000, 3) and rec.mag.shape == (2000, 3)
    assert rec.pos_ref.shape == (2000, 3) and rec.quat_ref.shape == (2000, 4)
    assert rec.acc_unit == "g" and rec.gyr_unit == "rad/s"
    assert rec.fs == pytest.approx(BROAD_FS, rel=1e-5)
    np.testing.assert_allclose(np.diff(rec.t), 1 / BROAD_FS, rtol=1e-5)
    assert rec.t[0] == 0.0
    # static start (movement begins later): |f| ~ 1 g (README: 9.82 m/s^2)
    assert not rec.extra["movement"].any() and rec.extra["movement"].dtype == bool
    assert np.median(np.linalg.norm(rec.acc, axis=1)) == pytest.approx(9.82 / G0, rel=0.01)
    # README: opt_quat NaN from the start up to first_valid; NaN kept, rows valid after it
    ok = rec.ref_valid
    assert not ok[:first_valid].any() and ok[first_valid]
    assert np.isnan(rec.quat_ref[:first_valid]).all()
    np.testing.assert_allclose(np.linalg.norm(rec.quat_ref[ok], axis=1), 1.0, atol=1e-12)
    # README check: the static accelerometer rotated by quat_ref into ENU is [0.01, -0.04, 9.82] m/s^2
    f_world = _rotate(rec.quat_ref[ok][:500], rec.acc[ok][:500]).mean(axis=0)
    assert f_world[2] == pytest.approx(9.82 / G0, rel=0.01)
    assert np.all(np.abs(f_world[:2]) < 0.06 / G0)


@pytest.mark.parametrize("trial,n,seconds,quat_nan,pos_nan,gap_rows,gyr_max", [
    ("07_undisturbed_fast_rotation_B", 52518, 183.8, 1594, 0, 1594, 25.4),
    ("21_undisturbed_fast_combined", 53612, 187.6, 2226, 219, 2226, 14.2),  # pos gaps lie inside quat gaps
])
def test_broad_compact_copies_keep_the_readme_gaps(trial, n, seconds, quat_nan, pos_nan, gap_rows, gyr_max):
    path = DATA / f"broad_{trial}" / f"{trial}.npz"
    assert path.stat().st_size < 3e6
    rec = load_recording(path)
    assert rec.n == n and rec.acc_unit == "g" and rec.gyr_unit == "rad/s"
    assert rec.fs == pytest.approx(BROAD_FS, rel=1e-5) and rec.n / rec.fs == pytest.approx(seconds, abs=0.05)
    np.testing.assert_allclose(np.diff(rec.t), 1 / BROAD_FS, rtol=1e-5)
    q_gap, p_gap = np.isnan(rec.quat_ref).any(axis=1), np.isnan(rec.pos_ref).any(axis=1)
    assert q_gap.sum() == quat_nan and p_gap.sum() == pos_nan
    assert np.isnan(rec.quat_ref[q_gap]).all() and np.isnan(rec.pos_ref[p_gap]).all()  # whole rows
    ok = rec.ref_valid
    assert ok.dtype == bool and (~ok).sum() == gap_rows and (~ok).sum() == (q_gap | p_gap).sum()
    assert np.linalg.norm(rec.gyr, axis=1).max() == pytest.approx(gyr_max, abs=0.1)  # README peak (14.15: "14.2")
    still = ~rec.extra["movement"] & ok
    f_world = _rotate(rec.quat_ref[still][:500].astype(np.float64), rec.acc[still][:500].astype(np.float64))
    assert f_world.mean(axis=0)[2] == pytest.approx(9.82 / G0, rel=0.01)


def test_broad_synthetic_file_units_gaps_and_convention(tmp_path):
    rec = read("broad", [_broad_mat(tmp_path)])
    n = 40
    np.testing.assert_allclose(rec.t, np.arange(n) / 100.0)
    assert rec.fs == 100.0
    np.testing.assert_allclose(rec.acc, [[0, 1, 0]] * n, atol=1e-12)  # m/s^2 / 9.80665 -> g
    np.testing.assert_allclose(rec.gyr, 1e-3)
    np.testing.assert_allclose(rec.mag[0], [0, 15, -40])
    ok = rec.ref_valid
    assert ok.shape == (n,) and ok.dtype == bool
    assert sorted(np.flatnonzero(~ok)) == [3, 4, 5, 10, 11, 12]  # union of the pos and quat gaps
    assert np.isnan(rec.pos_ref[[3, 4, 5]]).all() and np.isfinite(rec.pos_ref[10:13]).all()  # not filled
    assert np.isnan(rec.quat_ref[[4, 10, 11, 12]]).all() and np.isfinite(rec.quat_ref[3]).all()
    # IMU y axis up: quat_ref (body to world) takes the specific force to +1 g along world z
    np.testing.assert_allclose(_rotate(rec.quat_ref[ok], rec.acc[ok]), [[0, 0, 1]] * ok.sum(), atol=1e-12)
    assert rec.extra["movement"].tolist() == [False] * 20 + [True] * 20
    assert rec.extra["meta_info"] == "synthetic BROAD-like trial"


@pytest.mark.parametrize("var", ["imu_acc", "imu_gyr", "opt_quat", "opt_pos", "sampling_rate"])
def test_broad_missing_variable_is_named(tmp_path, var):
    p = _broad_mat(tmp_path, drop=var)
    with pytest.raises(ReaderError, match=f"variable '{var}' not found") as e:
        read("broad", [p])
    assert str(p) in str(e.value) and "\n" not in str(e.value)


def test_broad_bad_values_are_refused(tmp_path):
    pos = np.zeros((40, 3))
    pos[7, 1] = np.inf
    with pytest.raises(ReaderError, match=r"variable 'opt_pos' row 7: infinite"):
        read("broad", [_broad_mat(tmp_path, opt_pos=pos)])
    with pytest.raises(ReaderError, match=r"variable 'imu_gyr': expected shape \(40, 3\)"):
        read("broad", [_broad_mat(tmp_path, imu_gyr=np.zeros((39, 3)))])
    with pytest.raises(ReaderError, match=r"variable 'opt_quat' .*not a unit quaternion"):
        read("broad", [_broad_mat(tmp_path, opt_quat=np.tile([2.0, 0, 0, 0], (40, 1)))])
    with pytest.raises(ReaderError, match=r"variable 'imu_acc'.*not near 1 g"):
        read("broad", [_broad_mat(tmp_path, imu_acc=np.tile([0.0, G0 * G0, 0.0], (40, 1)))])
    junk = tmp_path / "junk.mat"
    junk.write_text("hello\n" * 20)
    with pytest.raises(ReaderError, match="not a readable MATLAB .mat file"):
        read("broad", [junk])
    with pytest.raises(ReaderError, match="takes 1..1 files"):
        read("broad", [junk, junk])


def test_broad_recording_round_trip_keeps_nan_gaps(tmp_path):
    rec = read("broad", [_broad_mat(tmp_path)])
    for name in ("r.npz", "r.csv"):
        save_recording(rec, tmp_path / name)
        back = load_recording(tmp_path / name)
        np.testing.assert_array_equal(back.pos_ref, rec.pos_ref)  # NaN rows compare equal here
        np.testing.assert_array_equal(back.quat_ref, rec.quat_ref)
        assert np.isnan(back.pos_ref[[3, 4, 5]]).all()
        np.testing.assert_array_equal(back.ref_valid, rec.ref_valid)
        assert back.ref_valid.dtype == bool
        np.testing.assert_array_equal(back.mag, rec.mag)
        np.testing.assert_array_equal(back.extra["movement"], rec.extra["movement"])


def test_cli_import_broad(tmp_path, capsys):
    from jaxcal.cli import main

    mat = _broad_mat(tmp_path)
    out = tmp_path / "x.npz"
    assert main(["import", "broad", str(mat), "--out", str(out)]) == 0
    rec = load_recording(out)
    assert rec.n == 40 and rec.acc_unit == "g" and np.isnan(rec.pos_ref[3]).all()
    assert "wrote" in capsys.readouterr().err
    assert main(["import", "broad", str(mat), "--fs", "100", "--out", str(tmp_path / "y.npz")]) == 2
    assert not (tmp_path / "y.npz").exists()
