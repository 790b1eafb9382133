"""``jaxcal noise``: Allan deviation and noise parameters (Kalibr / OpenVINS keys) of a static stretch.

::

    jaxcal noise RECORDING --out DIR [--sensors acc,gyr] [--start S --end S] [--rostopic T] [--taus N] [--target-width PCT]

Writes ``DIR/noise.json`` (per sensor and axis: taus, ADEV with intervals, N/B/K with intervals from
the GMWM, its model and how long to record, the slope-line reading as a second opinion, SI units, the
stretch used), ``DIR/imu.yaml`` (Kalibr), ``DIR/openvins_noise.yaml`` (OpenVINS
``kalibr_imu_chain.yaml`` keys) and ``DIR/allan.png``; the maths is :mod:`jaxcal.noise`,
:mod:`jaxcal.gmwm` and :mod:`jaxcal.allan`. The YAML files need both sensors.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from jaxcal.cli.core import (
    DATASHEET_FLAGS,
    PROG,
    Command,
    UsageError,
    _add_datasheet_flags,
    _count,
    _datasheet_values,
    _output_dir,
    _real,
    register_command,
)
from jaxcal.recording import load_recording

__all__: list[str] = []


def _sensor_list(text: str) -> tuple[str, ...]:
    got = tuple(s.strip() for s in text.split(",") if s.strip())
    bad = [s for s in got if s not in ("acc", "gyr")]
    if bad or not got or len(set(got)) != len(got):
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of acc, gyr; got {text!r}")
    return tuple(s for s in ("acc", "gyr") if s in got)


def _add_noise(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="RECORDING", help="recording with a static stretch (acc/gyr in g, rad/s, or LSB with "
                   "the datasheet scales acc_lsb_per_g / gyr_lsb_per_rads in the file or as --acc-lsb-per-g / "
                   "--gyr-lsb-per-rads)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory: noise.json, imu.yaml, openvins_noise.yaml, allan.png")
    p.add_argument("--sensors", type=_sensor_list, default=("acc", "gyr"), metavar="LIST",
                   help="sensors to analyse, comma-separated (default acc,gyr; the YAML files need both)")
    p.add_argument("--start", type=_real(-1e12, 1e12, open_low=False), default=None, metavar="S",
                   help="start of the static stretch (s, the recording's time); default: the longest static interval found")
    p.add_argument("--end", type=_real(-1e12, 1e12, open_low=False), default=None, metavar="S",
                   help="end of the static stretch (s); default: the end of the recording when --start is given")
    p.add_argument("--rostopic", default="/imu0", metavar="TOPIC", help="Kalibr's rostopic key (default /imu0)")
    p.add_argument("--taus", type=_count(2, 100), default=10, metavar="N", help="cluster times per decade (default 10)")
    p.add_argument("--target-width", type=_real(0.1, 1000.0), default=10.0, metavar="PCT",
                   help="interval half-width (%%) whose record length the report predicts (default 10: +-10 %%)")
    _add_datasheet_flags(p, "a recording in raw counts (LSB) without it:")
    p.add_argument("--quiet", action="store_true", help="no summary on stderr")


def _write_text(path: Path, text: str) -> None:
    path.write_text(text, encoding="utf-8")


def _run_noise(args: argparse.Namespace) -> int:
    from jaxcal import noise as nz

    rec = _with_datasheet(load_recording(args.recording), _datasheet_values(args))
    t0 = time.perf_counter()
    rep = nz.noise_report(rec, args.sensors, args.start, args.end, args.rostopic, args.taus, target=args.target_width / 100.0)
    with _output_dir(args.out) as d:
        _write_text(d / "noise.json", json.dumps(nz.report_json(rep, str(args.recording)), indent=1, allow_nan=False) + "\n")
        if rep.kalibr is not None:
            _write_text(d / "imu.yaml", nz.kalibr_yaml_text(rep.kalibr, notes=tuple(rep.warnings)))
            _write_text(d / "openvins_noise.yaml", nz.openvins_yaml_text(rep.openvins))
        fig = nz.allan_figure(rep, title=f"{Path(args.recording).name}: {rep.t_end - rep.t_start:.0f} s static")
        fig.savefig(d / "allan.png", dpi=110)
    if not args.quiet:
        for line in nz.summary_lines(rep):
            print(f"{PROG}: {line}", file=sys.stderr)
        written = "noise.json, allan.png" + (", imu.yaml, openvins_noise.yaml" if rep.kalibr is not None else
                                             " (no imu.yaml: Kalibr needs both acc and gyr)")
        print(f"{PROG}: wrote {written} to {args.out} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


def _with_datasheet(rec, values: dict):
    """The recording with the datasheet scales given as flags (they replace the file's; only a sensor
    in raw counts takes one), validated again: an implausible scale is refused naming its flag."""
    import numpy as np

    from jaxcal.recording import RecordingError, validate_recording

    for key, flag, sensor, _ in DATASHEET_FLAGS:
        y = getattr(rec, sensor)
        if key in values and (y is None or getattr(rec, f"{sensor}_unit") != "LSB"):
            state = "absent" if y is None else f"in {getattr(rec, f'{sensor}_unit')}"
            raise UsageError(f"{flag}: the recording's {sensor} is {state}, not raw counts (LSB): it takes no datasheet scale")
    if not values:
        return rec
    rec = rec.replace(**{k: np.asarray(v, np.float64) for k, v in values.items()})
    try:
        validate_recording(rec)
    except RecordingError as e:
        msg = str(e)
        for key, flag, *_ in DATASHEET_FLAGS:
            msg = msg.replace(f"'{key}'", flag)
        raise UsageError(f"{msg} (as given by the flag)") from None
    return rec


def _checked_run(args: argparse.Namespace) -> int:
    if args.start is not None and args.end is not None and args.end <= args.start:
        raise UsageError(f"--end {args.end:g} must be after --start {args.start:g}")
    return _run_noise(args)


register_command(
    "noise",
    Command(
        "Allan deviation and IMU noise parameters (Kalibr imu.yaml) of a static stretch",
        _add_noise,
        _checked_run,
        "Compute the overlapping Allan deviation of each axis over a static stretch of RECORDING (--start/--end, or "
        "the longest static interval found), select and fit the noise processes jointly over all cluster times (GMWM: "
        "white noise density N, random walk K, and quantisation, bias instability, rate ramp or a Gauss-Markov term where "
        "they show) with 95 % intervals and the record length a --target-width would need (the slope-line reading kept "
        "as a second opinion), and write DIR/noise.json, DIR/imu.yaml (Kalibr), DIR/openvins_noise.yaml and DIR/allan.png. "
        "All numbers in SI units; the YAML values are the largest over the three axes, the sensor's own values "
        "(no inflation).",
    ),
)
