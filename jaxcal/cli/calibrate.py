"""``jaxcal calibrate``, ``jaxcal apply`` and ``jaxcal methods``: fit a model, apply it, list the methods."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.cli.core import PROG, Command, UsageError, _check_out_file, _progress, _real, register_command
from jaxcal.flags import Flag
from jaxcal.recording import atomic_output, load_recording

# The methods (jax, flax, optimistix) are imported inside the functions that use them, so that
# registering these commands costs nothing (`jaxcal --help`, other commands).

__all__ = ["OPTION_FLAGS", "STARTUP_BIAS_NOTE", "Flag", "applied_output", "method_options", "not_carried_text", "options_from_diagnose",
           "rest_bias"]


# ----------------------------------------------------------------------------- calibrate


class _RegistryFlags(Mapping[str, Flag]):
    """Method option field (the argparse dest) -> its flag, as the registered methods' options types
    declare them (``FLAGS``, :mod:`jaxcal.flags`), read from :data:`jaxcal.methods.REGISTRY` on each
    use (a method registered later brings its flags). A field several types share has one flag
    (``tests/test_methods_contract.py`` checks it); its first declaration is used."""

    def _table(self) -> dict[str, Flag]:
        from jaxcal import methods

        out: dict[str, Flag] = {}
        for m in methods.REGISTRY.values():
            declared = getattr(m.options, "FLAGS", {})
            for field in m.options._fields:
                if field in declared:
                    out.setdefault(field, declared[field])
        return out

    def __getitem__(self, field: str) -> Flag:
        return self._table()[field]

    def __iter__(self) -> Iterator[str]:
        return iter(self._table())

    def __len__(self) -> int:
        return len(self._table())


OPTION_FLAGS: Mapping[str, Flag] = _RegistryFlags()


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
    p.add_argument("--from-diagnose", metavar="REPORT",
                   help="switch on the options that model what a `jaxcal diagnose` report names (its report.json, or "
                        "the folder it wrote): e.g. a named gyr g_sensitivity sets --g-sensitivity (online, multipos); "
                        "the named effects the method cannot model are listed")
    defaults = _option_defaults()
    groups: dict[str, argparse._ArgumentGroup] = {}
    for field, spec in dict(OPTION_FLAGS).items():
        used = _used_by(field)
        if not used:
            continue
        g = groups.setdefault(used, p.add_argument_group(f"options of {used}"))
        text = f"{spec.help} ({used}; default {_default_text(field, spec, defaults)})"
        if spec.parse is None:
            g.add_argument(spec.flag, dest=field, action="store_const", const=spec.const, default=argparse.SUPPRESS,
                           help=text)
        else:
            g.add_argument(spec.flag, dest=field, default=argparse.SUPPRESS, metavar=spec.metavar, choices=spec.choices,
                           help=text)
    p.add_argument("--force", action="store_true",
                   help="write the model even where its own held-out figure or a plausible range contradicts it "
                        "(with a warning; default: refuse, exit 2)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")


def method_options(args: argparse.Namespace) -> Any:
    """The options of ``args.method`` from the flags given (the others keep the options type's
    defaults). Every problem (a value that does not parse, a flag of another method) is collected
    and reported at once, naming the flags, as one usage error."""
    from jaxcal import methods

    kind = methods.get(args.method).options
    values, errors = {}, []
    for field, spec in dict(OPTION_FLAGS).items():
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


def options_from_diagnose(path: str, options: Any, method: str) -> Any:
    """``options`` with what the ``jaxcal diagnose`` report at ``path`` (``report.json`` or the folder
    holding it) names switched on (:func:`jaxcal.methods.from_report.options_from_report`); one line on
    stderr says what was used and what the method cannot model. A missing or malformed report is a
    usage error naming ``--from-diagnose``."""
    from jaxcal.methods.from_report import options_from_report

    f = Path(path) / "report.json" if Path(path).is_dir() else Path(path)
    try:
        out = options_from_report(options, json.loads(f.read_text()))
    except OSError as e:
        raise UsageError(f"--from-diagnose {path}: cannot read {f} ({e.strerror or e})") from None
    except ValueError as e:  # not JSON, or not a report
        raise UsageError(f"--from-diagnose {path}: {f}: {str(e).splitlines()[0]}") from None
    used = ", ".join(out.modelled) or "nothing"
    rest = f"; not in {method}'s model: {', '.join(out.not_modelled)}" if out.not_modelled else ""
    print(f"{PROG}: from {f}: {method} models {used}{rest}", file=sys.stderr)
    return out


def _run_calibrate(args: argparse.Namespace) -> int:
    from jaxcal import methods
    from jaxcal.methods import CalibrationModel, ModelError
    from jaxcal.methods.summary import contradiction, describe, summary_lines
    from jaxcal.model_file import save_model

    if not args.out.lower().endswith(".npz"):
        raise UsageError(f"--out {args.out}: model files are .npz")
    _check_out_file(args.out, [args.recording])
    options = method_options(args)  # before reading data
    from_report = None
    if args.from_diagnose is not None:
        from_report = options_from_diagnose(args.from_diagnose, options, args.method)
        options = from_report.options
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
    if from_report is not None:
        desc = {**desc, "from_diagnose": {"report": str(args.from_diagnose), "modelled": list(from_report.modelled),
                                          "not_modelled": list(from_report.not_modelled)}}
    model = CalibrationModel(model.method, model.sensors, model.state, {**model.meta, **desc})
    save_model(model, args.out)
    for line in summary_lines(desc):
        print(line)
    if log and "gyr" in model.sensors:
        log(f"note: {STARTUP_BIAS_NOTE}; `jaxcal apply --rest-bias SEC` takes another recording's from its first SEC "
            "seconds at rest")
    if log:
        log(f"wrote {args.out} ({args.method}, sensors {','.join(model.sensors)}) in {time.perf_counter() - t0:.1f} s")
    return 0


# ----------------------------------------------------------------------------- apply


def _add_apply(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", metavar="MODEL", help="model file written by `jaxcal calibrate`")
    p.add_argument("recording", metavar="RECORDING", help="recording to calibrate (.npz or .csv)")
    p.add_argument(
        "--out", required=True, metavar="OUT.npz",
        help="output: a recording every command reads (acc in g, gyr in rad/s, every other field kept), plus "
             "t, and acc_cal (g) and/or gyr_cal (rad/s)")
    p.add_argument("--rest-bias", type=_real(0.0), default=None, metavar="SEC",
                   help="replace the model's gyro bias by this power-up's: the mean calibrated gyro over the recording's "
                        "first SEC seconds, which must be at rest (default: the model's bias)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines or notes on stderr")
    p.add_argument("--allow-extrapolation", action="store_true",
                   help="apply even where the recording lies outside the model's fitted range (a cubic model's input "
                        "bounds, a diagnosed model's temperature range or time offset): warn on stderr instead of refusing")


STARTUP_BIAS_NOTE = ("a gyro's start-up bias changes at every power-up (the MPU-6050's by up to 0.10 deg/s on its next "
                     "recording), so the model's gyro bias is its fit recording's")
"""The note ``calibrate`` and ``apply`` print when a gyroscope is calibrated (issue 29)."""


def applied_output(model_path: str, rec_path: str, allow_extrapolation: bool) -> tuple[Any, Any, dict[str, np.ndarray]]:
    """Load a model and a recording and apply the one to the other (``jaxcal apply``, ``jaxcal
    score``): ``(model, recording, {"acc_cal", "gyr_cal"})``. A recording outside the model's fitted
    range is refused naming ``--allow-extrapolation`` (with it: one warning line per problem)."""
    from jaxcal.methods import ModelError
    from jaxcal.model_file import load_model
    from jaxcal.plausible import apply_range_problems

    model = load_model(model_path)
    rec = load_recording(rec_path)
    problems = apply_range_problems(model.method, model.state, model.meta, rec)
    if problems and not allow_extrapolation:
        raise UsageError(f"{model_path} on {rec_path}: {problems[0]} (--allow-extrapolation applies it anyway)")
    for why in problems:
        print(f"{PROG}: warning: {why}", file=sys.stderr)
    try:
        out = model.apply(rec)
    except ModelError as e:  # the model does not suit the recording (or is malformed): say which files
        raise ModelError(f"{model_path} on {rec_path}: {e}") from None
    return model, rec, out


def _run_apply(args: argparse.Namespace) -> int:
    from jaxcal.recording import RecordingError, save_recording, validate_recording, with_calibrated

    if not args.out.lower().endswith(".npz"):
        raise UsageError(f"--out {args.out}: calibrated output is written as .npz")
    _check_out_file(args.out, [args.model, args.recording])
    model, rec, out = applied_output(args.model, args.recording, args.allow_extrapolation)
    log = _progress(args)
    if args.rest_bias is not None:
        out = rest_bias(out, rec, args.rest_bias, log)
    elif "gyr_cal" in out and log:
        log(f"note: {STARTUP_BIAS_NOTE}; --rest-bias SEC takes this recording's from its first SEC seconds at rest")
    lost = not_carried_text(model.meta)
    if lost and log:
        log(f"note: {args.model} does not carry what its fit found of: {lost}")
    cal = with_calibrated(rec, out).replace(extra={**rec.extra, **out})
    try:
        validate_recording(cal, args.out)
    except RecordingError as e:  # an implausible output is still written, as the calibrated arrays alone
        cal = None
        print(f"{PROG}: warning: {args.out} holds t and {', '.join(out)} only, not a recording other commands read: "
              f"{' '.join(str(e).split())}", file=sys.stderr)
    try:
        if cal is not None:
            save_recording(cal, args.out)
        else:
            with atomic_output(args.out) as tmp, open(tmp, "wb") as fh:
                np.savez_compressed(fh, t=np.asarray(rec.t), **out)
    except (OSError, RecordingError) as e:
        raise UsageError(f"{args.out}: cannot write ({getattr(e, 'strerror', None) or e})") from None
    if log:
        log(f"wrote {args.out}: {', '.join(out)} for {rec.n} samples" + (" (a recording every command reads)" if cal else ""))
    return 0


def not_carried_text(meta: Any) -> str:
    """What a model's fit found but the model does not apply (``meta["not_carried"]``: a diagnosed
    model's bias drift, saturation, ...), as ``"acc bias_drift (why); ..."``; empty when nothing."""
    items = meta.get("not_carried") if isinstance(meta, Mapping) else None
    if not isinstance(items, list):
        return ""
    return "; ".join(f"{e.get('sensor', '')} {e.get('name', '')} ({e.get('why', '')})".strip()
                     for e in items if isinstance(e, Mapping))


