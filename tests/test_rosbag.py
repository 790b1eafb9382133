"""``jaxcal import rosbag``: bags of all three kinds (ROS1 ``.bag``, ROS2 sqlite3, ROS2 MCAP) written
here with ``rosbags``' own writers, imported through the command line, compared with what was written.

Truth: the IMU samples and stamps written into each bag (exact float64 / integer ns), a pose track
whose interpolation has a closed form (position linear in time, rotation at a constant rate about one
axis, so linear interpolation and slerp reproduce it), and, as a second implementation, jaxcal's own
``tumvi`` CSV reader on the TUM-VI sample written into a bag.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from jaxcal import rosbag
from jaxcal.cli import main
from jaxcal.readers import read
from jaxcal.recording import Recording, load_recording

rosbags = pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

DATA = Path(__file__).resolve().parent.parent / "data"
G0 = 9.80665
KINDS = ("ros1", "sqlite3", "mcap")
BASE_NS = 1_700_000_000_123_456_789  # a 2023 Unix time in ns: needs all 61 bits, float64 cannot hold it
N, M = 40, 18  # IMU samples (200 Hz), pose samples (100 Hz)
V = np.array([0.3, -0.2, 0.1])  # m/s, pose track velocity
P0 = np.array([1.0, 2.0, 0.5])  # m, position at t = 0 (the first IMU stamp)
W_RATE = 2.0  # rad/s about AXIS
AXIS = np.array([1.0, 2.0, 2.0]) / 3.0


# ----------------------------------------------------------------------------- writing bags


def _typestore(kind: str) -> Any:
    if kind != "ros1":
        return get_typestore(Stores.ROS2_HUMBLE)
    ts = get_typestore(Stores.ROS1_NOETIC)  # without tf messages: registered here from their ROS1 definitions
    for name in ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage"):
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", name))
    return ts


def _header(ts: Any, ns: int, frame: str) -> Any:
    H, T = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    seq = {"seq": 0} if "seq" in H.__dataclass_fields__ else {}  # ROS1 headers carry a sequence number
    return H(**seq, stamp=T(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame)


def _vec3(ts: Any, v: Any) -> Any:
    return ts.types["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _quat(ts: Any, q_xyzw: Any) -> Any:
    return ts.types["geometry_msgs/msg/Quaternion"](*[float(c) for c in q_xyzw])


def imu_msg(ts: Any, ns: int, acc: Any, gyr: Any, acc_cov0: float = 0.0) -> Any:
    cov = np.zeros(9)
    return ts.types["sensor_msgs/msg/Imu"](
        header=_header(ts, ns, "imu_link"), orientation=_quat(ts, [0, 0, 0, 1]),
        orientation_covariance=np.r_[-1.0, np.zeros(8)], angular_velocity=_vec3(ts, gyr), angular_velocity_covariance=cov,
        linear_acceleration=_vec3(ts, acc), linear_acceleration_covariance=np.r_[acc_cov0, np.zeros(8)])


def _pose(ts: Any, p: Any, q_xyzw: Any) -> Any:
    P = ts.types["geometry_msgs/msg/Pose"]
    return P(position=ts.types["geometry_msgs/msg/Point"](*[float(c) for c in p]), orientation=_quat(ts, q_xyzw))


def _transform(ts: Any, ns: int, child: str, p: Any, q_xyzw: Any) -> Any:
    Tr = ts.types["geometry_msgs/msg/Transform"]
    return ts.types["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, ns, "world"), child_frame_id=child, transform=Tr(translation=_vec3(ts, p), rotation=_quat(ts, q_xyzw)))


def pose_msg(ts: Any, msgtype: str, ns: int, p: Any, q_xyzw: Any) -> Any:
    """One message of ``msgtype`` holding the body's pose (tf: beside another frame's)."""
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return ts.types[msgtype](header=_header(ts, ns, "world"), pose=_pose(ts, p, q_xyzw))
    if msgtype == "geometry_msgs/msg/PoseWithCovarianceStamped":
        pwc = ts.types["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(ts, p, q_xyzw), covariance=np.zeros(36))
        return ts.types[msgtype](header=_header(ts, ns, "world"), pose=pwc)
    if msgtype == "nav_msgs/msg/Odometry":
        pwc = ts.types["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(ts, p, q_xyzw), covariance=np.zeros(36))
        tw = ts.types["geometry_msgs/msg/TwistWithCovariance"](
            twist=ts.types["geometry_msgs/msg/Twist"](linear=_vec3(ts, [0, 0, 0]), angular=_vec3(ts, [0, 0, 0])),
            covariance=np.zeros(36))
        return ts.types[msgtype](header=_header(ts, ns, "world"), child_frame_id="body", pose=pwc, twist=tw)
    if msgtype == "geometry_msgs/msg/TransformStamped":
        return _transform(ts, ns, "body", p, q_xyzw)
    assert msgtype in ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
    other = _transform(ts, ns, "other", [9.0, 9.0, 9.0], [0, 0, 0, 1])
    return ts.types[msgtype](transforms=[other, _transform(ts, ns, "body", p, q_xyzw)])


def write_bag(path: Path, kind: str, topics: dict[str, tuple[str, list[tuple[int, Any]]]], compress: str = "") -> Path:
    """A bag of ``kind`` with ``topic -> (msgtype, [(receive ns, message), ...])``; returns the path to import.

    ``compress``: ROS1 ``"lz4"`` / ``"bz2"`` chunks; ROS2 zstd by ``"file"``, ``"message"`` or ``"storage"`` (MCAP chunks).
    """
    ts = _typestore(kind)
    if kind == "ros1":
        path = path.with_suffix(".bag")
        w1 = Writer1(path)
        if compress:
            w1.set_compression(Writer1.CompressionFormat[compress.upper()])
        with w1 as w:
            for topic, (msgtype, msgs) in topics.items():
                c = w.add_connection(topic, msgtype, typestore=ts)
                for t, m in msgs:
                    w.write(c, t, ts.serialize_ros1(m, msgtype))
        return path
    plugin = StoragePlugin.MCAP if kind.startswith("mcap") else StoragePlugin.SQLITE3
    w2 = Writer2(path, version=9, storage_plugin=plugin)
    if compress:
        w2.set_compression(CompressionMode[compress.upper()], CompressionFormat.ZSTD)
    with w2 as w:
        for topic, (msgtype, msgs) in topics.items():
            c = w.add_connection(topic, msgtype, typestore=ts)
            for t, m in msgs:
                w.write(c, t, ts.serialize_cdr(m, msgtype))
    return next(path.glob("*.mcap")) if kind == "mcap-file" else path


class Truth:
    """Known IMU samples (stamps with integer-ns jitter, receive times after them) and a pose track."""

    def __init__(self, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        jitter = rng.integers(-1000, 1001, N)
        jitter[0] = 0
        self.ns = BASE_NS + 5_000_000 * np.arange(N, dtype=np.int64) + jitter
        self.recv = self.ns + 3_000_000 + 17 * np.arange(N, dtype=np.int64)
        self.acc = rng.normal(size=(N, 3)) + [0.0, 0.0, 9.81]  # m/s^2
        self.gyr = rng.normal(scale=0.5, size=(N, 3))  # rad/s
        self.pose_ns = BASE_NS + 2_000_000 + 10_000_000 * np.arange(M, dtype=np.int64)  # 2 ms .. 172 ms
        tp = (self.pose_ns - BASE_NS) / 1e9
        self.pos = P0 + V * tp[:, None]
        self.q_wxyz = quat_at(tp)

    def imu_msgs(self, ts: Any, acc_cov0: float = 0.0) -> list[tuple[int, Any]]:
        return [(int(r), imu_msg(ts, int(s), a, g, acc_cov0)) for r, s, a, g in zip(self.recv, self.ns, self.acc, self.gyr)]

    def pose_msgs(self, ts: Any, msgtype: str) -> list[tuple[int, Any]]:
        return [(int(s) + 1_000_000, pose_msg(ts, msgtype, int(s), p, np.r_[q[1:], q[0]]))
                for s, p, q in zip(self.pose_ns, self.pos, self.q_wxyz)]


def quat_at(t: np.ndarray) -> np.ndarray:
    """Hamilton [w, x, y, z] of a constant-rate rotation about AXIS (closed form, numpy only)."""
    half = 0.5 * W_RATE * np.asarray(t)
    return np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * AXIS], axis=1)


def run(capsys, *argv: Any) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


def _import_imu0(capsys, bag, tmp_path) -> Recording:
    """``jaxcal import rosbag BAG --imu-topic /imu0``, which must succeed; the recording it wrote."""
    out = tmp_path / "rec.npz"
    code, err = run(capsys, "import", "rosbag", bag, "--imu-topic", "/imu0", "--out", out)
    assert code == 0, err
    return load_recording(out)


def refused(capsys, argv: list, out: Path, *needles: str) -> str:
    """Exit 2, one stderr line holding every needle, nothing written."""
    code, err = run(capsys, *argv)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    for s in needles:
        assert s in lines[0], (s, lines[0])
    assert not out.exists()
    return lines[0]


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("kind", KINDS + ("mcap-file",))
def test_imu_round_trip_exact(tmp_path, capsys, kind):
    """t from header stamps (integer ns, jitter included), acc in g, gyr in rad/s: equal to what was written."""
    tr = Truth()
    ts = _typestore(kind)
    bag = write_bag(tmp_path / "b", kind, {"/imu0": ("sensor_msgs/msg/Imu", tr.imu_msgs(ts)),
                                            "/other": ("geometry_msgs/msg/PoseStamped", tr.pose_msgs(ts, "geometry_msgs/msg/PoseStamped"))})
    rec = _import_imu0(capsys, bag, tmp_path)
    assert rec.acc_unit == "g" and rec.gyr_unit == "rad/s" and rec.n == N
    np.testing.assert_array_equal(rec.t, (tr.ns - tr.ns[0]) / 1e9)  # integer ns difference, one rounding
    # the ns jitter survives: t differs from the 5 ms grid by exactly the jitter written
    np.testing.assert_allclose(rec.t * 1e9 - 5e6 * np.arange(N), tr.ns - BASE_NS - 5_000_000 * np.arange(N), atol=1e-6)
    np.testing.assert_array_equal(rec.acc, tr.acc / G0)
    np.testing.assert_array_equal(rec.gyr, tr.gyr)
    assert int(rec.extra["t0_ns"]) == BASE_NS and rec.t0 == BASE_NS / 1e9
    bag_kind = {"ros1": "ros1", "sqlite3": "ros2-sqlite3"}.get(kind, "ros2-mcap")
    assert str(rec.extra["meta_bag_kind"]) == bag_kind and str(rec.extra["meta_imu_frame_id"]) == "imu_link"
    assert str(rec.extra["meta_time_source"]) == "header" and str(rec.extra["meta_imu_topic"]) == "/imu0"
    assert rec.pos_ref is None and rec.gt_t is None


@pytest.mark.parametrize(("kind", "compress"), [("ros1", "lz4"), ("ros1", "bz2"), ("sqlite3", "file"), ("sqlite3", "message"),
                                                ("mcap", "storage"), ("mcap", "message")])
def test_compressed_bags(tmp_path, capsys, kind, compress):
    """Compressed bags (ROS1 lz4 / bz2 chunks; ROS2 zstd per file, per message or per MCAP chunk) read the same."""
    tr = Truth(7)
    bag = write_bag(tmp_path / "b", kind, {"/imu0": ("sensor_msgs/msg/Imu", tr.imu_msgs(_typestore(kind)))}, compress)
    rec = _import_imu0(capsys, bag, tmp_path)
    np.testing.assert_array_equal(rec.t, (tr.ns - tr.ns[0]) / 1e9)
    np.testing.assert_array_equal(rec.acc, tr.acc / G0)
    np.testing.assert_array_equal(rec.gyr, tr.gyr)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("msgtype", ["geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped",
                                     "tf2_msgs/msg/TFMessage"])
def test_pose_track_and_interpolation(tmp_path, capsys, kind, msgtype):
    """The pose track on its own clock: gt_* exactly as written (quaternion re-ordered to w, x, y, z);
    pos_ref / quat_ref at the IMU times equal the closed-form track; ref_valid False outside it."""
    tr = Truth(1)
    ts = _typestore(kind)
    topic = "/tf" if msgtype.startswith("tf") else "/mocap"
    bag = write_bag(tmp_path / "b", kind, {"/imu0": ("sensor_msgs/msg/Imu", tr.imu_msgs(ts)),
                                            topic: (msgtype, tr.pose_msgs(ts, msgtype))})
    out = tmp_path / "rec.npz"
    frame = ["--pose-frame", "/body"] if topic == "/tf" else []  # ROS1-style leading slash is ignored
    code, err = run(capsys, "import", "rosbag", bag, "--imu-topic", "/imu0", "--pose-topic", topic, *frame, "--out", out)
    assert code == 0, err
    rec = load_recording(out)
    np.testing.assert_array_equal(rec.gt_t, (tr.pose_ns - tr.ns[0]) / 1e9)
    np.testing.assert_array_equal(rec.gt_pos, tr.pos)
    np.testing.assert_allclose(rec.gt_quat, tr.q_wxyz, rtol=0, atol=4.5e-16)  # renormalised (2 ulp at 1): measured <= 1.1e-16
    t = rec.t
    inside = (t >= rec.gt_t[0]) & (t <= rec.gt_t[-1])
    assert inside.sum() == 34 and not inside[0]  # track: 2 .. 172 ms; IMU: 0 .. 195 ms
    np.testing.assert_array_equal(rec.ref_valid, inside)
    np.testing.assert_allclose(rec.pos_ref[inside], P0 + V * t[inside, None], rtol=0, atol=1e-15)  # measured 2.2e-16 m
    np.testing.assert_allclose(rec.quat_ref[inside], quat_at(t[inside]), rtol=0, atol=1e-15)  # measured 1.1e-16
    assert str(rec.extra["meta_pose_topic"]) == topic and str(rec.extra["meta_pose_frame_id"]) == "world"
    if msgtype != "geometry_msgs/msg/PoseStamped":
        assert str(rec.extra["meta_pose_child_frame_id"]) == "body"


@pytest.mark.parametrize(("kind", "msgtype"), [("mcap", "geometry_msgs/msg/PoseWithCovarianceStamped"),
                                               ("sqlite3", "nav_msgs/msg/Odometry"), ("ros1", "tf/msg/tfMessage")])
def test_other_pose_types(tmp_path, capsys, kind, msgtype):
    tr = Truth(2)
    ts = _typestore(kind)
    bag = write_bag(tmp_path / "b", kind, {"/imu0": ("sensor_msgs/msg/Imu", tr.imu_msgs(ts)),
                                            "/odom": (msgtype, tr.pose_msgs(ts, msgtype))})
    out = tmp_path / "rec.npz"
    frame = ["--pose-frame", "body"] if msgtype.startswith("tf/") else []
    code, err = run(capsys, "import", "rosbag", bag, "--imu-topic", "/imu0", "--pose-topic", "/odom", *frame, "--out", out)
    assert code == 0, err
    rec = load_recording(out)
    np.testing.assert_array_equal(rec.gt_pos, tr.pos)
    np.testing.assert_allclose(rec.gt_quat, tr.q_wxyz, rtol=0, atol=4.5e-16)  # 2 ulp at 1: measured <= 1.1e-16


def test_receive_time(tmp_path, capsys):
    """--time receive: t and the pose track from the bag's record times instead of the header stamps."""
    tr = Truth(3)
    ts = _typestore("sqlite3")
    bag = write_bag(tmp_path / "b", "sqlite3", {"/imu0": ("sensor_msgs/msg/Imu", tr.imu_msgs(ts)),
                                                 "/mocap": ("geometry_msgs/msg/PoseStamped",
                                                            tr.pose_msgs(ts, "geometry_msgs/msg/PoseStamped"))})
    out = tmp_path / "rec.npz"
    code, err = run(capsys, "import", "rosbag", bag, "--imu-topic", "/imu0", "--pose-topic", "/mocap", "--time", "receive",
                    "--out", out)
    assert code == 0, err
    rec = load_recording(out)
    np.testing.assert_array_equal(rec.t, (tr.recv - tr.recv[0]) / 1e9)
    np.testing.assert_array_equal(rec.gt_t, (tr.pose_ns + 1_000_000 - tr.recv[0]) / 1e9)
    assert int(rec.extra["t0_ns"]) == tr.recv[0] and str(rec.extra["meta_time_source"]) == "receive"


