"""The ``jaxcal`` command line: the parser built from the registered subcommands, and :func:`main`.

:mod:`jaxcal.cli.core` holds the shared machinery (:class:`Command`, :func:`register_command`,
argument types, atomic outputs); each subcommand lives in its own module and registers itself on
import.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from jaxcal._version import __version__
from jaxcal.cli import calibrate, crop, diagnose, export, importer, noise, score, simulate, sweep  # noqa: F401 - they register their commands
from jaxcal.cli.calibrate import OPTION_FLAGS
from jaxcal.cli.core import COMMANDS, PROG, Command, UsageError, _LazyParser, _Parser, register_command
from jaxcal.recording import RecordingError

__all__ = ["COMMANDS", "NO_CACHE_ENV", "OPTION_FLAGS", "PROG", "Command", "UsageError", "build_parser", "cache_dir", "main",
           "register_command"]


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
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_LazyParser)
    sub.required = True
    for name, cmd in COMMANDS.items():
        sub.add_parser(name, help=cmd.help, description=cmd.description or cmd.help, build=_arguments_of(cmd))
    return parser


def _arguments_of(cmd: Command) -> Callable[[argparse.ArgumentParser], None]:
    """What adds ``cmd``'s arguments to its parser, run when that parser is first used: the flags of
    one command may need heavy imports (e.g. ``calibrate``'s defaults come from the methods)."""

    def build(p: argparse.ArgumentParser) -> None:
        cmd.add_arguments(p)
        p.add_argument("--no-cache", action="store_true", default=argparse.SUPPRESS,
                       help=f"do not use the persistent compilation cache ({NO_CACHE_ENV}=1 does the same)")

    return build


NO_CACHE_ENV = "JAXCAL_NO_CACHE"
CACHE_MIN_COMPILE_SECS = 0.5  # cache every compile worth keeping (the Makefile keeps all for the suite) ...
CACHE_MIN_ENTRY_BYTES = 0  # ... whatever its size


def cache_dir(environ: dict[str, str] | None = None) -> Path | None:
    """The persistent compilation cache ``main`` uses: ``None`` when ``JAX_COMPILATION_CACHE_DIR``
    is set (jax then uses it as it is) or ``JAXCAL_NO_CACHE`` is set to a non-empty value other than
    ``0``; else ``$XDG_CACHE_HOME/jaxcal/jax`` (``~/.cache/jaxcal/jax``).

    Args:
        environ: the environment (``os.environ`` if ``None``).
    """
    env = os.environ if environ is None else environ
    if env.get("JAX_COMPILATION_CACHE_DIR") or env.get(NO_CACHE_ENV, "") not in ("", "0"):
        return None
    base = env.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "jaxcal" / "jax"


def _use_cache(args: argparse.Namespace) -> None:
    """Point jax's persistent compilation cache at :func:`cache_dir` (a second call of a command
    then skips most compiling), unless ``--no-cache``, the opt-out variable or the user's own
    ``JAX_COMPILATION_CACHE_DIR``."""
    d = None if getattr(args, "no_cache", False) else cache_dir()
    if d is None:
        return
    import jax

    jax.config.update("jax_compilation_cache_dir", str(d))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", CACHE_MIN_COMPILE_SECS)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", CACHE_MIN_ENTRY_BYTES)


def _is_bad_input(e: BaseException) -> bool:
    """Whether ``e`` means bad input (exit status 2, one line): a usage, recording, model or reader
    error. The last two are imported only here, when an exception is being judged, not on every
    start."""
    if isinstance(e, (UsageError, RecordingError)):
        return True
    from jaxcal.formats import ReaderError
    from jaxcal.methods.base import ModelError

    return isinstance(e, (ModelError, ReaderError))


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
        _use_cache(args)
        return COMMANDS[args.command].run(args)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted (no partial output left behind)", file=sys.stderr)
        return 130
    except Exception as e:
        if not _is_bad_input(e):
            raise
        msg = " ".join(str(e).split())
        prefix = "" if msg.startswith(PROG) else f"{PROG}: error: "
        print(f"{prefix}{msg}", file=sys.stderr)
        return 2

