"""ROS bags (ROS1 ``.bag``, ROS2 sqlite3 and MCAP) -> :class:`jaxcal.recording.Recording`.

``jaxcal import rosbag BAG [BAG ...] --imu-topic T [--pose-topic P] [--pose-frame F]`` reads one bag
with the pure-Python ``rosbags`` library (no ROS installation): a ROS1 ``.bag`` file, a ROS2 bag
directory (``metadata.yaml`` with sqlite3 or MCAP storage; its split files are read together), or a
bare ROS2 ``.mcap`` / ``.db3`` file. Several ROS1 ``.bag`` files are the parts of one split recording
(``rosbag record --split``): their messages are merged by time, in any order the files are given.

What maps to what (CONVENTIONS.md):

* ``sensor_msgs/msg/Imu`` on ``imu_topic``: ``linear_acceleration`` (m/s^2, specific force) ->
  ``acc`` in g (divided by 9.80665), ``angular_velocity`` (rad/s) -> ``gyr`` in rad/s, the same
  numbers as a TUM-VI / EuRoC CSV of the topic. A sensor whose covariance element 0 is -1 in every
  message ("no data", ROS REP 145 / the message's comment) is left out. ``orientation`` (the
  device's own filter output) is not a reference and is not read.
* Time: the message **header stamp** (default) or, with ``time="receive"``, the bag's receive
  (record) time. Stamps are kept as integer nanoseconds until ``t = (stamp - stamp_0) / 1e9`` s
  counts from the first IMU sample; ``t0`` (s) and ``t0_ns`` (exact int64) keep the absolute offset.
  Messages are sorted by stamp (a bag stores them in receive order); exact repeats (same stamp,
  same values) are dropped, and two different messages with one stamp are refused.
* Reference pose on ``pose_topic`` (motion capture): ``geometry_msgs/msg/PoseStamped`` or
  ``PoseWithCovarianceStamped`` (``pose.position``, ``pose.orientation``),
  ``geometry_msgs/msg/TransformStamped`` (``transform.translation``, ``transform.rotation``),
  ``nav_msgs/msg/Odometry`` (``pose.pose``) and ``tf2_msgs/msg/TFMessage`` or ROS1's ``tf/tfMessage``
  (the transforms whose
  ``child_frame_id`` is ``pose_frame``; required there). ROS poses are the child (body) frame in
  the parent (``header.frame_id``) frame, i.e. body to world, and ROS quaternions are
  ``x, y, z, w``: re-ordered to the conventions' Hamilton scalar-first ``[w, x, y, z]``. The track
  is on its own clock: as for TUM-VI and EuRoC (:mod:`jaxcal.formats.euroc`), it is interpolated to the
  IMU times (``pos_ref``, ``quat_ref``, ``ref_valid`` False across gaps over ``max_gap`` s and
  outside the track) and kept as ``gt_t`` / ``gt_pos`` / ``gt_quat``.
* ``extra``: ``meta_bag_kind`` (``"ros1"``, ``"ros2-sqlite3"``, ``"ros2-mcap"``),
  ``meta_bag_files`` (the number of files read: more than 1 for a split ROS1 recording),
  ``meta_imu_topic``, ``meta_imu_frame_id``, ``meta_time_source`` (``"header"`` / ``"receive"``),
  and with a pose ``meta_pose_topic``, ``meta_pose_frame_id`` (parent), ``meta_pose_child_frame_id``
  (where the message type has one).

Like the other readers, this module reads files by design (a recording I/O boundary) and holds
no state. Bad input raises :class:`jaxcal.formats.table.ReaderError` with one line naming the bag, the
topic and the reason (a missing topic lists the topics the bag has, with their types).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.constants import G0
from jaxcal.flags import Flag
from jaxcal.formats.base import Format
from jaxcal.formats.pose import attach_pose, unit_quaternions
from jaxcal.formats.table import ReaderError, finish_recording
from jaxcal.recording import Recording

__all__ = ["FORMAT", "IMU_TYPE", "POSE_TYPES", "TIME_SOURCES", "read_rosbag", "bag_topics"]

IMU_TYPE = "sensor_msgs/msg/Imu"
POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "geometry_msgs/msg/TransformStamped",
    "nav_msgs/msg/Odometry",
    "tf2_msgs/msg/TFMessage",
    "tf/msg/tfMessage",
)
_TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
TIME_SOURCES = ("header", "receive")
_ROS2_SUFFIXES = (".mcap", ".db3")
_LIST_AT_MOST = 15  # topics named in a "not found" message


def _bag_kind(path: Path) -> str:
    """``"ros1"``, ``"ros2-sqlite3"`` or ``"ros2-mcap"`` from the path; refuses anything else."""
    if not path.exists():
        raise ReaderError(f"{path}: no such file or directory")
    if path.is_dir():
        meta = path / "metadata.yaml"
        if not meta.is_file():
            raise ReaderError(f"{path}: not a ROS2 bag directory (no metadata.yaml); give a ROS1 .bag file, "
                              "a ROS2 bag directory or an .mcap / .db3 file")
        try:
            text = meta.read_text(encoding="utf-8", errors="replace")
        except OSError as e:
            raise ReaderError(f"{meta}: cannot read ({e.strerror or e})") from None
        return "ros2-mcap" if "storage_identifier: mcap" in text else "ros2-sqlite3"
    suffix = path.suffix.lower()
    if suffix == ".bag":
        return "ros1"
    if suffix in _ROS2_SUFFIXES:
        return "ros2-mcap" if suffix == ".mcap" else "ros2-sqlite3"
    raise ReaderError(f"{path}: not a ROS bag (expected a ROS1 .bag file, a ROS2 bag directory or an "
                      f".mcap / .db3 file, got {suffix or 'no suffix'!r})")


def _one_line(e: BaseException) -> str:
    return f"{type(e).__name__}: {' '.join(str(e).split())[:160]}"


def _topic_list(topics: dict[str, Any], want: Sequence[str] | None = None) -> str:
    """``/a (type, N messages), ...`` (only topics of a type in ``want`` when given)."""
    items = [(k, v) for k, v in sorted(topics.items()) if want is None or v.msgtype in want]
    if not items:
        return "none"
    text = ", ".join(f"{k} ({v.msgtype or 'mixed types'}, {v.msgcount} messages)" for k, v in items[:_LIST_AT_MOST])
    return text + (f", and {len(items) - _LIST_AT_MOST} more" if len(items) > _LIST_AT_MOST else "")


def _check_topic(bag: str, topics: dict[str, Any], topic: str, flag: str, types: Sequence[str]) -> str:
    """The topic's message type, after checking it exists, has one allowed type and holds messages."""
    if topic not in topics:
        raise ReaderError(f"{bag}: {flag} {topic!r} not found; the bag has {_topic_list(topics)}")
    info = topics[topic]
    if info.msgtype not in types:
        held = info.msgtype or "several message types"
        good = _topic_list(topics, types)
        raise ReaderError(f"{bag}: {flag} {topic!r} holds {held}, not {' / '.join(types)}; topics of that type: {good}")
    if info.msgcount == 0:
        raise ReaderError(f"{bag}: {flag} {topic!r} ({info.msgtype}) has no messages")
    return info.msgtype


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _sorted_unique(ns: list[int], values: np.ndarray, where: str, time: str) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (int64 ns) and their rows sorted by stamp; exact repeats dropped, conflicting ones refused."""
    stamps = np.asarray(ns, dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    stamps, values = stamps[order], values[order]
    dup = np.flatnonzero(np.diff(stamps) == 0)
    if dup.size:
        differ = dup[np.any(values[dup] != values[dup + 1], axis=1)]
        if differ.size:
            hint = " (try --time receive)" if time == "header" else ""
            raise ReaderError(f"{where}: two different messages carry the same {time} stamp "
                              f"{int(stamps[differ[0]])} ns{hint}")
        keep = np.ones(stamps.size, dtype=bool)
        keep[dup + 1] = False
        stamps, values = stamps[keep], values[keep]
    return stamps, values


def _vec(v: Any) -> tuple[float, float, float]:
    return (float(v.x), float(v.y), float(v.z))


def _quat_wxyz(q: Any) -> tuple[float, float, float, float]:
    return (float(q.w), float(q.x), float(q.y), float(q.z))


def _pose_rows(msgtype: str, msg: Any) -> list[tuple[Any, str, str, tuple[float, ...]]]:
    """``(header, parent frame, child frame, (x, y, z, qw, qx, qy, qz))`` of each pose in one message."""
    if msgtype in _TF_TYPES:
        return [row for tf in msg.transforms for row in _pose_rows("geometry_msgs/msg/TransformStamped", tf)]
    if msgtype == "geometry_msgs/msg/TransformStamped":
        child, tr = msg.child_frame_id, msg.transform
        return [(msg.header, msg.header.frame_id, child, _vec(tr.translation) + _quat_wxyz(tr.rotation))]
    if msgtype == "nav_msgs/msg/Odometry":
        p = msg.pose.pose
        return [(msg.header, msg.header.frame_id, msg.child_frame_id, _vec(p.position) + _quat_wxyz(p.orientation))]
    p = msg.pose.pose if msgtype == "geometry_msgs/msg/PoseWithCovarianceStamped" else msg.pose
    return [(msg.header, msg.header.frame_id, "", _vec(p.position) + _quat_wxyz(p.orientation))]


def _frame(name: str) -> str:
    """A frame id without ROS1's leading slash (``/body`` and ``body`` name one tf frame)."""
    return name.lstrip("/")


