"""The ``jaxcal`` command line (CONVENTIONS.md, "Command line").

::

    jaxcal calibrate --method METHOD RECORDING --out MODEL.npz [--seed N] [...]
    jaxcal apply MODEL.npz RECORDING --out CALIBRATED.npz
    jaxcal simulate dataset2 --out DIR [--seed N] [--labels]
    jaxcal simulate dataset1 --out DIR [--seed N]
    jaxcal import FORMAT FILE... --out REC.npz [--fs HZ] [...]
    jaxcal diagnose RECORDING --out DIR [--baseline diag|affine]
    jaxcal sweep CONFIG.json --out DIR [--resume]
    jaxcal export MODEL.npz --format json|c|kalibr|openvins --out FILE [--name NAME]
    jaxcal methods
    jaxcal --version

Subcommands live in the :data:`COMMANDS` table (name -> help, argument builder, handler); more
plug in with :func:`register_command`. This module only parses arguments and dispatches: methods
come from :mod:`jaxcal.methods` (each ``calibrate`` flag's default is its method's options type's),
model files from :mod:`jaxcal.model_file`, simulated recordings from
:mod:`jaxcal.simulate.recordings`. Exit status: 0 on
success; 2 on bad input, with exactly one line on stderr that says what is wrong and where (no
traceback); 130 on Ctrl-C. Bad input is refused where it is read (the readers, recording
validation with its plausibility checks, model loading, each method's requirements), before any
fit where the input alone shows it. Every output (file or ``--out DIR``) is written beside its
destination and moved into place only when complete, so a refused or interrupted run leaves
nothing behind and never damages an earlier file; an ``--out`` that is one of the inputs is
refused. Progress lines of long fits go to stderr (silence them with ``--quiet``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from jaxcal import __version__, methods, readers
from jaxcal.constants import GYR_RANGE_DEGS, SENSORS
from jaxcal.methods import ModelError, MultiposOptions, NNOptions
from jaxcal.model_file import load_model, save_model
from jaxcal.recording import Recording, RecordingError, atomic_output, load_recording, save_recording
from jaxcal.simulate import Dataset2Config
from jaxcal.simulate.recordings import dataset1_recordings, dataset2_recordings

__all__ = ["COMMANDS", "OPTION_FLAGS", "PROG", "Command", "UsageError", "build_parser", "main", "register_command"]

PROG = "jaxcal"


class UsageError(Exception):
    """Bad command-line input; printed as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage block) that main() turns into exit status 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        raise UsageError(f"{self.prog}: error: {message}")


class Command(NamedTuple):
    """A subcommand: one-line help, a function adding its arguments, and its handler.

    Attributes:
        help: one-line help, listed by ``jaxcal --help``.
        add_arguments: adds the subcommand's arguments to its ``argparse`` parser.
        run: the handler; takes the parsed arguments, returns the exit status.
        description: longer text of ``jaxcal NAME --help``; empty: ``help``.
    """

    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    description: str = ""


COMMANDS: dict[str, Command] = {}


def register_command(name: str, command: Command) -> None:
    """Add a subcommand to the ``jaxcal`` CLI (e.g. ``diagnose``, ``import``).

    Args:
        name: the subcommand's name (``jaxcal NAME``); an existing one is replaced.
        command: its :class:`Command`.
    """
    COMMANDS[name] = command