def rest_bias(out: dict[str, np.ndarray], rec: Any, seconds: float, log: Any) -> dict[str, np.ndarray]:
    """``out`` with the gyro's start-up bias of this recording removed (:func:`jaxcal.static.initial_rest_bias`)."""
    from jaxcal.static import initial_rest_bias

    if "gyr_cal" not in out:
        raise UsageError("--rest-bias: the model calibrates no gyroscope on this recording")
    try:
        b = initial_rest_bias(rec.t, out["gyr_cal"], seconds)
    except ValueError as e:
        raise UsageError(f"--rest-bias {seconds:g}: {e}") from None
    if log:
        log(f"--rest-bias: this power-up's gyro bias over the first {seconds:g} s: "
            f"[{', '.join(f'{x:+.4f}' for x in np.degrees(b))}] deg/s, removed")
    return {**out, "gyr_cal": out["gyr_cal"] - b}


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
        "Apply MODEL to RECORDING; write OUT.npz, a recording every command reads (acc in g, gyr in rad/s, the "
        "labels, pose, seq ids and other fields of RECORDING kept), which also holds acc_cal (g) and/or gyr_cal "
        "(rad/s). The gyro bias is the model's (its fit recording's power-up); --rest-bias SEC takes this one's.",
    ),
)

register_command("methods", Command("list the calibration methods", _add_methods, _run_methods))
