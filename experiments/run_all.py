"""The main job of ``make run``: every experiment in turn, then an index of what was written.

    python -m experiments.run_all --quick      # make run: quick forms (minutes on 2 cores)
    python -m experiments.run_all              # make run-full: the full reproduction

Each experiment module exposes ``main(quick: bool)`` and writes its own ``results/*.md``,
``results/*.json`` and ``results/figures/*.png``; ``results/index.md`` lists them with the wall
time each took in this run.
"""

from __future__ import annotations

import argparse
import importlib
import platform
import sys
import time
from pathlib import Path

import jax

RESULTS = Path(__file__).resolve().parent.parent / "results"

# (module, report it writes, what it reproduces)
EXPERIMENTS = (
    ("experiments.offline", "offline.md", "thesis chapter 3: Table 3.1, Fig. 3.4-3.10"),
    ("experiments.online", "online.md", "thesis chapter 4: Tables 4.1-4.2, Fig. 4.2-4.18, and beyond"),
    ("experiments.real_data", "real.md", "public recordings: readers, multipos, peers side by side"),
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="quick forms (what `make run` does)")
    ap.add_argument("--only", nargs="*", default=None, help="run only these modules (e.g. experiments.offline)")
    args = ap.parse_args(argv)

    RESULTS.mkdir(exist_ok=True)
    rows = []
    for module, report, what in EXPERIMENTS:
        if args.only and module not in args.only:
            continue
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            print(f"[run_all] {module}: not in this build, skipped", file=sys.stderr)
            continue
        print(f"[run_all] {module} ({'quick' if args.quick else 'full'}): {what}", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        mod.main(quick=args.quick)
        dt = time.perf_counter() - t0
        print(f"[run_all] {module} done in {dt:.0f} s -> results/{report}", file=sys.stderr, flush=True)
        rows.append((module, report, what, dt))

    lines = [
        "# jaxcal results index",
        "",
        f"Written by `python -m experiments.run_all{' --quick' if args.quick else ''}` "
        f"({'`make run`' if args.quick else '`make run-full`'}) on {platform.machine()} / "
        f"{platform.system()}, JAX {jax.__version__}, devices {jax.devices()}.",
        "",
        "| experiment | report | reproduces | wall time (s) |",
        "|---|---|---|---|",
    ]
    lines += [f"| `{m}` | [{r}]({r}) | {w} | {t:.0f} |" for m, r, w, t in rows]
    (RESULTS / "index.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
