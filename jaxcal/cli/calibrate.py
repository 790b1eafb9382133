"""``jaxcal calibrate``, ``jaxcal apply`` and ``jaxcal methods``: fit a model, apply it, list the methods."""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from jaxcal.cli.core import PROG, Command, UsageError, _check_out_file, _count, _progress, _real, _seed, register_command
from jaxcal.constants import GYR_RANGE_DEGS, SENSORS
from jaxcal.recording import atomic_output, load_recording

# The methods (jax, flax, optimistix) are imported inside the functions that use them, so that
# registering these commands costs nothing (`jaxcal --help`, other commands).

__all__ = ["OPTION_FLAGS", "Flag"]


# ----------------------------------------------------------------------------- calibrate


def _int_tuple(text: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(v) for v in text.replace(",", " ").split())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not vals or any(v <= 0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected positive layer widths, got {text!r}")
    return vals


def _sensors(text: str) -> tuple[str, ...]:
    vals = tuple(v for v in text.replace(",", " ").split())
    bad = [v for v in vals if v not in SENSORS]
    if not vals or bad:
        raise argparse.ArgumentTypeError(f"expected acc, gyr or acc,gyr, got {text!r}")
    return vals


def _turns(text: str) -> tuple[tuple[float, float], ...]:
    try:
        out = tuple(tuple(float(x) for x in part.split("-")) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START-END[,START-END...] in seconds, got {text!r}") from None
    if not all(math.isfinite(v) for x in out for v in x):
        raise argparse.ArgumentTypeError(f"turn times must be finite numbers of seconds, got {text!r}")
    if any(len(x) != 2 or x[1] <= x[0] for x in out):
        raise argparse.ArgumentTypeError(f"each turn needs START-END with START < END, got {text!r}")
    return out


def _degs_to_rads(v: float) -> float:
    return v * math.pi / 180.0


class Flag(NamedTuple):
    """A ``calibrate`` flag of a method option field.

    Args:
        flag: the flag, e.g. ``--lr``.
        parse: text -> the flag's value (raises ``argparse.ArgumentTypeError``); ``None`` for a
            switch (``const`` is its value).
        conv: the flag's value -> the option's (e.g. deg/s -> rad/s), or ``None``.
        help: what it does (the methods that take it and the default are added).
        metavar: the value's name in the help.
        const: the value of a switch (``parse`` is ``None``).
        show_default: the default as the help shows it (``None``: the option's default).
    """

    flag: str
    parse: Callable[[str], Any] | None
    conv: Callable[[Any], Any] | None
    help: str
    metavar: str | None = None
    const: Any = None
    show_default: Any = None


def _choice(*names: str) -> Callable[[str], str]:
    def parse(text: str) -> str:
        if text not in names:
            raise argparse.ArgumentTypeError(f"expected one of {', '.join(names)}, got {text!r}")
        return text

    return parse


# Method option field (the argparse dest) -> its flag. Every field of every registered options
# type that a user needs is here; defaults come from the options types (one source of truth).
OPTION_FLAGS: dict[str, Flag] = {
    "seed": Flag("--seed", _seed, None, "PRNG seed in [0, 2**32 - 1]", "N"),
    "sensors": Flag("--sensors", _sensors, None, "calibrate only these: acc, gyr or acc,gyr", "S", show_default="all labelled"),
    # nn
    "widths": Flag("--widths", _int_tuple, None, "hidden widths, e.g. 7500 or 5,10,5", "W[,W...]"),
    "slope": Flag("--slope", _real(0.0, 1.0, open_low=False), None, "leaky-ReLU slope in [0, 1]", "A"),
    "learning_rate": Flag("--lr", _real(0.0, 10.0), None, "Adam learning rate", "LR"),
    "patience": Flag("--patience", _count(1, 10**9), None, "early-stopping patience in epochs", "N"),
    "max_epochs": Flag("--max-epochs", _count(1, 10**9), None, "maximum full-batch epochs", "N"),
    "val_fraction": Flag("--val-fraction", _real(0.0, 0.99), None,
                         "share of labelled samples held out for early stopping, whole sequences if `seq` is given", "F"),
    "acc_range": Flag("--acc-range", _real(0.0, 1e6), None, "accelerometer full scale in g for eq. 3.6 bounds", "G"),
    "gyr_range": Flag("--gyr-range", _real(0.0, 1e6), _degs_to_rads, "gyroscope full scale in deg/s for eq. 3.6 bounds",
                      "DEG_S", show_default=GYR_RANGE_DEGS),
    "min_rel_delta": Flag("--min-rel-delta", _real(0.0, 1.0, open_low=False), None,
                          "relative fall of the validation loss that counts as an improvement", "R"),
    "warm_start": Flag("--no-warm-start", None, None, "start Adam from the random initialisation, not from the ridge "
                       "least-squares output layer", const=False, show_default="warm start"),
    # cubic
    "degree": Flag("--degree", _count(1, 9), None, "polynomial degree", "D"),
    "ridge": Flag("--ridge", _real(0.0, 1e12, open_low=False), None, "ridge penalty on the polynomial coefficients", "R"),
    # multipos
    "turns": Flag("--turns", _turns, None, "whole turns about the vertical (e.g. turned flat on a table), start-end in "
                  "seconds; their axes are read from the accelerometer at the rests around them (no labels)",
                  "T0-T1[,T0-T1...]", show_default="none"),
    "partial": Flag("--partial", None, None, "when the poses do not determine every combination, fit only those they do "
                    "and leave the rest as recorded (recordings in g and rad/s; an undetermined gyroscope is not "
                    "calibrated) instead of refusing", const=True, show_default="refuse"),
    "acc_model": Flag("--acc-model", _choice("9", "12"), None, "accelerometer model: 9 (3 scales, 3 misalignment "
                      "angles, bias) or 12 (full 3x3 and bias)", "9|12"),
    "gyro_bias": Flag("--gyro-bias", _choice("static", "init"), None,
                      "gyro bias from all rests (static) or the initial rest only (init, as imu_tk)", "static|init"),
    "datasheet_prior": Flag("--datasheet-prior", None, None, "MAP fit with the recording's datasheet scales "
                            "(acc_lsb_per_g, gyr_lsb_per_rads) as prior centre, tolerances --prior-scale and "
                            "--prior-cross (results/real.md: MPU-6050 held out 0.79 -> 0.66 mg)", const=True,
                            show_default="off"),
    "g_sensitivity": Flag("--g-sensitivity", None, None, "also fit the gyroscope's g-sensitivity G ((rad/s)/g: "
                          "w = A_g (y_g - b_g) - G f, f the calibrated accelerometer) jointly with the gyro bias from "
                          "the rests (4+ poses spanning 3-D), stored as state/gyr/G and applied by `jaxcal apply` "
                          "(which then needs the recording's acc)", const=True,
                          show_default="off"),
    "latitude": Flag("--latitude", _real(-90.0, 90.0, open_low=False), None, "the rig's latitude in degrees: with "
                     "--g-sensitivity the vertical Earth rate (15.04 sin(latitude) deg/h, read at rest along gravity) is "
                     "taken out of G instead of left in its trace", "DEG", show_default="none: left in G"),
    "prior_scale": Flag("--prior-scale", _real(0.0, 10.0), None,
                        "prior std of the relative scale around the datasheet value (sensitivity tolerance)", "S"),
    "prior_cross": Flag("--prior-cross", _real(0.0, 10.0), None, "prior std of the cross-axis terms", "S"),
    "init_duration": Flag("--init-duration", _real(0.0, 1e6), None, "seconds of initial rest that set the rest "
                          "detector's threshold", "SEC", show_default="10 %% of the recording, at most 30 s"),
    "min_rest": Flag("--min-rest", _real(0.0, 1e6), None, "shortest rest (pose) kept, in seconds", "SEC"),
    "rest_window": Flag("--rest-window", _real(0.0, 1e6), None, "moving-variance window of the rest detector, seconds",
                        "SEC"),
    # online
    "kind": Flag("--kind", _choice("affine", "diag"), None, "filter model: affine (scale, cross-axis, bias) or diag "
                 "(scale, bias)", "affine|diag", show_default="affine with seq ids, diag between rests"),
    "sigma_acc": Flag("--sigma-acc", _real(0.0, 1.0), None, "accelerometer noise std of the filter, in g",
                      "G", show_default="measured at the rests; 1.8e-5 with seq ids"),
    "n_iter": Flag("--n-iter", _count(1, 100), None, "Gauss-Newton iterations per sequence", "N",
                   show_default="4"),
    "forgetting": Flag("--forgetting", _real(0.0, 1.0), None, "information forgetting factor per sequence, in (0, 1]",
                       "L"),
    "rest_pad": Flag("--rest-pad", _real(0.0, 1e6), None, "seconds of each rest streamed with the motions around it "
                     "(recordings without seq ids)", "SEC"),
    "folds": Flag("--folds", _count(2, 1000), None, "interleaved rest folds of the held-out figure", "K"),
    "residuals": Flag("--residuals", _choice("rests", "all"), None, "between rests: the accelerometer residuals at "
                      "the rests only, or at every sample (the simulation's recipe; motions carry translational "
                      "acceleration)", "rests|all"),
    # diagnosed
    "baseline": Flag("--baseline", _choice("diag", "affine"), None, "baseline sensor model diagnosed against: diag "
                     "(thesis eq. 4.6) or affine (eq. 2.3), as `jaxcal diagnose --baseline`", "diag|affine"),
}


def _option_defaults() -> dict[str, Any]:
    """Option field -> default, over every registered method's options type (a field that several
    types share has one default; ``tests/test_methods_contract.py`` checks it)."""
    from jaxcal import methods

    return {f: d for m in methods.REGISTRY.values() for f, d in m.options._field_defaults.items()}


def _used_by(field: str) -> str:
    """The registered methods whose options have ``field``, e.g. ``"nn and online-thesis"``."""
    from jaxcal import methods

    return " and ".join(m.name for m in methods.REGISTRY.values() if field in m.options._fields)


def _default_text(field: str, spec: Flag, defaults: dict[str, Any]) -> str:
    d = spec.show_default if spec.show_default is not None else defaults.get(field)
    if isinstance(d, tuple):
        d = ",".join(map(str, d))
    return f"{d:g}" if isinstance(d, float) else str(d)


def _add_calibrate(p: argparse.ArgumentParser) -> None:
    from jaxcal import methods

    p.add_argument("recording", metavar="RECORDING", help="recording (.npz or .csv; see CONVENTIONS.md)")
    p.add_argument(
        "--method",
        required=True,
        choices=methods.names(),
        help="calibration method (`jaxcal methods` says what each needs)",
    )
    p.add_argument("--out", required=True, metavar="MODEL.npz", help="model file to write")
    p.add_argument("--no-held-out", dest="held_out", action="store_false",
                   help="skip the held-out figure (leave-poses-out, rest folds or a validation refit: seconds)")
    defaults = _option_defaults()
    groups: dict[str, argparse._ArgumentGroup] = {}
    for field, spec in OPTION_FLAGS.items():
        used = _used_by(field)
        if not used:
            continue
        g = groups.setdefault(used, p.add_argument_group(f"options of {used}"))
        text = f"{spec.help} ({used}; default {_default_text(field, spec, defaults)})"
        if spec.parse is None:
            g.add_argument(spec.flag, dest=field, action="store_const", const=spec.const, default=argparse.SUPPRESS,
                           help=text)
        else:
            g.add_argument(spec.flag, dest=field, default=argparse.SUPPRESS, metavar=spec.metavar, help=text)
    p.add_argument("--force", action="store_true",
                   help="write the model even where its own held-out figure or a plausible range contradicts it "
                        "(with a warning; default: refuse, exit 2)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")


def _method_options(args: argparse.Namespace) -> Any:
    """The options of ``args.method`` from the flags given (the others keep the options type's
    defaults). Every problem (a value that does not parse, a flag of another method) is collected
    and reported at once, naming the flags, as one usage error."""
    from jaxcal import methods

    kind = methods.get(args.method).options
    values, errors = {}, []
    for field, spec in OPTION_FLAGS.items():
        if not hasattr(args, field):
            continue
        raw = getattr(args, field)
        try:
            v = raw if spec.parse is None or not isinstance(raw, str) else spec.parse(raw)
        except argparse.ArgumentTypeError as e:
            errors.append(f"{spec.flag}: {e}")
            v = None
        if field not in kind._fields:
            errors.append(f"{spec.flag} is an option of {_used_by(field) or 'no method'}, not of {args.method}")
        elif v is not None or spec.parse is None:
            values[field] = spec.conv(v) if spec.conv else v
    if errors:
        raise UsageError(f"calibrate --method {args.method}: " + "; ".join(errors))
    return kind(**values)


def _run_calibrate(args: argparse.Namespace) -> int:
    from jaxcal import methods
    from jaxcal.methods import CalibrationModel, ModelError
    from jaxcal.methods.summary import contradiction, describe, summary_lines
    from jaxcal.model_file import save_model

    if not args.out.lower().endswith(".npz"):
        raise UsageError(f"--out {args.out}: model files are .npz")
    _check_out_file(args.out, [args.recording])
    options = _method_options(args)  # before reading data
    rec = load_recording(args.recording)
    log = _progress(args)
    t0 = time.perf_counter()
    try:
        model = methods.fit(args.method, rec, options, log=log)
        if log and args.held_out:
            log("scoring the fit held out (--no-held-out skips this) ...")
        desc = describe(args.method, rec, options, model, log or (lambda msg: None), held_out=args.held_out)
    except ModelError as e:  # the recording does not suit the method: say which file
        raise ModelError(f"{args.recording}: {e}") from None
    why = contradiction(desc)
    if why is not None and not args.force:
        raise ModelError(f"{args.recording}: {args.method}: not written: {why} (--force writes it anyway)")
    if why is not None:
        print(f"{PROG}: warning: {args.method}: {why}; written because of --force", file=sys.stderr)
        desc = {**desc, "contradiction": why}
    model = CalibrationModel(model.method, model.sensors, model.state, {**model.meta, **desc})
    save_model(model, args.out)
    for line in summary_lines(desc):
        print(line)
    if log:
        log(f"wrote {args.out} ({args.method}, sensors {','.join(model.sensors)}) in {time.perf_counter() - t0:.1f} s")
    return 0


# ----------------------------------------------------------------------------- apply


def _add_apply(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", metavar="MODEL", help="model file written by `jaxcal calibrate`")
    p.add_argument("recording", metavar="RECORDING", help="recording to calibrate (.npz or .csv)")
    p.add_argument(
        "--out", required=True, metavar="OUT.npz", help="output: t, and acc_cal (g) and/or gyr_cal (rad/s)"
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    p.add_argument("--allow-extrapolation", action="store_true",
                   help="apply even where the recording lies outside the model's fitted range (a cubic model's input "
                        "bounds, a diagnosed model's temperature range or time offset): warn on stderr instead of refusing")


def _run_apply(args: argparse.Namespace) -> int:
    from jaxcal.methods import ModelError
    from jaxcal.model_file import load_model
    from jaxcal.plausible import apply_range_problems

    if not args.out.lower().endswith(".npz"):
        raise UsageError(f"--out {args.out}: calibrated output is written as .npz")
    _check_out_file(args.out, [args.model, args.recording])
    model = load_model(args.model)
    rec = load_recording(args.recording)
    problems = apply_range_problems(model.method, model.state, model.meta, rec)
    if problems and not args.allow_extrapolation:
        raise UsageError(f"{args.model} on {args.recording}: {problems[0]} (--allow-extrapolation applies it anyway)")
    for why in problems:
        print(f"{PROG}: warning: {why}", file=sys.stderr)
    try:
        out = model.apply(rec)
    except ModelError as e:  # the model does not suit the recording (or is malformed): say which files
        raise ModelError(f"{args.model} on {args.recording}: {e}") from None
    try:
        with atomic_output(args.out) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, t=np.asarray(rec.t), **out)
    except OSError as e:
        raise UsageError(f"{args.out}: cannot write ({e.strerror or e})") from None
    log = _progress(args)
    if log:
        log(f"wrote {args.out}: {', '.join(out)} for {rec.n} samples")
    return 0

# ----------------------------------------------------------------------------- methods, version


def _add_methods(p: argparse.ArgumentParser) -> None:
    pass


def _run_methods(args: argparse.Namespace) -> int:
    from jaxcal import methods

    for name, m in methods.REGISTRY.items():
        print(f"{name:14s} {m.doc}")
    return 0

register_command(
    "calibrate",
    Command(
        "fit a calibration model to a recording",
        _add_calibrate,
        _run_calibrate,
        "Fit a calibration model to RECORDING and write it to MODEL.npz. linear/nn need reference "
        "labels (acc_ref, gyr_ref) and use the datasheet values in the metadata (acc_lsb_per_g, ...) "
        "only for nn input normalisation (eq. 3.6-3.7).",
    ),
)
register_command(
    "apply",
    Command(
        "calibrate a recording with a model",
        _add_apply,
        _run_apply,
        "Apply MODEL to RECORDING; write t and acc_cal (g) and/or gyr_cal (rad/s) to OUT.npz.",
    ),
)

register_command("methods", Command("list the calibration methods", _add_methods, _run_methods))
