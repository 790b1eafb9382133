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

from jaxcal import readers
from jaxcal.readers import ReaderError, read_dict as read

DATA = Path(__file__).resolve().parent.parent / "data"
G0 = 9.80665


def test_imu_tk_ascii_counts_rate_and_factory_norm():
    d = DATA / "imu_tk_xsens_multipos"
    rec = read("imu_tk", [d / "xsens_acc_head.txt", d / "xsens_gyro_head.txt"])
    assert rec["acc"].shape == (400, 3) and rec["gyr"].shape == (400, 3)
    assert rec["acc"].dtype.kind == "i" and rec["acc_unit"] == "LSB"
    # README: first lines and 100 Hz
    np.testing.assert_array_equal(rec["acc"][0], [33108, 33329, 36429])
    np.testing.assert_array_equal(rec["gyr"][0], [32786, 32429, 32499])
    assert rec["t"][0] == pytest.approx(0.02984)
    assert rec["fs"] == pytest.approx(100.0, rel=1e-3)
    # at rest: factory offsets and 415 counts per m/s^2 give |f| = local g (9.817 m/s^2) within 1 %
    f = (rec["acc"] - np.array([33123, 33276, 32360])) / np.array([415.0, 413.0, 415.0])
    assert np.median(np.linalg.norm(f, axis=1)) == pytest.approx(9.81744, rel=0.01)


def test_imucal_physical_session_units_and_missing_unit_error():
    d = DATA / "imucal_ferraris_example"
    f = d / "example_ferraris_session_head.csv"
    rec = read("imucal", [f], fs=102.4, acc_unit="m/s^2", gyr_unit="deg/s")
    assert rec["acc"].shape == (399, 3) and rec["acc_unit"] == "g" and rec["gyr_unit"] == "rad/s"
    np.testing.assert_allclose(np.diff(rec["t"]), 1 / 102.4, rtol=1e-9)
    # README first line: acc_x 10.3321 m/s^2, gyr_x -0.61035 deg/s
    assert rec["acc"][0, 0] == pytest.approx(10.332114257812501 / G0)
    assert rec["gyr"][0, 0] == pytest.approx(math.radians(-0.6103515625))
    # the x_p hold is uncalibrated: norm 10.34 m/s^2 (README)
    assert np.median(np.linalg.norm(rec["acc"], axis=1)) == pytest.approx(10.34 / G0, rel=0.01)
    with pytest.raises(ReaderError, match="acc_x"):
        read("imucal", [f], fs=102.4)
    with pytest.raises(ReaderError, match="fs"):
        read("imucal", [f], acc_unit="m/s^2", gyr_unit="deg/s")
    with pytest.raises(ReaderError, match="acc_x.*unknown acc unit"):
        read("imucal", [f], fs=102.4, acc_unit="m/s", gyr_unit="deg/s")


def test_imucal_annotated_raw_counts_sections():
    d = DATA / "imucal_ferraris_example"
    rec = read("imucal", [d / "annotated_session_head.csv"], fs=204.8)
    assert rec["acc_unit"] == "LSB" and rec["acc"].dtype.kind == "i"
    assert list(rec["section_names"]) == ["x_a"]
    np.testing.assert_array_equal(rec["acc"][0], [-2052, -28, -73])
    assert rec["t"][0] == pytest.approx(1028 / 204.8)
    # x_a hold: x reads about -1 g at ~208.5 counts per m/s^2 (example_cal.json K_a)
    assert np.median(rec["acc"][:, 0]) / 208.5 == pytest.approx(-9.81, rel=0.02)


def test_mpu6050_header_lines_rate_and_datasheet_scale():
    rec = read("mpu6050", [DATA / "tomisuarez_mpu6050" / "example_data_calibration_head.csv"])
    assert rec["acc"].shape == (395, 3) and rec["fs"] == 100.0
    np.testing.assert_allclose(np.diff(rec["t"]), 0.01)
    np.testing.assert_array_equal(rec["acc"][0], [-12, -812, 15032])
    assert rec["meta_initialization_time"] == 36.5
    # static start, datasheet 16384 LSB/g: |f| within 10 % of 1 g (uncalibrated chip)
    norm = np.median(np.linalg.norm(rec["acc"] / rec["acc_lsb_per_g"], axis=1))
    assert 0.9 < norm < 1.1
    assert rec["gyr_lsb_per_rads"] == pytest.approx(131 * 180 / math.pi)


