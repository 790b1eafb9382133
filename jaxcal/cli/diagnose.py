"""``jaxcal diagnose`` and ``jaxcal align``: the discrepancy report and IMU-to-mocap alignment."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from jaxcal.cli.core import PROG, Command, UsageError, _check_out_file, _output_dir, _real, register_command
from jaxcal.recording import load_recording

__all__: list[str] = []


def _add_diagnose(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="RECORDING",
                   help="recording, with reference motion (acc_ref/gyr_ref or pos_ref+quat_ref) or without one")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory: report.json, report.md, figures")
    p.add_argument("--baseline", choices=("diag", "affine"), default="diag", help="baseline sensor model (default diag)")
    p.add_argument("--model-out", metavar="MODEL.npz", default=None,
                   help="also write a model file (method 'diagnosed') with the baseline and the named effects, "
                        "for `jaxcal apply` on new recordings (reference mode only)")
    p.add_argument("--reference", choices=("auto", "none"), default="auto",
                   help="auto (default): against the reference motion when the recording has one, otherwise from the "
                        "IMU's self-consistency (gravity carried by the gyroscope, rests); none: ignore any reference")


def _run_diagnose(args: argparse.Namespace) -> int:
    from jaxcal import diagnose as diag  # imported on use: it adds about a second to every command
    from jaxcal.diagnose.noref import check_input, has_reference

    if args.model_out is not None:
        if not args.model_out.lower().endswith(".npz"):
            raise UsageError(f"--model-out {args.model_out}: model files are .npz")
        try:
            _check_out_file(args.model_out, [args.recording])
        except UsageError as e:  # its message names --out
            raise UsageError(str(e).replace("--out", "--model-out", 1)) from None
    rec = load_recording(args.recording)
    noref = args.reference == "none" or not has_reference(rec)
    if noref and args.model_out is not None:
        raise UsageError(f"{args.recording}: --model-out needs a reference motion (a diagnosed model of the reference-free "
                         "mode is not written yet)")
    t0 = time.perf_counter()
    with _output_dir(args.out) as d:
        try:
            # refuse bad input (too short, no reference and nothing to start without one) before any progress line
            check_input(rec) if noref else diag.prepare(rec)
            how = "without a reference (IMU self-consistency)" if noref else "against its reference motion"
            print(f"{PROG}: diagnosing {args.recording} {how}, {args.baseline} baseline ...", file=sys.stderr)
            rep = diag.diagnose_recording(rec, baseline=args.baseline, out_dir=d, keep_fit=args.model_out is not None,
                                          reference="none" if noref else "motion")
            fit = rep.pop("_fit", None)
        except ValueError as e:  # documented: bad input
            raise UsageError(f"{args.recording}: {e}") from None
    if fit is not None:
        from jaxcal.methods import CalibrationModel
        from jaxcal.methods.diagnosed import diagnosed_model_state
        from jaxcal.model_file import save_model

        fitted = diagnosed_model_state(*fit, args.baseline, rec)
        model = CalibrationModel("diagnosed", fitted.sensors, fitted.state, fitted.meta)
        save_model(model, args.model_out)
        carried = "; ".join(f"{s}: {', '.join(v) or 'baseline only'}" for s, v in model.meta["effects"].items())
        print(f"{PROG}: wrote {args.model_out} (method diagnosed; {carried})", file=sys.stderr)
    names = [e.get("name", "?") + "(" + e.get("sensor", "?") + ")" for e in rep.get("effects", [])]
    print(
        f"{PROG}: wrote {Path(args.out) / 'report.json'} in {time.perf_counter() - t0:.1f} s; "
        f"effects: {', '.join(names) or 'none'}",
        file=sys.stderr,
    )
    return 0


def _add_align(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="RECORDING", help="recording with the IMU and a reference pose (pos_ref + quat_ref)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output directory: align.json, groundtruth.csv (EuRoC columns), report.json/md, align_residuals.png")
    p.add_argument("--pose-sigma", type=_real(0.0, 1.0), default=None, metavar="S",
                   help="Gaussian width (s) of the pose derivatives (default: chosen per sensor from where the reference "
                        "keeps its gain against the sensor)")


def _run_align(args: argparse.Namespace) -> int:
    from jaxcal.diagnose import align as al

    rec = load_recording(args.recording)
    t0 = time.perf_counter()
    with _output_dir(args.out) as d:
        try:
            print(f"{PROG}: aligning {args.recording} (time offset, rotation, lever arm) ...", file=sys.stderr)
            res = al.align_recording(rec, pose_sigma=args.pose_sigma)
        except ValueError as e:  # documented: bad input
            raise UsageError(f"{args.recording}: {e}") from None
        al.write_alignment(d, res)
    a = res.align
    r = "-" if a["r"] is None else "[" + ", ".join(f"{1e3 * v:.1f}" for v in a["r"]) + "] mm"
    print(f"{PROG}: wrote {Path(args.out) / 'align.json'} in {time.perf_counter() - t0:.1f} s; tau {1e3 * a['tau']:.2f} "
          f"+- {1e3 * 1.96 * a['tau_stderr']:.2f} ms, rotation {a['rotation_deg']:.3f} deg, lever arm {r}", file=sys.stderr)
    return 0

register_command(
    "diagnose",
    Command(
        "find the effects a sensor model leaves out (report.json)",
        _add_diagnose,
        _run_diagnose,
        "Fit the baseline sensor model to RECORDING against its reference motion (or, with none, against the "
        "IMU itself: the gravity its gyroscope carries and its rests), test the effects of "
        "the discrepancy vocabulary (CONVENTIONS.md) and write DIR/report.json, report.md and figures; with "
        "--model-out, also a model file (method 'diagnosed': the baseline and the named effects) that "
        "`jaxcal apply` inverts on new recordings.",
    ),
)

register_command(
    "align",
    Command(
        "IMU-to-mocap time offset, rotation and lever arm; ground truth in the IMU frame",
        _add_align,
        _run_align,
        "Estimate the time offset, rotation and lever arm between the IMU and the reference pose of RECORDING "
        "(diagnose's engine, affine baseline) and write DIR/align.json and DIR/groundtruth.csv (EuRoC "
        "state_groundtruth_estimate0 columns: the IMU pose in the world frame on the IMU clock).",
    ),
)