def _messages(reader: Any, bag: str, topic: str, flag: str) -> Any:
    """``(receive ns, message)`` of one topic, deserialisation errors as one-line ReaderErrors."""
    conns = [c for c in reader.connections if c.topic == topic]
    try:
        for conn, t_recv, raw in reader.messages(connections=conns):
            yield int(t_recv), reader.deserialize(raw, conn.msgtype)
    except Exception as e:  # rosbags raises several types on a damaged bag
        raise ReaderError(f"{bag}: {flag} {topic!r}: cannot read its messages ({_one_line(e)})") from None


CLOCK_STEP_S = 1.0  # header stamps may drift from the receive times by transport delay, not by more


def _check_clocks(header_ns: list[int], recv_ns: list[int], where: str) -> None:
    """Refuse header stamps whose offset from the bag's receive times changes by more than
    ``max(CLOCK_STEP_S, half the receive span)``: a step of the header clock (a one-hour step over a
    10 s bag was kept)."""
    if len(header_ns) < 2:
        return
    h, r = np.asarray(header_ns, np.int64), np.asarray(recv_ns, np.int64)
    off = (h - h[0]) - (r - r[0])  # int64 ns, no float rounding of 61-bit stamps
    spread = float(off.max() - off.min()) / 1e9
    span = float(r.max() - r.min()) / 1e9
    if spread > max(CLOCK_STEP_S, 0.5 * span):
        k = int(np.argmax(np.abs(np.diff(off)))) + 1
        raise ReaderError(f"{where}: the header stamps drift from the bag's receive times by {spread:.4g} s over a "
                          f"{span:.4g} s recording (a jump of {float(off[k] - off[k - 1]) / 1e9:.4g} s at message {k}): "
                          "a header clock step; try --time receive")