def test_out_of_order_stamps_sorted_and_exact_repeats_dropped(tmp_path, capsys):
    """A bag stores messages in receive order: header stamps that arrive out of order are sorted; a
    message recorded twice (same stamp, same values) counts once; two different ones with one stamp
    are refused."""
    tr = Truth(4)
    ts = _typestore("ros1")
    msgs = tr.imu_msgs(ts)
    msgs[5], msgs[6] = (msgs[5][0], msgs[6][1]), (msgs[6][0], msgs[5][1])  # stamps 6 then 5, receive order kept
    msgs.insert(11, (msgs[10][0] + 1, msgs[10][1]))  # the same message again
    bag = write_bag(tmp_path / "b", "ros1", {"/imu0": ("sensor_msgs/msg/Imu", msgs)})
    rec = _import_imu0(capsys, bag, tmp_path)
    np.testing.assert_array_equal(rec.t, (tr.ns - tr.ns[0]) / 1e9)
    np.testing.assert_array_equal(rec.acc, tr.acc / G0)
    # a different message with stamp 10's time
    msgs[11] = (msgs[11][0], imu_msg(ts, int(tr.ns[10]), tr.acc[10] + 1.0, tr.gyr[10]))
    bag2 = write_bag(tmp_path / "c", "ros1", {"/imu0": ("sensor_msgs/msg/Imu", msgs)})
    refused(capsys, ["import", "rosbag", bag2, "--imu-topic", "/imu0", "--out", tmp_path / "x.npz"],
            tmp_path / "x.npz", "same header stamp", str(int(tr.ns[10])), "--time receive")


