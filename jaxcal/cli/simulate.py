"""``jaxcal simulate``: write simulated recordings (dataset1, dataset2)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from jaxcal.cli.core import MAX_SIM_SEQUENCES, PROG, Command, _count, _output_dir, _Parser, _seed, register_command
from jaxcal.recording import Recording, save_recording

__all__: list[str] = []


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
    from jaxcal.simulate import Dataset2Config  # jax: imported on use
    from jaxcal.simulate.recordings import dataset1_recordings, dataset2_recordings

    with _output_dir(args.out) as d:
        if args.dataset == "dataset2":
            kw = {name: getattr(args, name) for name in ("n_train", "n_val") if getattr(args, name) is not None}
            recs, truth = dataset2_recordings(args.seed, Dataset2Config(**kw), args.labels)
        else:
            recs, truth = dataset1_recordings(args.seed)
        names = _write_all(d, recs, truth, args.format)
    print(f"{PROG}: wrote {', '.join(names)} and truth.json to {args.out}", file=sys.stderr)
    return 0

register_command(
    "simulate",
    Command("write simulated recordings (dataset2, dataset1)", _add_simulate, _run_simulate),
)
