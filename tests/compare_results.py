"""Compare two results trees field by field: ``python -m tests.compare_results OLD_DIR NEW_DIR [FILES...]``.

The refactor check of issue 15: every number in ``results/*.json`` must be unchanged. Walks both
JSON documents in parallel and reports every leaf that differs (exact comparison; floats are
compared bit for bit), every key present in one only, and counts. Keys that are timings or
describe the machine may differ and are listed separately (``TIMING``, exact key names): wall and
compile times, load averages, speed ratios measured in the run, and the JAX/machine description.
Exit status 1 if any non-timing leaf differs.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

TIMING = frozenset({
    # wall and compile times of the run, and speeds derived from them
    "seconds", "wall_s", "total_s", "runtime_s", "time_s", "diagnosis_s", "align_time_s", "as_recorded_time_s",
    "compile_s", "pass_s", "run_s", "fisher_s", "pass_s_all_lambdas", "wall_s_incl_compile", "data_s",
    "one_pass_compile_s", "one_pass_run_s", "loop_only_run_s", "all_seeds_vmapped_incl_compile_s",
    "vmapped_run_s", "vmapped_compile_s", "sweep_total_s", "sweep_run_s",
    "realtime_factor", "real_time_factor", "real_time_factor_loop_only", "timing",
    # the machine and library versions the run saw
    "loadavg_1min_at_start", "load_average_1min_at_end", "cpu_count", "machine", "jax",
})


def _walk(a, b, path, out):
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b), key=str):
            p = f"{path}/{k}"
            if k not in a or k not in b:
                out["missing"].append((p, "old" if k not in a else "new"))
            else:
                _walk(a[k], b[k], p, out)
        return
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            _walk(x, y, f"{path}[{i}]", out)
        return
    timing = any(part.split("[")[0] in TIMING for part in path.split("/"))
    out["n_timing" if timing else "n_leaves"] += 1
    if a != b and not (a != a and b != b):  # NaN == NaN here
        out["timing" if timing else "diff"].append((path, a, b))


def compare(old: Path, new: Path) -> dict:
    """Every differing leaf of two JSON files: ``diff`` (numbers that must not change), ``timing``
    (allowed), ``missing`` (keys in one file only), and the leaf counts."""
    out = {"diff": [], "timing": [], "missing": [], "n_leaves": 0, "n_timing": 0}
    _walk(json.loads(old.read_text()), json.loads(new.read_text()), "", out)
    return out


def main(argv: list[str]) -> int:
    old, new, *names = argv
    names = names or sorted(p.name for p in Path(new).glob("*.json") if (Path(old) / p.name).exists())
    bad = 0
    for n in names:
        r = compare(Path(old) / n, Path(new) / n)
        status = "IDENTICAL" if not r["diff"] and not r["missing"] else "DIFFERENT"
        bad += status != "IDENTICAL"
        print(f"{n}: {status}: {r['n_leaves']} leaves compared, {len(r['diff'])} differ; "
              f"{r['n_timing']} timing leaves ({len(r['timing'])} differ, allowed); {len(r['missing'])} keys in one file only")
        for p, a, b in r["diff"][:20]:
            rel = abs(a - b) / max(abs(a), abs(b)) if isinstance(a, (int, float)) and isinstance(b, (int, float)) and max(abs(a), abs(b)) else None
            print(f"    {p}: {a!r} -> {b!r}" + (f" (relative {rel:.1e})" if rel is not None else ""))
        for p, side in r["missing"][:10]:
            print(f"    {p}: missing in {side}")
        for p, a, b in r["timing"][:3]:
            print(f"    (timing) {p}: {a!r} -> {b!r}")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