def test_sensor_marked_absent_is_left_out(tmp_path, capsys):
    """linear_acceleration_covariance[0] = -1 in every message (no accelerometer data): a gyro-only recording."""
    tr = Truth(5)
    ts = _typestore("mcap")
    bag = write_bag(tmp_path / "b", "mcap", {"/imu0": ("sensor_msgs/msg/Imu", tr.imu_msgs(ts, acc_cov0=-1.0))})
    rec = _import_imu0(capsys, bag, tmp_path)
    assert rec.acc is None and rec.sensors() == ("gyr",)
    np.testing.assert_array_equal(rec.gyr, tr.gyr)


# ----------------------------------------------------------------------------- errors: exit 2, one line, nothing written


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict[str, Path]:
    """One bag per kind with an IMU topic, a PoseStamped topic, a tf topic and an empty Imu topic."""
    d = tmp_path_factory.mktemp("bags")
    tr = Truth(6)
    out = {}
    for kind in KINDS:
        ts = _typestore(kind)
        out[kind] = write_bag(d / kind, kind, {
            "/imu0": ("sensor_msgs/msg/Imu", tr.imu_msgs(ts)),
            "/mocap": ("geometry_msgs/msg/PoseStamped", tr.pose_msgs(ts, "geometry_msgs/msg/PoseStamped")),
            "/tf": ("tf2_msgs/msg/TFMessage", tr.pose_msgs(ts, "tf2_msgs/msg/TFMessage")),
            "/imu_empty": ("sensor_msgs/msg/Imu", []),
        })
    return out