def _imu(reader: Any, bag: str, topic: str, time: str) -> dict[str, Any]:
    ns, rows, no_acc, no_gyr, frames = [], [], True, True, set()
    hdr, rcv = [], []
    for t_recv, m in _messages(reader, bag, topic, "--imu-topic"):
        hdr.append(_stamp_ns(m.header))
        rcv.append(t_recv)
        ns.append(hdr[-1] if time == "header" else t_recv)
        rows.append(_vec(m.linear_acceleration) + _vec(m.angular_velocity))
        no_acc = no_acc and float(m.linear_acceleration_covariance[0]) == -1.0
        no_gyr = no_gyr and float(m.angular_velocity_covariance[0]) == -1.0
        frames.add(m.header.frame_id)
    where = f"{bag}: --imu-topic {topic!r}"
    if len(frames) > 1:
        raise ReaderError(f"{where}: the messages name {len(frames)} frames {sorted(frames)[:_LIST_AT_MOST]} (two IMUs on one "
                          "topic?); jaxcal reads one IMU per topic: split the topic by header.frame_id first")
    if time == "header":
        _check_clocks(hdr, rcv, where)
    if no_acc and no_gyr:
        raise ReaderError(f"{where}: every message marks both linear_acceleration and angular_velocity as "
                          "absent (covariance[0] = -1)")
    stamps, vals = _sorted_unique(ns, np.asarray(rows, dtype=np.float64).reshape(-1, 6), where, time)
    if stamps.size < 2:
        hint = "; the header stamps are all equal: try --time receive" if time == "header" and len(ns) > 1 else ""
        raise ReaderError(f"{where}: {stamps.size} distinct sample time(s); need at least 2{hint}")
    ns0 = int(stamps[0])
    rec: dict[str, Any] = {
        "t": (stamps - ns0) / 1e9, "t0": ns0 / 1e9, "t0_ns": np.int64(ns0), "meta_imu_topic": topic,
        "meta_imu_frame_id": ",".join(sorted(frames)), "meta_time_source": time,
    }
    if not no_acc:
        rec.update(acc=vals[:, :3] / G0, acc_unit="g", _acc_columns=f"{topic} linear_acceleration (m/s^2)")
    if not no_gyr:
        rec.update(gyr=vals[:, 3:], gyr_unit="rad/s", _gyr_columns=f"{topic} angular_velocity (rad/s)")
    return rec


