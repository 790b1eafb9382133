"""``jaxcal diagnose`` and ``jaxcal align``: the discrepancy report and IMU-to-mocap alignment."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from jaxcal.cli.core import PROG, Command, UsageError, _check_out_file, _count, _output_dir, _real, _same_file, register_command
from jaxcal.recording import Recording, load_recording

if TYPE_CHECKING:  # annotations only: jaxcal.diagnose is imported on use
    from jaxcal.diagnose.gate import GateResult

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


def _check_model_out(model_out: str, out: str, recording: str) -> None:
    """Refuse a ``--model-out`` that cannot be written, before the diagnosis: not ``.npz``, one of
    the inputs, the ``--out`` folder itself, or in a folder that is missing (other than ``--out``)
    or not writable."""
    if not model_out.lower().endswith(".npz"):
        raise UsageError(f"--model-out {model_out}: model files are .npz")
    try:
        _check_out_file(model_out, [recording])
    except UsageError as e:  # its message names --out
        raise UsageError(str(e).replace("--out", "--model-out", 1)) from None
    m, o = Path(model_out).absolute(), Path(out).absolute()
    if m == o or _same_file(m, o):
        raise UsageError(f"--model-out {model_out}: is the --out folder; name a file outside it or inside it")
    parent = m.parent
    if parent == o:
        return  # written after the report folder is published
    if parent.exists() and not parent.is_dir():
        raise UsageError(f"--model-out {model_out}: {parent} is not a folder")
    if not parent.is_dir():
        raise UsageError(f"--model-out {model_out}: folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"--model-out {model_out}: folder {parent} is not writable")


def _gate(rec: Recording, what: str) -> GateResult:
    """The reference gate (:mod:`jaxcal.diagnose.gate`) before any fit: one line on refusal."""
    from jaxcal.diagnose.gate import check_reference

    try:
        return check_reference(rec)
    except ValueError as e:
        raise UsageError(f"{what}: {e}") from None


def _run_diagnose(args: argparse.Namespace) -> int:
    from jaxcal import diagnose as diag  # imported on use: it adds about a second to every command
    from jaxcal.diagnose.gate import baseline_scales, report_gate
    from jaxcal.diagnose.noref import check_input, has_reference

    if args.model_out is not None:
        _check_model_out(args.model_out, args.out, args.recording)
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise UsageError(f"--out {args.out}: exists and is not a directory")
    rec = load_recording(args.recording)
    noref = args.reference == "none" or not has_reference(rec)
    if noref and args.model_out is not None:
        raise UsageError(f"{args.recording}: --model-out needs a reference motion (a diagnosed model of the reference-free "
                         "mode is not written yet)")
    # refuse bad input (too short, a reference that does not explain the sensor) before any progress line
    if noref:
        try:
            check_input(rec)
        except ValueError as e:
            raise UsageError(f"{args.recording}: {e}") from None
        gate = None
    else:
        gate = _gate(rec, args.recording)
    t0 = time.perf_counter()
    with _output_dir(args.out) as d:
        try:
            how = "without a reference (IMU self-consistency)" if noref else "against its reference motion"
            print(f"{PROG}: diagnosing {args.recording} {how}, {args.baseline} baseline ...", file=sys.stderr)
            rep = diag.diagnose_recording(rec, baseline=args.baseline, with_figures=True, keep_fit=True,
                                          reference="none" if noref else "motion")
            kept = rep.pop("_fit")
            fit = kept if args.model_out is not None else None
            figs = rep.pop("_figures", None)
        except ValueError as e:  # documented: bad input
            raise UsageError(f"{args.recording}: {e}") from None
        try:
            bad = [] if gate is None else report_gate(rep, gate, scales=baseline_scales(kept[1], args.baseline))
            if bad:
                raise UsageError(f"{args.recording}: {bad[0]}; nothing written")
            diag.write_report(d, rep, figs)
        finally:
            if figs:
                import matplotlib.pyplot as plt

                for f in figs.values():
                    plt.close(f)
        if fit is not None:
            from jaxcal.methods import CalibrationModel
            from jaxcal.methods.diagnosed import diagnosed_model_state
            from jaxcal.model_file import save_model

            fitted = diagnosed_model_state(*fit, args.baseline, rec)
            model = CalibrationModel("diagnosed", fitted.sensors, fitted.state, fitted.meta)
            if Path(args.model_out).absolute().parent != Path(args.out).absolute():
                save_model(model, args.model_out)  # before the report is published: a failure leaves neither
    if fit is not None:
        if Path(args.model_out).absolute().parent == Path(args.out).absolute():
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
    p.add_argument("--clock-windows", type=_count(3, 100), default=None, metavar="K",
                   help="also align K consecutive windows and test whether their offsets lie on one line, i.e. whether "
                        "one clock skew holds the recording (align.json clock_check; about one more alignment's time)")


def _clock_check(rec: Recording, args: argparse.Namespace, skew_se: float | None) -> dict:
    """``--clock-windows K``: :func:`jaxcal.diagnose.clock_check.clock_windows`, and one line on stderr
    (a warning where one offset line does not hold the windows, with the single skew's interval
    widened by their scatter, ``skew_half95_scaled_ppm``: :func:`~jaxcal.diagnose.clock_check.scaled_half95`)."""
    from jaxcal.diagnose.clock_check import LineCheck, clock_windows, scaled_half95

    print(f"{PROG}: aligning {args.clock_windows} windows of {args.recording} (does one clock skew hold?) ...", file=sys.stderr)
    try:
        out = clock_windows(rec, args.clock_windows, args.pose_sigma)
    except ValueError as e:  # a window without a usable reference
        raise UsageError(f"{args.recording}: --clock-windows {args.clock_windows}: {e}") from None
    c = out["line"]
    how = f"chi-square {c['chi2']:.1f} on {c['dof']} dof, p {c['p']:.2g}; the windows' skew {c['slope_ppm']:+.2f} ppm"
    widened = ""
    if skew_se is not None and math.isfinite(skew_se):
        out["skew_half95_scaled_ppm"] = scaled_half95(skew_se, LineCheck(**c))
        widened = f"; with their scatter its 95 % interval is +- {out['skew_half95_scaled_ppm']:.2f} ppm, not +- {1.96 * skew_se:.2f}"
    if c["p"] < 0.01:
        print(f"{PROG}: warning: one clock skew does not hold {args.recording}: the offsets of {args.clock_windows} windows "
              f"are not on one line ({how}); align.json's single skew does not describe it{widened}", file=sys.stderr)
    else:
        print(f"{PROG}: one clock skew holds: the windows' offsets lie on one line ({how})", file=sys.stderr)
    return out


def skew_line(align: dict, checked: bool) -> str:
    """The clock skew ``align`` wrote, for stderr: its 95 % interval, and, where no window check ran
    (``--clock-windows``), that the interval holds only if one clock rate holds the whole recording.
    On the two BROAD trials it did not: the windows' offsets scattered 5.5 and 9.4 times their
    standard errors, and the single skew's 95 % interval widened by that scatter is +-3.0 and +-17.8 ppm
    where its own is about +-0.3 and +-0.9 (``results/discrepancy.md``)."""
    s, se = align.get("clock_skew"), (align.get("stderr") or {}).get("clock_skew")
    if s is None or se is None or not math.isfinite(se):
        return ""
    line = f"clock skew {s:+.2f} +- {1.959964 * se:.2f} ppm (95 %)"
    if checked:
        return line
    return (line + ", if one clock rate holds the whole recording; --clock-windows 4 tests that and widens the "
            "interval by the windows' scatter where it does not (about one more alignment's time)")


def _run_align(args: argparse.Namespace) -> int:
    from jaxcal.diagnose import align as al
    from jaxcal.diagnose.gate import baseline_scales, report_gate

    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise UsageError(f"--out {args.out}: exists and is not a directory")
    rec = load_recording(args.recording)
    if rec.pos_ref is None or rec.quat_ref is None:
        raise UsageError(f"{args.recording}: align needs a reference pose (pos_ref and quat_ref)")
    gate = _gate(rec, args.recording)
    t0 = time.perf_counter()
    with _output_dir(args.out) as d:
        try:
            print(f"{PROG}: aligning {args.recording} (time offset, rotation, lever arm) ...", file=sys.stderr)
            res = al.align_recording(rec, pose_sigma=args.pose_sigma)
        except ValueError as e:  # documented: bad input
            raise UsageError(f"{args.recording}: {e}") from None
        bad = report_gate(res.report, gate, res.align, scales=baseline_scales(res.results, "affine"))
        if bad:
            raise UsageError(f"{args.recording}: {bad[0]}; nothing written")
        if args.clock_windows is not None:
            res = res._replace(align={**res.align, "clock_check": _clock_check(rec, args, res.align["stderr"].get("clock_skew"))})
        al.write_alignment(d, res)
    a = res.align
    r = "-" if a["r"] is None else "[" + ", ".join(f"{1e3 * v:.1f}" for v in a["r"]) + "] mm"
    print(f"{PROG}: wrote {Path(args.out) / 'align.json'} in {time.perf_counter() - t0:.1f} s; tau {1e3 * a['tau']:.2f} "
          f"+- {1e3 * 1.96 * a['tau_stderr']:.2f} ms, rotation {a['rotation_deg']:.3f} deg, lever arm {r}", file=sys.stderr)
    skew = skew_line(a, args.clock_windows is not None)
    if skew:
        print(f"{PROG}: {skew}", file=sys.stderr)
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