@pytest.mark.parametrize("kind", KINDS)
def test_topic_errors_name_the_topic_and_list_the_bag(bags, tmp_path, capsys, kind):
    bag, out = bags[kind], tmp_path / "x.npz"
    imp = ["import", "rosbag", bag]
    line = refused(capsys, [*imp, "--imu-topic", "/imu", "--out", out], out,
                   "--imu-topic '/imu' not found", "/imu0 (sensor_msgs/msg/Imu, 40 messages)",
                   "/mocap (geometry_msgs/msg/PoseStamped, 18 messages)", "/tf (tf2_msgs/msg/TFMessage, 18 messages)")
    assert str(bag) in line
    refused(capsys, [*imp, "--imu-topic", "/mocap", "--out", out], out,
            "--imu-topic '/mocap' holds geometry_msgs/msg/PoseStamped, not sensor_msgs/msg/Imu", "/imu0 (sensor_msgs")
    refused(capsys, [*imp, "--imu-topic", "/imu0", "--pose-topic", "/imu_empty", "--out", out], out,
            "--pose-topic '/imu_empty' holds sensor_msgs/msg/Imu, not geometry_msgs/msg/PoseStamped")
    refused(capsys, [*imp, "--imu-topic", "/imu_empty", "--out", out], out, "'/imu_empty' (sensor_msgs/msg/Imu) has no messages")
    refused(capsys, [*imp, "--imu-topic", "/imu0", "--pose-topic", "/nope", "--out", out], out,
            "--pose-topic '/nope' not found", "/imu0 (sensor_msgs/msg/Imu")
    refused(capsys, [*imp, "--imu-topic", "/imu0", "--pose-topic", "/tf", "--out", out], out, "--pose-frame")
    refused(capsys, [*imp, "--imu-topic", "/imu0", "--pose-topic", "/tf", "--pose-frame", "hand", "--out", out], out,
            "no transform with child_frame_id 'hand'", "['body', 'other']")
    refused(capsys, [*imp, "--imu-topic", "/imu0", "--pose-topic", "/mocap", "--pose-frame", "body", "--out", out], out,
            "PoseStamped has none")


