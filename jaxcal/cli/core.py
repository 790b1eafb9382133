"""The ``jaxcal`` command line (CONVENTIONS.md, "Command line").

::

    jaxcal calibrate --method METHOD RECORDING --out MODEL.npz [--seed N] [...]
    jaxcal apply MODEL.npz RECORDING --out CALIBRATED.npz
    jaxcal score MODEL.npz RECORDING [--out SCORE.json]
    jaxcal simulate dataset2 --out DIR [--seed N] [--labels]
    jaxcal simulate dataset1 --out DIR [--seed N]
    jaxcal import FORMAT FILE... --out REC.npz [--fs HZ] [...]
    jaxcal import rosbag BAG --imu-topic T [--pose-topic P] --out REC.npz
    jaxcal diagnose RECORDING --out DIR [--baseline diag|affine] [--model-out MODEL.npz]
    jaxcal align RECORDING --out DIR
    jaxcal noise RECORDING --out DIR [--start S --end S]
    jaxcal sweep CONFIG.json --out DIR [--resume]
    jaxcal export MODEL.npz --format json|c|kalibr|openvins|imucal --out FILE [--name NAME] [--noise IMU_YAML]
    jaxcal import-model imucal|json|kalibr|openvins FILE --out MODEL.npz [--drop-g-sensitivity]
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
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

from jaxcal.flags import count as _count  # noqa: F401  (the argument types the commands import from here;
from jaxcal.flags import real as _real  # noqa: F401  one copy, in jaxcal.flags, shared with the method
from jaxcal.flags import seed as _seed  # noqa: F401  options' flags)

__all__ = ["COMMANDS", "PROG", "Command", "UsageError", "register_command"]

PROG = "jaxcal"


class UsageError(Exception):
    """Bad command-line input; printed as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage block) that main() turns into exit status 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        raise UsageError(f"{self.prog}: error: {message}")


class _LazyParser(_Parser):
    """A subcommand's parser whose arguments are added on its first use (parsing, help or usage), by
    ``build``: building every command's flags would import what each needs (the methods, jax), and
    ``jaxcal --help`` or another command needs none of it."""

    def __init__(self, *args, build: Callable[[argparse.ArgumentParser], None] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self._build = build

    def _built(self) -> None:
        build, self._build = self._build, None
        if build is not None:
            build(self)

    def parse_known_args(self, args=None, namespace=None):  # noqa: D102 - argparse API
        self._built()
        return super().parse_known_args(args, namespace)

    def format_usage(self) -> str:  # noqa: D102 - argparse API
        self._built()
        return super().format_usage()

    def format_help(self) -> str:  # noqa: D102 - argparse API
        self._built()
        return super().format_help()


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
# (_seed, _real, _count: imported above from jaxcal.flags)

MAX_SIM_SEQUENCES = 20_000  # simulate: 101 samples each, so at most ~2 million samples per file


DATASHEET_FLAGS = (("acc_lsb_per_g", "--acc-lsb-per-g", "acc", "LSB/g"),
                   ("gyr_lsb_per_rads", "--gyr-lsb-per-rads", "gyr", "LSB/(rad/s)"))
"""The datasheet-scale flags (recording key, flag, sensor, unit) of ``export`` and ``noise``."""


def _add_datasheet_flags(p: argparse.ArgumentParser, what: str) -> None:
    """``--acc-lsb-per-g`` / ``--gyr-lsb-per-rads`` (one value or three); ``what`` starts each help."""
    for key, flag, sensor, unit in DATASHEET_FLAGS:
        p.add_argument(flag, dest=key, type=float, nargs="+", default=None, metavar="SCALE",
                       help=f"{what} the datasheet {sensor} scale ({unit}, one value or three)")


def _datasheet_values(args: argparse.Namespace) -> dict:
    """The datasheet flags given, ``key -> value`` (a float, or a list of three); a wrong count is a
    :class:`UsageError` naming the flags."""
    got = {key: getattr(args, key) for key, *_ in DATASHEET_FLAGS if getattr(args, key) is not None}
    if any(len(v) not in (1, 3) for v in got.values()):
        raise UsageError(f"{' / '.join(f for _, f, *_ in DATASHEET_FLAGS)} take one value or three")
    return {k: v if len(v) > 1 else v[0] for k, v in got.items()}


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
    ``DIR`` same-named files are replaced, others kept); a new ``DIR`` gets the mode ``mkdir`` gives
    (0777 less the umask), not ``mkdtemp``'s 0700. On any failure, Ctrl-C included, the
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
        tmp.chmod(0o777 & ~_umask())  # mkdtemp makes it 0700; the published folder gets mkdir's usual mode
    except OSError as e:
        raise UsageError(f"--out {path}: cannot create directory ({e.strerror or e})") from None
    try:
        yield tmp
        _publish_dir(tmp, d)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _umask() -> int:
    """The process's file-creation mask (read by setting it and restoring it at once)."""
    m = os.umask(0o022)
    os.umask(m)
    return m


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


