"""``jaxcal import``: public IMU formats to a jaxcal recording (each a reader of :data:`jaxcal.formats.REGISTRY`)."""

from __future__ import annotations

import argparse
import re
import sys

from jaxcal.cli.core import PROG, Command, UsageError, _check_out_file, _count, _real, register_command
from jaxcal.recording import save_recording

__all__: list[str] = []


# ----------------------------------------------------------------------------- import, diagnose


def _mapping(text: str) -> dict[str, str]:
    out = {}
    for item in text.split(","):
        if "=" not in item:
            raise argparse.ArgumentTypeError(f"expected NAME=VALUE[,NAME=VALUE...], got {text!r}")
        k, v = item.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def _add_import(p: argparse.ArgumentParser) -> None:
    from jaxcal.formats.rosbag import TIME_SOURCES  # imported when the command is parsed, not when it registers

    p.add_argument(
        "format",
        metavar="FORMAT",
        help="imu_tk (ACC GYR files), imucal (CSV [sections.json]; needs --fs), euroc / tumvi (IMU CSV "
        "[pose CSV]), mpu6050, fusion (x-io), broad (BROAD trial .mat), csv (generic; needs --columns), "
        "rosbag (a ROS1 .bag or the .bag parts of a split recording, a ROS2 bag directory or .mcap; needs --imu-topic)",
    )
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="input file(s) in that format (rosbag: one BAG path, or the ROS1 .bag parts of one split recording)")
    p.add_argument("--out", required=True, metavar="REC.npz", help="recording to write (.npz or .csv)")
    p.add_argument("--fs", type=_real(0.0, 1e9), default=None, help="sample rate in Hz (imucal, csv without a time column)")
    p.add_argument("--acc-unit", default=None, help="accelerometer unit where the file does not say (imucal)")
    p.add_argument("--gyr-unit", default=None, help="gyroscope unit where the file does not say (imucal)")
    p.add_argument("--time-unit", default=None, help="time unit of the files (imu_tk; default s)")
    p.add_argument(
        "--columns", type=_mapping, default=None, help="csv: conventions name=CSV column, e.g. t=time,acc_x=ax,..."
    )
    p.add_argument("--units", type=_mapping, default=None, help="csv: quantity=unit, e.g. t=ms,acc=m/s^2,gyr=deg/s")
    p.add_argument("--skip-rows", type=_count(0, 10**9), default=None, help="csv: lines to skip before the header")
    p.add_argument("--imu-topic", default=None, metavar="TOPIC", help="rosbag: the sensor_msgs/msg/Imu topic (required)")
    p.add_argument("--pose-topic", default=None, metavar="TOPIC",
                   help="rosbag: reference pose topic (PoseStamped, PoseWithCovarianceStamped, TransformStamped, "
                   "Odometry or tf2_msgs/TFMessage)")
    p.add_argument("--pose-frame", default=None, metavar="FRAME",
                   help="rosbag: child_frame_id of the body's transform (required for a tf topic)")
    p.add_argument("--time", choices=TIME_SOURCES, default=None,
                   help="rosbag: sample times from message header stamps (default) or the bag's receive time")


_OPTIONS = ("fs", "acc_unit", "gyr_unit", "time_unit", "columns", "units", "skip_rows", "imu_topic", "pose_topic",
            "pose_frame", "time")
"""The reader options the command has flags for (``--fs`` -> ``fs``, ...)."""


def _flags(names: tuple[str, ...] | list[str], args: argparse.Namespace) -> list[str]:
    """The given (non-default) options among ``names``, as flags."""
    return ["--" + a.replace("_", "-") for a in names if getattr(args, a) is not None]


def _check_reader(args: argparse.Namespace) -> None:
    """``args.format`` is a reader, and the options given fit it: options that only some reader takes
    (:attr:`~jaxcal.formats.base.Format.own_options`) go with that reader alone, and the options it
    ``needs`` are given."""
    from jaxcal import formats

    fmt = formats.get(args.format)
    if fmt is None or fmt.read is None:
        raise UsageError(f"unknown format {args.format!r}; expected one of {list(formats.readers())}")
    owners = {o: f.name for f in formats.REGISTRY.values() for o in f.own_options}
    foreign = [o for o in owners if o not in fmt.own_options]
    if _flags(foreign, args):
        owner = " / ".join(dict.fromkeys(owners[o] for o in foreign if getattr(args, o) is not None))
        raise UsageError(f"{', '.join(_flags(foreign, args))}: only for the {owner} format, not {args.format!r}")
    if fmt.own_options:  # a reader with options of its own takes no others
        others = [o for o in _OPTIONS if o not in owners]
        if _flags(others, args):
            raise UsageError(f"format {fmt.name!r} does not take {', '.join(_flags(others, args))}")
    for opt, what in (fmt.needs or {}).items():
        if getattr(args, opt) is None:
            raise UsageError(f"format {fmt.name!r} needs --{opt.replace('_', '-')} {what}")


def _run_import(args: argparse.Namespace) -> int:
    from jaxcal import formats

    if not args.out.lower().endswith((".npz", ".csv")):
        raise UsageError(f"--out {args.out}: recordings are written as .npz or .csv")
    _check_out_file(args.out, args.files)
    _check_reader(args)
    options = {k: getattr(args, k) for k in _OPTIONS if getattr(args, k) is not None}
    try:
        rec = formats.read(args.format, args.files, **options)
    except formats.ReaderError as e:
        raise UsageError(str(e)) from None
    except TypeError as e:  # an option this format does not take: name its flag, not the Python argument
        bad = re.search(r"argument '(\w+)'", str(e))
        given = ", ".join("--" + k.replace("_", "-") for k in options) or "none"
        what = f"--{bad.group(1).replace('_', '-')}" if bad and bad.group(1) in options else f"the options given ({given})"
        raise UsageError(f"format {args.format!r} does not take {what}") from None
    save_recording(rec, args.out)
    print(f"{PROG}: wrote {args.out} ({rec.n} samples, {', '.join(rec.sensors())})", file=sys.stderr)
    return 0

register_command(
    "import",
    Command(
        "convert a public IMU format to a jaxcal recording",
        _add_import,
        _run_import,
        "Read FILE(s) in FORMAT (jaxcal.formats) and write a recording per CONVENTIONS.md.",
    ),
)
