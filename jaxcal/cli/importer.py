"""``jaxcal import``: public IMU formats to a jaxcal recording (each a reader of :data:`jaxcal.formats.REGISTRY`)."""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Iterable
from typing import TYPE_CHECKING

from jaxcal.cli.core import PROG, Command, UsageError, _check_out_file, register_command
from jaxcal.flags import Flag
from jaxcal.recording import save_recording

if TYPE_CHECKING:
    from jaxcal.formats.base import Format

__all__: list[str] = []


# ----------------------------------------------------------------------------- import, diagnose
# Everything format-specific (the reader options' flags, which reader takes which, the help on each
# reader) is data on the registered readers (jaxcal.formats.Format: flags, own_options, needs,
# read_help, files_help): a reader with a new option needs no edit here.


def _readers() -> list[Format]:
    """The registered readers (:class:`~jaxcal.formats.base.Format` with ``read``), in registration order."""
    from jaxcal import formats  # imported when the command is parsed, not when it registers

    return [f for f in formats.REGISTRY.values() if f.read is not None]


def _reader_flags() -> dict[str, Flag]:
    """Reader option (the argparse dest) -> its flag, over the registered readers' ``flags``, in
    registration order; an option several readers take has one flag (the first declared;
    ``tests/test_formats_contract.py`` checks they agree)."""
    out: dict[str, Flag] = {}
    for f in _readers():
        for opt, spec in (f.flags or {}).items():
            out.setdefault(opt, spec)
    return out


def _format_help() -> str:
    """FORMAT's help: each reader's name and ``read_help``, readers in a row with the same text named together."""
    groups: list[tuple[list[str], str]] = []
    for f in _readers():
        if groups and f.read_help and groups[-1][1] == f.read_help:
            groups[-1][0].append(f.name)
        else:
            groups.append(([f.name], f.read_help))
    return ", ".join(" / ".join(names) + (f" ({text})" if text else "") for names, text in groups)


def _add_import(p: argparse.ArgumentParser) -> None:
    p.add_argument("format", metavar="FORMAT", help=_format_help())
    notes = "; ".join(f"{f.name}: {f.files_help}" for f in _readers() if f.files_help)
    p.add_argument("files", nargs="+", metavar="FILE", help="input file(s) in that format" + (f" ({notes})" if notes else ""))
    p.add_argument("--out", required=True, metavar="REC.npz", help="recording to write (.npz or .csv)")
    for opt, spec in _reader_flags().items():
        if spec.parse is None:
            p.add_argument(spec.flag, dest=opt, action="store_const", const=spec.const, default=None, help=spec.help)
        else:
            p.add_argument(spec.flag, dest=opt, type=spec.parse, choices=spec.choices, default=None, metavar=spec.metavar, help=spec.help)


def _flag(opt: str) -> str:
    """The flag of reader option ``opt`` (``fs`` -> ``--fs``)."""
    spec = _reader_flags().get(opt)
    return spec.flag if spec is not None else "--" + opt.replace("_", "-")


def _flags(names: Iterable[str], args: argparse.Namespace) -> list[str]:
    """The given (non-default) options among ``names``, as flags."""
    return [_flag(a) for a in names if getattr(args, a, None) is not None]


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
        owner = " / ".join(dict.fromkeys(owners[o] for o in foreign if getattr(args, o, None) is not None))
        raise UsageError(f"{', '.join(_flags(foreign, args))}: only for the {owner} format, not {args.format!r}")
    if fmt.own_options:  # a reader with options of its own takes no others
        others = [o for o in _reader_flags() if o not in owners]
        if _flags(others, args):
            raise UsageError(f"format {fmt.name!r} does not take {', '.join(_flags(others, args))}")
    for opt, what in (fmt.needs or {}).items():
        if getattr(args, opt, None) is None:
            raise UsageError(f"format {fmt.name!r} needs {_flag(opt)} {what}")


def _run_import(args: argparse.Namespace) -> int:
    from jaxcal import formats

    if not args.out.lower().endswith((".npz", ".csv")):
        raise UsageError(f"--out {args.out}: recordings are written as .npz or .csv")
    _check_out_file(args.out, args.files)
    _check_reader(args)
    options = {k: (spec.conv(v) if spec.conv else v) for k, spec in _reader_flags().items() if (v := getattr(args, k)) is not None}
    try:
        rec = formats.read(args.format, args.files, **options)
    except formats.ReaderError as e:
        raise UsageError(str(e)) from None
    except TypeError as e:  # an option this format does not take: name its flag, not the Python argument
        bad = re.search(r"argument '(\w+)'", str(e))
        given = ", ".join(_flag(k) for k in options) or "none"
        what = _flag(bad.group(1)) if bad and bad.group(1) in options else f"the options given ({given})"
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
