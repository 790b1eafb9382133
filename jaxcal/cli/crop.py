"""``jaxcal crop``: a stretch of a recording, as a recording every other command reads."""

from __future__ import annotations

import argparse
import sys

from jaxcal.cli.core import PROG, Command, UsageError, _check_out_file, _real, register_command
from jaxcal.recording import crop, load_recording, save_recording

__all__: list[str] = []


def _add_crop(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="REC", help="recording (.npz or .csv)")
    p.add_argument("--start", type=_real(0.0, open_low=False), default=0.0, metavar="S",
                   help="first second kept, counted from the recording's first sample (default 0)")
    p.add_argument("--end", type=_real(0.0), default=None, metavar="S",
                   help="end of the stretch (s from the first sample, not included; default: to the end)")
    p.add_argument("--out", required=True, metavar="REC", help="recording to write (.npz or .csv)")


def _run_crop(args: argparse.Namespace) -> int:
    if args.end is not None and args.end <= args.start:
        raise UsageError(f"--end {args.end:g} must be after --start {args.start:g}")
    _check_out_file(args.out, [args.recording])
    rec = load_recording(args.recording)
    try:
        out = crop(rec, args.start, args.end)
    except ValueError as e:
        raise UsageError(f"{args.recording}: --start/--end: {e}") from None
    save_recording(out, args.out)
    print(f"{PROG}: wrote {args.out} ({out.n} of {rec.n} samples, {out.t[0] - rec.t[0]:.3f}-{out.t[-1] - rec.t[0]:.3f} s "
          f"after the first sample)", file=sys.stderr)
    return 0


register_command(
    "crop",
    Command(
        "keep a stretch of a recording (seconds from its first sample)",
        _add_crop,
        _run_crop,
        "Write the samples of REC from --start to --end seconds after its first sample as a recording that "
        "every other command reads (the reference pose track, where there is one, cut alike).",
    ),
)