def test_path_and_flag_errors(bags, tmp_path, capsys):
    out = tmp_path / "x.npz"
    topic = ["--imu-topic", "/imu0", "--out", out]
    refused(capsys, ["import", "rosbag", tmp_path / "missing.bag", *topic], out, "missing.bag: no such file or directory")
    (tmp_path / "text.bag").write_text("not a bag\n")
    refused(capsys, ["import", "rosbag", tmp_path / "text.bag", *topic], out, "text.bag: not a readable ROS bag")
    (tmp_path / "junk.mcap").write_bytes(bytes(range(256)) * 8)
    refused(capsys, ["import", "rosbag", tmp_path / "junk.mcap", *topic], out, "junk.mcap: not a readable ROS bag")
    (tmp_path / "notes.txt").write_text("x\n")
    refused(capsys, ["import", "rosbag", tmp_path / "notes.txt", *topic], out, "not a ROS bag", "'.txt'")
    (tmp_path / "folder").mkdir()
    refused(capsys, ["import", "rosbag", tmp_path / "folder", *topic], out, "not a ROS2 bag directory (no metadata.yaml)")
    refused(capsys, ["import", "rosbag", bags["ros1"], "--out", out], out, "needs --imu-topic")
    refused(capsys, ["import", "rosbag", bags["ros1"], bags["mcap"], *topic], out,
            "parts of one split ROS1 recording", f"{bags['mcap']} is not one")
    refused(capsys, ["import", "rosbag", bags["mcap"], bags["sqlite3"], *topic], out, "give one ROS2 bag")
    refused(capsys, ["import", "rosbag", bags["ros1"], bags["ros1"], *topic], out, "a bag file is given twice")
    refused(capsys, ["import", "rosbag", bags["ros1"], "--fs", "100", *topic], out, "does not take --fs")
    refused(capsys, ["import", "rosbag", bags["ros1"], "--imu-topic", "/imu0", "--pose-frame", "body", "--out", out], out,
            "needs --pose-topic")
    refused(capsys, ["import", "tumvi", DATA / "tumvi_room1_512_16" / "imu_head.csv", *topic], out,
            "--imu-topic: only for the rosbag format")