def _pose(reader: Any, bag: str, topic: str, msgtype: str, pose_frame: str | None, time: str,
          ns0: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, str]]:
    where = f"{bag}: --pose-topic {topic!r}"
    has_child = msgtype in ("geometry_msgs/msg/TransformStamped", "nav_msgs/msg/Odometry", *_TF_TYPES)
    if pose_frame is not None and not has_child:
        raise ReaderError(f"{where}: --pose-frame selects a transform's child_frame_id, and {msgtype} has none; "
                          "drop --pose-frame")
    if pose_frame is None and msgtype in _TF_TYPES:
        raise ReaderError(f"{where}: a tf topic holds many frames; name the body with --pose-frame CHILD_FRAME_ID")
    want = None if pose_frame is None else _frame(pose_frame)
    ns, rows, parents, children, seen = [], [], set(), set(), set()
    hdr, rcv = [], []
    for t_recv, m in _messages(reader, bag, topic, "--pose-topic"):
        for header, parent, child, row in _pose_rows(msgtype, m):
            seen.add(_frame(child))
            if want is not None and _frame(child) != want:
                continue
            hdr.append(_stamp_ns(header))
            rcv.append(t_recv)
            ns.append(hdr[-1] if time == "header" else t_recv)
            rows.append(row)
            parents.add(parent)
            children.add(child)
    if want is not None and not rows:
        raise ReaderError(f"{where}: no transform with child_frame_id {want!r}; the topic has {sorted(seen)[:_LIST_AT_MOST]}")
    if want is None and len(children) > 1:
        raise ReaderError(f"{where}: the messages name several child frames {sorted(children)[:_LIST_AT_MOST]}; "
                          "pick one with --pose-frame")
    if time == "header":
        _check_clocks(hdr, rcv, where)
    stamps, vals = _sorted_unique(ns, np.asarray(rows, dtype=np.float64).reshape(-1, 7), where, time)
    if stamps.size < 2:
        raise ReaderError(f"{where}: {stamps.size} distinct pose time(s); need at least 2")
    q = unit_quaternions(vals[:, 3:], f"{where}: orientation")
    meta = {"meta_pose_topic": topic, "meta_pose_frame_id": ",".join(sorted(parents))}
    if has_child:
        meta["meta_pose_child_frame_id"] = ",".join(sorted(children))
    return (stamps - ns0) / 1e9, vals[:, :3], q, meta


