"""``jaxcal sweep``: hyperparameter sweeps from a JSON spec."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from jaxcal.cli.core import PROG, Command, UsageError, _progress, register_command

__all__: list[str] = []


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