def test_damaged_bags_never_traceback(bags, tmp_path, capsys):
    """Each kind cut short or with bytes overwritten (deterministic draws): imported whole (exit 0) or
    refused in one line with nothing written (exit 2)."""
    rng = np.random.default_rng(7)
    for kind, bag in bags.items():
        src = bag if bag.is_file() else next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
        data = src.read_bytes()
        for k in range(8):
            d = tmp_path / f"{kind}{k}"
            d.mkdir()
            if bag.is_dir():
                (d / "b").mkdir()
                (d / "b" / "metadata.yaml").write_bytes((bag / "metadata.yaml").read_bytes())
                target, path = d / "b" / src.name, d / "b"
            else:
                target = path = d / src.name
            if k % 2:
                damaged = data[: int(rng.integers(0, len(data)))]
            else:
                b = bytearray(data)
                at = rng.integers(0, len(b), 4)
                for i in at:
                    b[i] = int(rng.integers(0, 256))
                damaged = bytes(b)
            target.write_bytes(damaged)
            out = d / "out.npz"
            code, err = run(capsys, "import", "rosbag", path, "--imu-topic", "/imu0", "--out", out)
            assert code in (0, 2), err
            if code == 2:
                assert len([ln for ln in err.splitlines() if ln.strip()]) == 1 and "Traceback" not in err, err
                assert not out.exists()
            else:
                assert load_recording(out).n >= 2