def test_mpu6050_missing_fs(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("Logging Type,0\nax,ay,az,gx,gy,gz\n1,2,3,4,5,6\n1,2,3,4,5,6\n")
    with pytest.raises(ReaderError, match="Fs"):
        read("mpu6050", [p])


def test_tumvi_quaternion_order_and_units():
    d = DATA / "tumvi_room1_512_16"
    rec = read("tumvi", [d / "imu_head.csv", d / "gt_head.csv"])
    assert rec["acc_unit"] == "g" and rec["gyr_unit"] == "rad/s"
    assert rec["acc"][0, 2] == pytest.approx(9.92376030285343 / G0)
    assert np.median(np.linalg.norm(rec["acc"], axis=1)) == pytest.approx(1.0, abs=0.05)
    assert np.median(np.diff(rec["t"])) == pytest.approx(1 / 200, rel=0.01)
    # ROS (x, y, z, w) -> conventions (w, x, y, z)
    np.testing.assert_allclose(rec["gt_quat"][0], [0.9996498117006686, 0.0037373092773871,
                                                   0.00971696346904, -0.024328319036143], atol=1e-9)
    q = rec["quat_ref"]
    ok = rec["ref_valid"]
    assert ok.mean() > 0.9 and not ok[0]  # gt starts 7.8 ms after the IMU
    np.testing.assert_allclose(np.linalg.norm(q[ok], axis=1), 1.0, atol=1e-9)
    assert np.all(q[ok, 0] > 0.99)  # near identity at the start, scalar first


def test_fusion_uneven_time_and_deg_to_rad():
    rec = read("fusion", [DATA / "xio_fusion_sensor_data" / "sensor_data_head.csv"])
    assert rec["acc"].shape == (399, 3) and rec["mag"].shape == (399, 3)
    assert rec["gyr"][0, 0] == pytest.approx(math.radians(0.01644619))
    assert rec["acc"][0, 2] == pytest.approx(0.9970807)
    dt = np.diff(rec["t"])
    assert dt.min() < 0.0095 or dt.max() > 0.0105 or np.median(dt) == pytest.approx(0.01008, rel=1e-3)
    assert np.median(np.linalg.norm(rec["acc"], axis=1)) == pytest.approx(1.0, abs=0.05)


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
    np.testing.assert_allclose(rec["t"], np.arange(5) * 0.005, atol=1e-9)
    np.testing.assert_allclose(rec["acc"], [[0, 0, 1]] * 5, atol=1e-12)
    np.testing.assert_allclose(rec["quat_ref"], [[c, s, 0, 0]] * 5, atol=1e-9)
    np.testing.assert_allclose(rec["pos_ref"], [[1, 2, 3]] * 5)


def _write(tmp_path, header, rows):
    p = tmp_path / "g.csv"
    p.write_text(header + "\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    return p


def test_generic_csv_mapping_and_units(tmp_path):
    p = _write(tmp_path, "time_ms,ax,ay,az,wx,wy,wz",
               [[0, 0, 0, 9.80665, 180, 0, 0], [12.5, 0, 9.80665, 0, 0, 90, 0], [20, 9.80665, 0, 0, 0, 0, 0]])
    cols = {"t": "time_ms", "acc_x": "ax", "acc_y": "ay", "acc_z": "az", "gyr_x": "wx", "gyr_y": "wy", "gyr_z": "wz"}
    rec = read("csv", [p], columns=cols, units={"t": "ms", "acc": "m/s^2", "gyr": "deg/s"})
    np.testing.assert_allclose(rec["t"], [0, 0.0125, 0.02])  # uneven kept
    np.testing.assert_allclose(rec["acc"], np.eye(3)[[2, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(rec["gyr"][0], [math.pi, 0, 0])
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
    assert rec["acc_unit"] == "g" and rec["gyr_unit"] == "LSB" and rec["gyr"].dtype.kind == "i"
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
    readers.save_npz(rec, tmp_path / "r.npz")
    back = readers.load_npz(tmp_path / "r.npz")
    np.testing.assert_array_equal(back["acc"], rec["acc"])
    np.testing.assert_array_equal(back["t"], rec["t"])
    assert back["acc_unit"] == "LSB" and back["fs"] == 100.0


@pytest.mark.parametrize("name", ["imu_tk_xsens_multipos/xsens.npz", "tomisuarez_mpu6050/calibration.npz",
                                  "imucal_ferraris_example/session.npz", "tumvi_room1_512_16/room1.npz",
                                  "xio_fusion_sensor_data/sensor_data.npz"])
def test_compact_data_files_follow_conventions(name):
    rec = readers.load_npz(DATA / name)
    n = rec["t"].shape[0]
    assert rec["t"].dtype == np.float64 and np.all(np.diff(rec["t"]) > 0)
    assert rec["acc"].shape == (n, 3) and rec["gyr"].shape == (n, 3)
    assert rec["acc_unit"] in ("g", "LSB") and rec["gyr_unit"] in ("rad/s", "LSB")


def test_read_returns_validated_recording():
    from jaxcal.readers import read as read_rec
    from jaxcal.recording import Recording

    d = DATA / "tumvi_room1_512_16"
    rec = read_rec("tumvi", [d / "imu_head.csv", d / "gt_head.csv"])
    assert isinstance(rec, Recording) and rec.acc_unit == "g" and rec.quat_ref.shape == (rec.n, 4)
    assert rec.extra["gt_quat"].shape[1] == 4