def _open(paths: Sequence[Path], bag: str, kind: str) -> Any:
    """An open ``rosbags`` AnyReader over ``paths`` (the caller closes it)."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:  # pragma: no cover - rosbags is a dependency
        raise ReaderError(f"{bag}: reading ROS bags needs the rosbags package (pip install rosbags)") from None
    # Used only for a ROS2 bag without embedded message definitions (rosbag2 before Iron); the
    # sensor_msgs / geometry_msgs / tf2_msgs / nav_msgs layouts are the same in every ROS2 release.
    default = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    reader = AnyReader(list(paths), default_typestore=default)
    reader.open()
    return reader


def _bag_paths(path: str | Path | Sequence[str | Path]) -> tuple[list[Path], str, str]:
    """``(paths, label, kind)``: one bag, or the ROS1 parts of one split recording.

    ``label`` names the bag in messages: its path, or the first part's with ``(+N more parts)``.
    """
    paths = [Path(path)] if isinstance(path, (str, Path)) else [Path(p) for p in path]
    if not paths:
        raise ReaderError("no bag path given")
    kinds = [_bag_kind(p) for p in paths]
    label = str(paths[0]) if len(paths) == 1 else f"{paths[0]} (+{len(paths) - 1} more parts)"
    if len(paths) > 1:
        if any(k != "ros1" for k in kinds):
            others = sorted({str(p) for p, k in zip(paths, kinds) if k != "ros1"})
            raise ReaderError(f"{label}: several paths are read as the parts of one split ROS1 recording (.bag files); "
                              f"{', '.join(others)} is not one (a ROS2 bag directory reads its own split files): "
                              "give one ROS2 bag")
        if len({p.resolve() for p in paths}) < len(paths):
            raise ReaderError(f"{label}: a bag file is given twice")
    return paths, label, kinds[0]


def bag_topics(path: str | Path | Sequence[str | Path]) -> dict[str, tuple[str | None, int]]:
    """The topics of a bag (or of a split ROS1 recording's parts together):
    ``topic -> (message type, message count)`` (type None: mixed types).

    Raises:
        ReaderError: not a readable ROS bag.
    """
    paths, label, kind = _bag_paths(path)
    return _with_reader(paths, label, kind, lambda r: {k: (v.msgtype, int(v.msgcount)) for k, v in r.topics.items()})


def _with_reader(paths: Sequence[Path], bag: str, kind: str, fn: Callable[[Any], Any]) -> Any:
    try:
        reader = _open(paths, bag, kind)
    except ReaderError:
        raise
    except KeyError as e:  # rosbags maps a definition's encoding; rosbag2 writes "unknown" when it had none
        key = e.args[0] if e.args else None
        if kind == "ros1" or not isinstance(key, str) or "/" in key:  # a type name, not an encoding
            raise ReaderError(f"{bag}: not a readable ROS bag ({_one_line(e)})") from None
        raise ReaderError(f"{bag}: a message definition has the encoding {e.args[0]!r} (rosbag2 writes 'unknown' when "
                          "it lacked a type's definition), which rosbags cannot read; for sqlite3 run "
                          "DELETE FROM message_definitions WHERE encoding = 'unknown' on a copy, and the standard "
                          "sensor_msgs/geometry_msgs layouts are used") from None
    except Exception as e:  # AnyReaderError, FileNotFoundError, apsw / struct / yaml errors of a damaged file
        raise ReaderError(f"{bag}: not a readable ROS bag ({_one_line(e)})") from None
    try:
        return fn(reader)
    finally:
        reader.close()


def read_rosbag(
    path: str | Path | Sequence[str | Path],
    imu_topic: str,
    *,
    pose_topic: str | None = None,
    pose_frame: str | None = None,
    time: str = "header",
    max_gap: float = 0.05,
) -> Recording:
    """Read an IMU topic (and optionally a reference pose topic) of a ROS bag into a recording.

    See the module docstring for the mapping, the time base and the pose conventions.

    Args:
        path: a ROS1 ``.bag`` file, a ROS2 bag directory (sqlite3 or MCAP storage), or a bare ROS2
            ``.mcap`` / ``.db3`` file; or a sequence of ROS1 ``.bag`` files, the parts of one split
            recording (merged by time; their order does not matter).
        imu_topic: the ``sensor_msgs/msg/Imu`` topic.
        pose_topic: optional reference pose topic (PoseStamped, PoseWithCovarianceStamped,
            TransformStamped, Odometry, tf2_msgs TFMessage or tf tfMessage); None: no pose.
        pose_frame: the ``child_frame_id`` to keep (required for a TFMessage topic; optional
            filter for TransformStamped / Odometry; a leading ``/`` is ignored).
        time: ``"header"`` (message header stamps) or ``"receive"`` (the bag's record time).
        max_gap: longest pose spacing interpolated across (s).

    Raises:
        ReaderError: a missing path, not a bag, several paths that are not all ROS1 ``.bag`` files
            (or one given twice), a missing topic (the message lists the bag's
            topics), a wrong message type, an empty topic, fewer than two samples, conflicting
            samples with one stamp, a non-unit quaternion.
        RecordingError: the result breaks the conventions (e.g. implausible values).
    """
    paths, bag, kind = _bag_paths(path)
    if time not in TIME_SOURCES:
        raise ReaderError(f"{bag}: time source {time!r}; expected one of {list(TIME_SOURCES)}")

    def read(reader: Any) -> dict[str, Any]:
        topics = reader.topics
        _check_topic(bag, topics, imu_topic, "--imu-topic", (IMU_TYPE,))
        pose_type = None if pose_topic is None else _check_topic(bag, topics, pose_topic, "--pose-topic", POSE_TYPES)
        rec = _imu(reader, bag, imu_topic, time)
        rec["meta_bag_kind"] = kind
        rec["meta_bag_files"] = np.int64(len(paths))
        if pose_type is not None:
            tg, pos, q, meta = _pose(reader, bag, pose_topic, pose_type, pose_frame, time, int(rec["t0_ns"]))
            t_imu = rec["t"]
            if tg[-1] < t_imu[0] or tg[0] > t_imu[-1]:
                raise ReaderError(f"{bag}: --pose-topic {pose_topic!r}: the pose track ({tg[0]:.4g} to {tg[-1]:.4g} s) never "
                                  f"overlaps the IMU (0 to {t_imu[-1]:.4g} s) on the {time} clock; the two topics' clocks "
                                  f"differ{' (try --time receive)' if time == 'header' else ''}")
            attach_pose(rec, tg, pos, q, max_gap, f"{bag}: --pose-topic {pose_topic!r}")
            rec.update(meta)
        elif pose_frame is not None:
            raise ReaderError(f"{bag}: --pose-frame {pose_frame!r} needs --pose-topic")
        return rec

    return finish_recording(_with_reader(paths, bag, kind, read), f"{bag}: --imu-topic {imu_topic!r}")


def _read(files: list[Path], **options: Any) -> Recording:
    return read_rosbag(files, **options)


FORMAT = Format("rosbag", "a ROS bag (ROS1 .bag or its split parts, ROS2 directory, .mcap / .db3): an Imu topic "
                "[and a pose topic]", read=_read, files=(1, 10**6), paths_are_files=False,
                own_options=("imu_topic", "pose_topic", "pose_frame", "time"),
                needs={"imu_topic": "TOPIC (a sensor_msgs/msg/Imu topic)"},
                flags={"imu_topic": Flag("--imu-topic", str, None, "rosbag: the sensor_msgs/msg/Imu topic (required)",
                                         "TOPIC"),
                       "pose_topic": Flag("--pose-topic", str, None, "rosbag: reference pose topic (PoseStamped, "
                                          "PoseWithCovarianceStamped, TransformStamped, Odometry or tf2_msgs/TFMessage)",
                                          "TOPIC"),
                       "pose_frame": Flag("--pose-frame", str, None,
                                          "rosbag: child_frame_id of the body's transform (required for a tf topic)", "FRAME"),
                       "time": Flag("--time", str, None, "rosbag: sample times from message header stamps (default) or "
                                    "the bag's receive time", choices=TIME_SOURCES)},
                read_help="a ROS1 .bag or the .bag parts of a split recording, a ROS2 bag directory or .mcap; "
                "needs --imu-topic",
                files_help="one BAG path, or the ROS1 .bag parts of one split recording")