@pytest.mark.parametrize("order", [(0, 1, 2), (2, 0, 1)])
def test_split_ros1_recording_reads_as_the_whole(tmp_path, capsys, order):
    """``rosbag record --split``: the parts, given in any order, import exactly as the unsplit bag,
    the pose track too (interpolated across the cut between parts)."""
    tr = Truth(3)
    ts = _typestore("ros1")
    imu, mocap = tr.imu_msgs(ts), tr.pose_msgs(ts, "geometry_msgs/msg/PoseStamped")
    whole = write_bag(tmp_path / "whole", "ros1", {"/imu0": ("sensor_msgs/msg/Imu", imu),
                                                   "/mocap": ("geometry_msgs/msg/PoseStamped", mocap)})
    cut_ns = [int(tr.recv[N // 3]), int(tr.recv[2 * N // 3])]  # parts split by receive time, as rosbag does

    def part(msgs: list, k: int) -> list:
        lo, hi = ([0] + cut_ns)[k], (cut_ns + [2**62])[k]
        return [(t, m) for t, m in msgs if lo <= t < hi]

    parts = [write_bag(tmp_path / f"run_{k}", "ros1", {"/imu0": ("sensor_msgs/msg/Imu", part(imu, k)),
                                                       "/mocap": ("geometry_msgs/msg/PoseStamped", part(mocap, k))})
             for k in range(3)]
    assert all(0 < rosbag.bag_topics(p)["/imu0"][1] < N for p in parts)
    assert rosbag.bag_topics(parts)["/imu0"] == ("sensor_msgs/msg/Imu", N)
    recs = []
    for i, paths in enumerate(([whole], [parts[k] for k in order])):
        out = tmp_path / f"rec{i}.npz"
        code, err = run(capsys, "import", "rosbag", *paths, "--imu-topic", "/imu0", "--pose-topic", "/mocap", "--out", out)
        assert code == 0, err
        recs.append(load_recording(out))
    a, b = recs
    for name in ("t", "acc", "gyr", "gt_t", "gt_pos", "gt_quat", "pos_ref", "quat_ref", "ref_valid"):
        np.testing.assert_array_equal(getattr(b, name), getattr(a, name), err_msg=name)
    assert a.t0 == b.t0 and int(a.extra["meta_bag_files"]) == 1 and int(b.extra["meta_bag_files"]) == 3
    np.testing.assert_array_equal(b.acc, tr.acc / G0)  # and both equal what was written


# ----------------------------------------------------------------------------- a second implementation: TUM-VI


def _tumvi_rows(path: Path) -> tuple[list[int], np.ndarray]:
    """The CSV's Unix time as exact integer ns (from the decimal text) and its other columns."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))[1:]
    ns = []
    for r in rows:
        sec, frac = r[0].split(".")
        ns.append(int(sec) * 10**9 + int(frac.ljust(9, "0")[:9]))
    return ns, np.array([[float(c) for c in r[1:]] for r in rows])


def test_tumvi_sample_through_a_ros1_bag_matches_the_tumvi_reader(tmp_path, capsys):
    """The TUM-VI room1 excerpt (ROS message fields exported to CSV) written back as sensor_msgs/Imu
    and geometry_msgs/TransformStamped into a ROS1 bag imports as jaxcal's ``tumvi`` reader reads the CSVs."""
    d = DATA / "tumvi_room1_512_16"
    ns, imu = _tumvi_rows(d / "imu_head.csv")  # angular_velocity.xyz, linear_acceleration.xyz
    gns, gt = _tumvi_rows(d / "gt_head.csv")  # translation.xyz, rotation.xyzw
    ts = _typestore("ros1")
    bag = write_bag(tmp_path / "room1", "ros1", {
        "/imu0": ("sensor_msgs/msg/Imu", [(s, imu_msg(ts, s, r[3:], r[:3])) for s, r in zip(ns, imu)]),
        "/vrpn_client/raw_transform": ("geometry_msgs/msg/TransformStamped",
                                       [(s, _transform(ts, s, "imu", r[:3], r[3:])) for s, r in zip(gns, gt)]),
    })
    out = tmp_path / "rec.npz"
    code, err = run(capsys, "import", "rosbag", bag, "--imu-topic", "/imu0", "--pose-topic", "/vrpn_client/raw_transform",
                    "--out", out)
    assert code == 0, err
    got = load_recording(out)
    want = read("tumvi", [d / "imu_head.csv", d / "gt_head.csv"])
    assert got.n == want.n == 399  # data rows of imu_head.csv
    np.testing.assert_array_equal(got.acc, want.acc)
    np.testing.assert_array_equal(got.gyr, want.gyr)
    np.testing.assert_array_equal(got.gt_pos, want.gt_pos)
    np.testing.assert_array_equal(got.gt_quat, want.gt_quat)
    np.testing.assert_array_equal(got.ref_valid, want.ref_valid)
    # time: the CSV reader parses Unix seconds into float64 (spacing 2.4e-7 s at 1.5e9 s), the bag keeps
    # integer ns: measured max |dt| 5.5e-8 s (t), 8.8e-8 s (gt_t), 2.4e-7 s (t0: one float64 spacing)
    np.testing.assert_allclose(got.t, want.t, rtol=0, atol=2.5e-7)
    np.testing.assert_allclose(got.gt_t, want.gt_t, rtol=0, atol=2.5e-7)
    assert math.isclose(got.t0, want.t0, rel_tol=0, abs_tol=4.8e-7)
    # the interpolated pose differs only through those time roundings: measured 5.3e-9 m and 1.3e-8
    ok = want.ref_valid
    np.testing.assert_allclose(got.pos_ref[ok], want.pos_ref[ok], rtol=0, atol=5e-8)
    np.testing.assert_allclose(got.quat_ref[ok], want.quat_ref[ok], rtol=0, atol=5e-8)


def test_bag_topics_lists_types_and_counts(bags):
    from jaxcal.rosbag import bag_topics

    want = {"/imu0": ("sensor_msgs/msg/Imu", N), "/mocap": ("geometry_msgs/msg/PoseStamped", M),
            "/tf": ("tf2_msgs/msg/TFMessage", M), "/imu_empty": ("sensor_msgs/msg/Imu", 0)}
    for bag in bags.values():
        assert bag_topics(bag) == want


def test_ros2_bags_without_message_definitions(tmp_path, capsys):
    """rosbag2 before Iron stored no message definitions: the standard layouts are used, and the
    samples come back exactly. A definition stored with the encoding 'unknown' (what rosbag2 writes
    when it lacked one) is refused in one line that says what to do, and doing it imports the bag."""
    import sqlite3

    tr = Truth()
    ts = _typestore("sqlite3")
    bag = write_bag(tmp_path / "b", "sqlite3", {"/imu0": ("sensor_msgs/msg/Imu", tr.imu_msgs(ts))})
    db = next(bag.glob("*.db3"))
    with sqlite3.connect(db) as con:
        con.execute("UPDATE message_definitions SET encoding = 'unknown', encoded_message_definition = ''")
    out = tmp_path / "rec.npz"
    line = refused(capsys, ["import", "rosbag", bag, "--imu-topic", "/imu0", "--out", out], out, "'unknown'",
                   "DELETE FROM message_definitions WHERE encoding = 'unknown'")
    with sqlite3.connect(db) as con:
        con.execute(line[line.index("DELETE"):line.index("'unknown'", line.index("DELETE")) + len("'unknown'")])
    rec = _import_imu0(capsys, bag, tmp_path)
    np.testing.assert_array_equal(rec.acc, tr.acc / G0)
    np.testing.assert_array_equal(rec.gyr, tr.gyr)
    np.testing.assert_array_equal(rec.t, (tr.ns - tr.ns[0]) / 1e9)


# ----------------------------------------------------------------------------- plausibility (issue 27)


def test_two_frames_on_one_imu_topic_refused(tmp_path, capsys):
    """Two IMUs on one topic became one 400 Hz recording."""
    tr = Truth(5)
    ts = _typestore("ros1")
    msgs = tr.imu_msgs(ts)
    for r, m in msgs[1::2]:
        m.header.frame_id = "imu_b"
    bag = write_bag(tmp_path / "b", "ros1", {"/imu0": ("sensor_msgs/msg/Imu", msgs)})
    refused(capsys, ["import", "rosbag", bag, "--imu-topic", "/imu0", "--out", tmp_path / "x.npz"],
            tmp_path / "x.npz", "2 frames", "imu_b", "imu_link", "two IMUs on one topic")


def test_header_clock_step_refused_receive_time_accepted(tmp_path, capsys):
    """A one-hour header-clock step was kept though the receive times span the bag evenly."""
    tr = Truth(6)
    ts = _typestore("mcap")
    msgs = [(int(r), imu_msg(ts, int(s) + (3600 * 10**9 if k >= N // 2 else 0), a, g))
            for k, (r, s, a, g) in enumerate(zip(tr.recv, tr.ns, tr.acc, tr.gyr))]
    bag = write_bag(tmp_path / "b", "mcap", {"/imu0": ("sensor_msgs/msg/Imu", msgs)})
    refused(capsys, ["import", "rosbag", bag, "--imu-topic", "/imu0", "--out", tmp_path / "x.npz"],
            tmp_path / "x.npz", "header clock step", "3600 s", f"message {N // 2}", "--time receive")
    code, err = run(capsys, "import", "rosbag", bag, "--imu-topic", "/imu0", "--time", "receive", "--out", tmp_path / "r.npz")
    assert code == 0, err
    np.testing.assert_array_equal(load_recording(tmp_path / "r.npz").t, (tr.recv - tr.recv[0]) / 1e9)


def test_pose_topic_that_never_overlaps_the_imu_refused(tmp_path, capsys):
    """A pose track an hour after the IMU was written without a word."""
    tr = Truth(7)
    ts = _typestore("sqlite3")
    late = 3600 * 10**9
    poses = [(int(r) + late, pose_msg(ts, "geometry_msgs/msg/PoseStamped", int(s) + late, p, np.r_[q[1:], q[0]]))
             for (r, _), s, p, q in zip(tr.pose_msgs(ts, "geometry_msgs/msg/PoseStamped"), tr.pose_ns, tr.pos, tr.q_wxyz)]
    bag = write_bag(tmp_path / "b", "sqlite3", {"/imu0": ("sensor_msgs/msg/Imu", tr.imu_msgs(ts)),
                                                 "/mocap": ("geometry_msgs/msg/PoseStamped", poses)})
    refused(capsys, ["import", "rosbag", bag, "--imu-topic", "/imu0", "--pose-topic", "/mocap", "--out", tmp_path / "x.npz"],
            tmp_path / "x.npz", "never overlaps the IMU", "/mocap")