def _progress(args: argparse.Namespace) -> Callable[[str], None] | None:
    if getattr(args, "quiet", False):
        return None
    return lambda msg: print(f"{PROG}: {msg}", file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- argument types

SEED_MAX = 2**32 - 1  # jax.random.PRNGKey takes 32-bit seeds; larger ones overflow or alias
MAX_SIM_SEQUENCES = 20_000  # simulate: 101 samples each, so at most ~2 million samples per file


def _seed(text: str) -> int:
    """A PRNG seed: an integer in [0, 2**32 - 1]."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text!r}") from None
    if not 0 <= v <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"seed must lie in [0, {SEED_MAX}], got {text}")
    return v


def _real(low: float, high: float = math.inf, *, open_low: bool = True) -> Callable[[str], float]:
    """An argparse type: a finite float in ``(low, high]`` (``[low, high]`` if not ``open_low``)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        inside = (v > low if open_low else v >= low) and v <= high
        if not (math.isfinite(v) and inside):
            rng = f"{'(' if open_low else '['}{low:g}, {high:g}{']' if math.isfinite(high) else ')'}"
            raise argparse.ArgumentTypeError(f"expected a finite number in {rng}, got {text!r}")
        return v

    return parse


def _count(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: an integer in ``[low, high]``."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not low <= v <= high:
            raise argparse.ArgumentTypeError(f"expected an integer in [{low}, {high}], got {text}")
        return v

    return parse


# ----------------------------------------------------------------------------- output safety


def _same_file(a: Path, b: Path) -> bool:
    """Whether two paths name one file (the same inode, or the same resolved path)."""
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.resolve() == b.resolve()
    except OSError:
        return False


def _with_sidecars(paths: Sequence[str | Path]) -> list[Path]:
    """Paths plus the ``.json`` sidecar of every ``.csv`` among them (written or read alongside)."""
    out = []
    for p in map(Path, paths):
        out.append(p)
        if p.suffix.lower() == ".csv":
            out.append(p.with_suffix(".json"))
    return out


def _check_out_file(out: str, inputs: Sequence[str | Path]) -> None:
    """Refuse an ``--out`` file that is a directory or would overwrite one of the command's inputs
    (a recording, its CSV sidecar, a model)."""
    if Path(out).is_dir():
        raise UsageError(f"--out {out}: is a directory; name the file to write")
    for o in _with_sidecars([out]):
        for i in _with_sidecars(inputs):
            if i.exists() and _same_file(o, i):
                raise UsageError(f"--out {out}: would overwrite the input {i}; write the output elsewhere")


def _merge_into(src: Path, dst: Path) -> None:
    """Move every entry of ``src`` into the existing directory ``dst`` (same names replaced)."""
    for entry in src.iterdir():
        target = dst / entry.name
        if entry.is_dir() and target.is_dir():
            _merge_into(entry, target)
        else:
            os.replace(entry, target)


@contextlib.contextmanager
def _output_dir(path: str) -> Iterator[Path]:
    """A temporary directory to write ``--out DIR`` into, published only on success.

    On success its files move into ``DIR`` (created with its parents if needed; in an existing
    ``DIR`` same-named files are replaced, others kept). On any failure, Ctrl-C included, the
    temporary directory is removed: a refused or interrupted run leaves no folder and no partial
    file behind, and an existing ``DIR`` is untouched.
    """
    d = Path(path)
    if d.exists() and not d.is_dir():
        raise UsageError(f"--out {path}: exists and is not a directory")
    base = next(a for a in d.absolute().parents if a.exists())  # the nearest existing ancestor
    if not base.is_dir():
        raise UsageError(f"--out {path}: cannot create directory ({base} is not a directory)")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{d.name}.", suffix=".partial", dir=base))
    except OSError as e:
        raise UsageError(f"--out {path}: cannot create directory ({e.strerror or e})") from None
    try:
        yield tmp
        _publish_dir(tmp, d)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _publish_dir(tmp: Path, d: Path) -> None:
    """Move the finished temporary directory to ``d`` (or its files into an existing ``d``)."""
    try:
        if d.is_dir():
            _merge_into(tmp, d)
        else:
            d.parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp, d)
    except OSError as e:
        raise UsageError(f"--out {d}: cannot write ({e.strerror or e})") from None


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


# ----------------------------------------------------------------------------- simulate


def _add_simulate(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="dataset", metavar="DATASET", parser_class=_Parser)
    sub.required = True
    d2 = sub.add_parser(
        "dataset2",
        help="thesis Dataset 2 (section 4.2): rotation sequences + test sets",
        description="Write DIR/train.npz and DIR/val.npz (all sequences concatenated, `seq` ids, `static` "
        "ends, datasheet metadata, no labels unless --labels), DIR/test_acc.npz and DIR/test_gyr.npz "
        "(with acc_ref / gyr_ref labels) and DIR/truth.json (the hidden true sensor parameters).",
    )
    d2.add_argument("--out", required=True, metavar="DIR", help="output directory (created if needed)")
    d2.add_argument("--seed", type=_seed, default=0, help="PRNG seed in [0, 2**32 - 1] (default 0)")
    d2.add_argument("--labels", action="store_true", help="also store acc_ref/gyr_ref in train.npz and val.npz")
    d2.add_argument("--n-train", type=_count(1, MAX_SIM_SEQUENCES), default=None, help="training sequences (default 500)")
    d2.add_argument("--n-val", type=_count(1, MAX_SIM_SEQUENCES), default=None, help="validation sequences (default 100)")
    d2.add_argument("--format", choices=("npz", "csv"), default="npz", help="recording file format (default npz)")
    d1 = sub.add_parser(
        "dataset1",
        help="thesis Dataset 1 surrogate (section 3.4): labelled static orientations",
        description="Write DIR/train, DIR/val, DIR/test recordings (static samples with acc_ref labels) and "
        "DIR/truth.json, from jaxcal.simulate.dataset1.",
    )
    d1.add_argument("--out", required=True, metavar="DIR", help="output directory (created if needed)")
    d1.add_argument("--seed", type=_seed, default=0, help="PRNG seed in [0, 2**32 - 1] (default 0)")
    d1.add_argument("--format", choices=("npz", "csv"), default="npz", help="recording file format (default npz)")


def _write_all(d: Path, recs: dict[str, Recording], truth: dict[str, Any], fmt: str) -> list[str]:
    names = []
    for name, rec in recs.items():
        save_recording(rec, d / f"{name}.{fmt}")
        names.append(f"{name}.{fmt} ({rec.n} samples)")
    with open(d / "truth.json", "w") as fh:
        json.dump(truth, fh, indent=1)
    return names


def _run_simulate(args: argparse.Namespace) -> int:
    with _output_dir(args.out) as d:
        if args.dataset == "dataset2":
            kw = {name: getattr(args, name) for name in ("n_train", "n_val") if getattr(args, name) is not None}
            recs, truth = dataset2_recordings(args.seed, Dataset2Config(**kw), args.labels)
        else:
            recs, truth = dataset1_recordings(args.seed)
        names = _write_all(d, recs, truth, args.format)
    print(f"{PROG}: wrote {', '.join(names)} and truth.json to {args.out}", file=sys.stderr)
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
register_command(
    "simulate",
    Command("write simulated recordings (dataset2, dataset1)", _add_simulate, _run_simulate),
)
register_command("methods", Command("list the calibration methods", _add_methods, _run_methods))


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
    p.add_argument(
        "format",
        metavar="FORMAT",
        help="imu_tk (ACC GYR files), imucal (CSV [sections.json]; needs --fs), euroc / tumvi (IMU CSV "
        "[pose CSV]), mpu6050, fusion (x-io), broad (BROAD trial .mat), csv (generic; needs --columns)",
    )
    p.add_argument("files", nargs="+", metavar="FILE", help="input file(s) in that format")
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


def _run_import(args: argparse.Namespace) -> int:
    if not args.out.lower().endswith((".npz", ".csv")):
        raise UsageError(f"--out {args.out}: recordings are written as .npz or .csv")
    _check_out_file(args.out, args.files)
    names = {"fs": "fs", "acc_unit": "acc_unit", "gyr_unit": "gyr_unit", "time_unit": "time_unit",
             "columns": "columns", "units": "units", "skip_rows": "skip_rows"}
    options = {k: getattr(args, a) for a, k in names.items() if getattr(args, a) is not None}
    try:
        rec = readers.read(args.format, args.files, **options)
    except readers.ReaderError as e:
        raise UsageError(str(e)) from None
    except TypeError as e:  # an option this format does not take
        given = ", ".join("--" + k.replace("_", "-") for k in options) or "none"
        raise UsageError(f"format {args.format!r} does not take the options given ({given}): {e}") from None
    save_recording(rec, args.out)
    print(f"{PROG}: wrote {args.out} ({rec.n} samples, {', '.join(rec.sensors())})", file=sys.stderr)
    return 0


def _add_diagnose(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="RECORDING", help="recording with reference motion (acc_ref/gyr_ref or pos_ref+quat_ref)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory: report.json, report.md, figures")
    p.add_argument("--baseline", choices=("diag", "affine"), default="diag", help="baseline sensor model (default diag)")


def _run_diagnose(args: argparse.Namespace) -> int:
    from jaxcal import diagnose as diag  # imported on use: it adds about a second to every command

    rec = load_recording(args.recording)
    t0 = time.perf_counter()
    with _output_dir(args.out) as d:
        try:
            diag.prepare(rec)  # refuse bad input (no reference motion, too short) before any progress line
            print(f"{PROG}: diagnosing {args.recording} against the {args.baseline} baseline ...", file=sys.stderr)
            rep = diag.diagnose_recording(rec, baseline=args.baseline, out_dir=d)
        except ValueError as e:  # documented: bad input
            raise UsageError(f"{args.recording}: {e}") from None
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
    "import",
    Command(
        "convert a public IMU format to a jaxcal recording",
        _add_import,
        _run_import,
        "Read FILE(s) in FORMAT (jaxcal.readers) and write a recording per CONVENTIONS.md.",
    ),
)
register_command(
    "diagnose",
    Command(
        "find the effects a sensor model leaves out (report.json)",
        _add_diagnose,
        _run_diagnose,
        "Fit the baseline sensor model to RECORDING against its reference motion, test the effects of "
        "the discrepancy vocabulary (CONVENTIONS.md) and write DIR/report.json, report.md and figures.",
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


def _add_sweep(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", metavar="CONFIG", help="sweep spec (JSON; see docs/sweep_example.json)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output directory: sweep.json, sweep.md, sweep_heatmap.png; checkpoint.json while running")
    p.add_argument("--resume", action="store_true", help="skip the batches already in DIR/checkpoint.json")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def _run_sweep(args: argparse.Namespace) -> int:
    from jaxcal import sweep as sw  # imported on use

    try:
        spec = sw.load_sweep_spec(args.config)
    except ValueError as e:  # documented: bad input
        raise UsageError(str(e)) from None
    d = Path(args.out)
    if d.exists() and not d.is_dir():
        raise UsageError(f"--out {args.out}: exists and is not a directory")
    if not args.resume and (d / sw.CHECKPOINT).exists():
        raise UsageError(f"--out {args.out}: holds a checkpoint; add --resume to continue it, or choose another DIR")
    n = len(sw.expand(spec))
    log = _progress(args)
    if log is not None:
        log(f"sweep {args.config}: {n} runs in {len(sw.plan(spec))} batch(es) -> {args.out}")
    t0 = time.perf_counter()
    try:
        res = sw.run_sweep(spec, out_dir=d, resume=args.resume, log=log)
    except ValueError as e:  # a checkpoint of another spec
        raise UsageError(str(e)) from None
    sw.write_sweep(d, res)
    print(f"{PROG}: wrote {d / 'sweep.json'} ({len(res.rows)} runs) in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


register_command(
    "sweep",
    Command(
        "hyperparameter sweep (grid or random search), vmapped and sharded over the local devices",
        _add_sweep,
        _run_sweep,
        "Run the sweep of CONFIG (jaxcal.sweep: target, grid and/or random search, seeds, dataset) as one "
        "vmapped, jitted call per compile-compatible batch on all local devices, checkpointing DIR/checkpoint.json "
        "after each; write DIR/sweep.json, sweep.md and sweep_heatmap.png.",
    ),
)


# ----------------------------------------------------------------------------- export

_EXPORT_SUFFIX = {"json": ".json", "c": ".h", "kalibr": ".yaml", "openvins": ".yaml"}


def _c_identifier(text: str) -> str:
    if not (text.isascii() and text.replace("_", "a").isalnum() and not text[0].isdigit()):
        raise argparse.ArgumentTypeError(f"expected a C identifier (letters, digits, '_'), got {text!r}")
    return text


def _add_export(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", metavar="MODEL", help="linear model file written by `jaxcal calibrate` (linear, multipos, online)")
    p.add_argument("--format", required=True, choices=tuple(_EXPORT_SUFFIX),
                   help="json: plain JSON with the apply equation written out; c: dependency-free C99 header; "
                   "kalibr: Kalibr scale-misalignment IMU intrinsics (YAML); openvins: OpenVINS kalibr_imu_chain.yaml "
                   "intrinsics (kalibr and openvins need acc and gyr)")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="file to write (.json for json, .h for c, .yaml for kalibr and openvins)")
    p.add_argument("--name", type=_c_identifier, default="jaxcal_cal",
                   help="c: prefix of the header's identifiers (default jaxcal_cal)")


def _run_export(args: argparse.Namespace) -> int:
    from jaxcal import export  # imported on use, like diagnose

    suffix = _EXPORT_SUFFIX[args.format]
    if not args.out.lower().endswith(suffix):
        raise UsageError(f"--out {args.out}: the {args.format} export is written as {suffix}")
    _check_out_file(args.out, [args.model])
    model = load_model(args.model)
    try:
        if args.format == "json":
            text = json.dumps(export.to_json(model), indent=2) + "\n"
        elif args.format == "kalibr":
            text = export.yaml_document("kalibr", export.to_kalibr(model))
        elif args.format == "openvins":
            text = export.yaml_document("openvins", export.to_openvins(model))
        else:
            text = export.to_c_header(model, args.name)
    except ModelError as e:  # a non-linear model, a missing sensor, a singular matrix: say which file
        raise ModelError(f"{args.model}: {e}") from None
    try:
        with atomic_output(args.out) as tmp, open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
    except OSError as e:
        raise UsageError(f"{args.out}: cannot write ({e.strerror or e})") from None
    print(f"{PROG}: wrote {args.out} ({args.format}: {model.method} model, {export.EQUATION} for "
          f"{', '.join(model.sensors)})", file=sys.stderr)
    return 0


register_command(
    "export",
    Command(
        "write a linear model as plain JSON, a C99 header, or Kalibr/OpenVINS IMU intrinsics",
        _add_export,
        _run_export,
        "Write the linear calibration x = A @ (y - b) of each sensor of MODEL (methods linear, multipos, "
        "online) as plain JSON (--format json) or a dependency-free C99 header with an apply function "
        "(--format c), or as Kalibr's scale-misalignment / OpenVINS's kalibr_imu_chain.yaml IMU intrinsics "
        "(--format kalibr|openvins: YAML, acc in m/s^2 and gyr in rad/s from raw samples in the model's input "
        "unit; both sensors needed). Non-linear models (nn, cubic, online-thesis) are refused.",
    ),
)


# ----------------------------------------------------------------------------- main


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser (all registered subcommands)."""
    parser = _Parser(
        prog=PROG,
        description="jaxcal: IMU (accelerometer + gyroscope) calibration in JAX. Recordings are .npz or .csv "
        "files with t, acc and/or gyr in LSB (see CONVENTIONS.md). Exit status 2 on bad input.",
        epilog="examples: jaxcal simulate dataset2 --out d2 --labels; "
        "jaxcal calibrate --method linear d2/train.npz --out lin.npz; "
        "jaxcal apply lin.npz d2/test_acc.npz --out cal.npz",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name, cmd in COMMANDS.items():
        p = sub.add_parser(name, help=cmd.help, description=cmd.description or cmd.help)
        cmd.add_arguments(p)
    return parser


def _bad_input_errors() -> tuple[type[BaseException], ...]:
    """The exceptions that mean bad input (exit status 2, one line): usage, recording, model and
    reader errors."""
    return (UsageError, RecordingError, ModelError, readers.ReaderError)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit status (0 ok, 2 bad input, 130 interrupted).

    Every command writes its output whole or not at all, so a refused or interrupted run leaves
    nothing behind (and an earlier file at ``--out`` intact).
    """
    try:
        parser = build_parser()
        try:
            args = parser.parse_args(argv)
        except SystemExit as e:  # --help / --version
            return int(e.code or 0)
        return COMMANDS[args.command].run(args)
    except _bad_input_errors() as e:
        msg = " ".join(str(e).split())
        prefix = "" if msg.startswith(PROG) else f"{PROG}: error: "
        print(f"{prefix}{msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted (no partial output left behind)", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
