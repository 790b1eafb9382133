"""``jaxcal calibrate``, ``jaxcal apply`` and ``jaxcal methods``: fit a model, apply it, list the methods."""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from jaxcal import methods
from jaxcal.cli.core import Command, UsageError, _check_out_file, _count, _progress, _real, _seed, register_command
from jaxcal.constants import GYR_RANGE_DEGS, SENSORS
from jaxcal.methods import ModelError, MultiposOptions, NNOptions
from jaxcal.model_file import load_model, save_model
from jaxcal.recording import atomic_output, load_recording

__all__: list[str] = []


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


# Method option field (the argparse dest) -> (flag, conversion of the flag's value to the option's).
OPTION_FLAGS: dict[str, tuple[str, Callable[[Any], Any] | None]] = {
    "seed": ("--seed", None),
    "sensors": ("--sensors", None),
    "widths": ("--widths", None),
    "slope": ("--slope", None),
    "learning_rate": ("--lr", None),
    "patience": ("--patience", None),
    "max_epochs": ("--max-epochs", None),
    "val_fraction": ("--val-fraction", None),
    "acc_range": ("--acc-range", None),
    "gyr_range": ("--gyr-range", _degs_to_rads),
    "turns": ("--turns", None),
    "partial": ("--partial", None),
}


def _option_defaults() -> dict[str, Any]:
    """Option field -> default, over every registered method's options type (a field that several
    types share has one default; ``tests/test_methods_contract.py`` checks it)."""
    return {f: d for m in methods.REGISTRY.values() for f, d in m.options._field_defaults.items()}


def _used_by(field: str) -> str:
    """The registered methods whose options have ``field``, e.g. ``"nn and online-thesis"``."""
    return " and ".join(m.name for m in methods.REGISTRY.values() if field in m.options._fields)


def _add_calibrate(p: argparse.ArgumentParser) -> None:
    nn = NNOptions._field_defaults
    p.add_argument("recording", metavar="RECORDING", help="recording (.npz or .csv; see CONVENTIONS.md)")
    p.add_argument(
        "--method",
        required=True,
        choices=methods.names(),
        help="calibration method (`jaxcal methods` says what each needs)",
    )
    p.add_argument("--out", required=True, metavar="MODEL.npz", help="model file to write")
    p.add_argument("--seed", type=_seed, default=nn["seed"],
                   help=f"PRNG seed in [0, 2**32 - 1] ({_used_by('seed')}; default {nn['seed']})")
    p.add_argument("--sensors", type=_sensors, default=nn["sensors"],
                   help=f"calibrate only these: acc, gyr or acc,gyr ({_used_by('sensors')}; default all)")
    g = p.add_argument_group("nn options")
    g.add_argument("--widths", type=_int_tuple, default=nn["widths"],
                   help=f"hidden widths, e.g. 7500 or 5,10,5 (default {','.join(map(str, nn['widths']))})")
    g.add_argument("--slope", type=_real(0.0, 1.0, open_low=False), default=nn["slope"],
                   help=f"leaky-ReLU slope in [0, 1] (default {nn['slope']:g})")
    g.add_argument("--lr", dest="learning_rate", metavar="LR", type=_real(0.0, 10.0), default=nn["learning_rate"],
                   help=f"Adam learning rate (default {nn['learning_rate']:g})")
    g.add_argument("--patience", type=_count(1, 10**9), default=nn["patience"],
                   help=f"early-stopping patience in epochs (default {nn['patience']})")
    g.add_argument("--max-epochs", type=_count(1, 10**9), default=nn["max_epochs"],
                   help=f"maximum full-batch epochs (default {nn['max_epochs']})")
    g.add_argument(
        "--val-fraction",
        type=_real(0.0, 1.0),
        default=nn["val_fraction"],
        help=f"share of labelled samples held out for early stopping, whole sequences if `seq` is given "
        f"(default {nn['val_fraction']:g})",
    )
    g.add_argument("--acc-range", type=_real(0.0, 1e6), default=nn["acc_range"],
                   help=f"accelerometer full scale in g for eq. 3.6 bounds (default {nn['acc_range']:g})")
    g.add_argument("--gyr-range", type=_real(0.0, 1e6), default=GYR_RANGE_DEGS,
                   help=f"gyroscope full scale in deg/s for eq. 3.6 bounds (default {GYR_RANGE_DEGS:g})")
    mp = MultiposOptions._field_defaults
    m = p.add_argument_group("multipos options")
    m.add_argument(
        "--turns", type=_turns, default=mp["turns"], metavar="T0-T1[,T0-T1...]",
        help="whole turns about the vertical (e.g. turned flat on a table), start-end in seconds; their axes "
        "are read from the accelerometer at the rests around them (no labels)",
    )
    m.add_argument(
        "--partial", action="store_const", const=True, default=mp["partial"],
        help="when the poses do not determine every combination, fit only those they do and leave the rest "
        "as recorded (recordings in g and rad/s; an undetermined gyroscope is not calibrated) instead of refusing",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")


def _method_options(args: argparse.Namespace) -> Any:
    """The options of ``args.method`` from the flags; a flag set away from its default that the
    method does not take is a usage error naming the flag and the methods that take it."""
    kind = methods.get(args.method).options
    values = {f: (conv(getattr(args, f)) if conv else getattr(args, f)) for f, (_, conv) in OPTION_FLAGS.items()}
    defaults = _option_defaults()
    for f, v in values.items():
        if f not in kind._fields and f in defaults and v != defaults[f]:
            raise UsageError(f"{OPTION_FLAGS[f][0]} is an option of {_used_by(f)}, not of {args.method}")
    return kind(**{f: v for f, v in values.items() if f in kind._fields})


def _run_calibrate(args: argparse.Namespace) -> int:
    if not args.out.lower().endswith(".npz"):
        raise UsageError(f"--out {args.out}: model files are .npz")
    _check_out_file(args.out, [args.recording])
    if not 0.0 < args.val_fraction < 1.0:
        raise UsageError(f"--val-fraction must lie in (0, 1), got {args.val_fraction}")
    options = _method_options(args)  # before reading data
    rec = load_recording(args.recording)
    log = _progress(args)
    t0 = time.perf_counter()
    try:
        model = methods.fit(args.method, rec, options, log=log)
    except ModelError as e:  # the recording does not suit the method: say which file
        raise ModelError(f"{args.recording}: {e}") from None
    save_model(model, args.out)
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


def _run_apply(args: argparse.Namespace) -> int:
    if not args.out.lower().endswith(".npz"):
        raise UsageError(f"--out {args.out}: calibrated output is written as .npz")
    _check_out_file(args.out, [args.model, args.recording])
    model = load_model(args.model)
    rec = load_recording(args.recording)
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
