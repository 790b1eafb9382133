"""The main job of ``make run``: every experiment of a group in turn, then an index of what was written.

    python -m experiments.run_all --quick                  # make run: thesis chapters 3-4, quick (< 6 min, 2 cores)
    python -m experiments.run_all                          # make run-full: chapters 3-4, full (< 20 min, 2 cores)
    python -m experiments.run_all --group real [--quick]   # make run-real: public recordings and diagnose

Each experiment module exposes ``main(quick: bool)`` and writes its own ``results/*.md``,
``results/*.json`` and ``results/figures/*.png`` (quick forms: ``*_quick.*``, so that ``make run``
never overwrites the full results); ``results/index.md`` lists them with the wall time each took,
and ``results/reproduce[_quick].json`` records the wall times (the full thesis group's is the
``reproduce_minutes`` of ``benchmarks/run.py``).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax

RESULTS = Path(__file__).resolve().parent.parent / "results"

# (group, module, report stem, what it reproduces). A quick run writes ``results/STEM_quick.md`` (and
# ``STEM_quick`` figures, all git-ignored), so ``make run`` never overwrites the committed full forms.
EXPERIMENTS = (
    ("thesis", "experiments.offline", "offline", "thesis chapter 3: Table 3.1, Fig. 3.4-3.10, cubic and affine + NN residual"),
    ("thesis", "experiments.online", "online", "thesis chapter 4: Tables 4.1-4.2, Fig. 4.2-4.18"),
    ("thesis", "experiments.online_beyond", "online_beyond", "beyond chapter 4: jaxcal online at the quantisation floor, NN, drift"),
    ("real", "experiments.real_data", "real", "public recordings: readers, multipos, peers side by side"),
    ("real", "experiments.discrepancy_benchmark", "discrepancy", "jaxcal diagnose: concealed effects, nulls, TUM-VI, rigs"),
    ("real", "experiments.field_diagnose", "field_diagnose", "jaxcal diagnose without a reference: every real recording, BROAD's relative offset, concealment"),
    ("real", "experiments.apply_effects", "apply_effects", "diagnosed model applied to held-out data: each simulated effect removed; real rigs (BROAD 07<->21, TUM-VI halves)"),
    ("real", "experiments.field", "field", "calibration in the field: online and online-thesis on real recordings without seq ids or datasheet values, beside multipos and the factory calibrations"),
    ("real", "experiments.noise", "noise", "Allan-variance noise parameters: interval coverage, allantools, real static stretches, inflation"),
)
GROUPS = ("thesis", "real", "all")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="quick forms (what `make run` does)")
    ap.add_argument("--group", choices=GROUPS, default="thesis",
                    help="thesis (chapters 3-4 and beyond; default), real (public recordings, diagnose) or all")
    ap.add_argument("--only", nargs="*", default=None, help="run only these modules (e.g. experiments.offline)")
    args = ap.parse_args(argv)

    t_start = time.perf_counter()
    RESULTS.mkdir(exist_ok=True)
    rows = []
    for group, module, stem, what in EXPERIMENTS:
        if args.only and module not in args.only or not args.only and args.group not in ("all", group):
            continue
        mod = importlib.import_module(module)
        print(f"[run_all] {module} ({'quick' if args.quick else 'full'}): {what}", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        mod.main(quick=args.quick)
        dt = time.perf_counter() - t0
        # a finished experiment's compiled code is released: each live XLA CPU executable holds about
        # 7 memory mappings, and a process may hold vm.max_map_count (65530 by default; tests/conftest.py)
        jax.clear_caches()
        # Quick forms write STEM_quick.md, except experiments whose only form is the quick one.
        report = f"{stem}_quick.md" if args.quick and (RESULTS / f"{stem}_quick.md").exists() else f"{stem}.md"
        print(f"[run_all] {module} done in {dt:.0f} s -> results/{report}", file=sys.stderr, flush=True)
        rows.append((module, report, what, dt))

    total = time.perf_counter() - t_start
    command = "python -m experiments.run_all" + (" --quick" if args.quick else "") + (
        f" --group {args.group}" if args.group != "thesis" else "") + (f" --only {' '.join(args.only)}" if args.only else "")
    make = {("thesis", True): "`make run`", ("thesis", False): "`make run-full`", ("real", True): "`make run-real`"}
    record = {
        "command": command,
        "make": make.get((args.group, args.quick), "").strip("`"),
        "total_s": total,
        "minutes": total / 60.0,
        "experiments": {m: dt for m, _, _, dt in rows},
        "machine": f"{platform.machine()} {platform.system()}, {os.cpu_count()} CPUs, JAX {jax.__version__}, "
                   f"devices {[str(d) for d in jax.devices()]}",
        "load_average_1min_at_end": os.getloadavg()[0],
        "note": "wall time of this process from the first experiment's import to the last report (the install "
                "and the interpreter's start-up are not included)",
    }
    if not args.only:
        suffix = "" if args.group == "thesis" else f"_{args.group}"
        (RESULTS / f"reproduce{suffix}{'_quick' if args.quick else ''}.json").write_text(json.dumps(record, indent=1) + "\n")
    lines = [
        "# jaxcal results index",
        "",
        f"Written by `{command}` {make.get((args.group, args.quick), '')} on {platform.machine()} / "
        f"{platform.system()}, JAX {jax.__version__}, devices {jax.devices()}, in {total / 60:.1f} min.",
        "",
        "| experiment | report | reproduces | wall time (s) |",
        "|---|---|---|---|",
    ]
    lines += [f"| `{m}` | [{r}]({r}) | {w} | {t:.0f} |" for m, r, w, t in rows]
    if args.quick:
        lines += ["", "Quick forms run fewer seeds with the full forms' settings; the full-form reports "
                  "(`offline.md`, `online.md`, `online_beyond.md`) are regenerated by `make run-full`, and "
                  "`real.md` / `discrepancy.md` by each script without `--quick`."]
    (RESULTS / "index.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
