"""More logs for the coverage cases that missed 93-97 % in ``results/noise.md`` (issue 29).

    python -m experiments.noise_more_logs [--extra 300] [--report-only]

With 100 logs a coverage share has a binomial standard error of 2.2 points: an interval that covers
exactly 95 % lands outside 93-97 % in about one case in four. This script tells a real shortfall from
that noise. It reads the 100 logs of each case from ``results/noise.json`` (written by
``python -m experiments.noise``). For every case where a parameter's coverage fell outside 93-97 %,
it simulates ``--extra`` more logs of that case (new seeds, the same simulator and the same
``jaxcal noise`` reading, :func:`experiments.noise._case_row`). It then reports the coverage over all
the logs, with its exact (Clopper-Pearson) 95 % interval. Writes ``results/noise_more_logs.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from scipy.stats import beta, binom

from experiments.noise import CASES, PARAMS_OF_INTEREST, RESULTS, _case_log, _case_row

GOAL = (0.93, 0.97)
NOMINAL = 0.95


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact two-sided binomial interval for ``k`` successes in ``n`` trials."""
    a = 1.0 - level
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def chance_in_goal(n: int, p: float = NOMINAL) -> float:
    """Probability that ``n`` logs of an interval covering exactly ``p`` show a share within :data:`GOAL`."""
    lo, hi = int(np.ceil(GOAL[0] * n - 1e-9)), int(np.floor(GOAL[1] * n + 1e-9))
    return float(binom.cdf(hi, n, p) - binom.cdf(lo - 1, n, p))


def _covered(row: dict, key: str, truth: float) -> bool:
    return bool(row[key][1] <= truth <= row[key][2])


def _misses(noise: dict) -> dict[str, list[str]]:
    """The cases, and their parameters, whose 100-log coverage in ``noise.json`` fell outside :data:`GOAL`."""
    out = {}
    for name, case in CASES.items():
        bad = [k for k in PARAMS_OF_INTEREST if k in case
               and not GOAL[0] <= noise["coverage"][name][k]["coverage"] <= GOAL[1]]
        if bad:
            out[name] = bad
    return out


def run(extra: int) -> dict:
    noise = json.loads((RESULTS / "noise.json").read_text())
    out = {"extra": extra, "cases": {}, "load_start": round(os.getloadavg()[0], 2)}
    t_all = time.perf_counter()
    for name, params in _misses(noise).items():
        case = CASES[name]
        first = noise["coverage"][name + "_rows"]
        i = list(CASES).index(name)
        t0 = time.perf_counter()
        seeds = range(len(first), len(first) + extra)  # disjoint from experiments.noise's first logs
        more = [{k: v for k, v in _case_row(case, _case_log(case, 10_000 * (i + 1) + s)).items() if k != "fit"}
                for s in seeds]
        rows = first + more
        res = {"label": case["label"], "logs_first": len(first), "logs_extra": len(more),
               "seconds_per_log": (time.perf_counter() - t0) / max(extra, 1), "params": {}}
        for k in PARAMS_OF_INTEREST:
            if k not in case:
                continue
            hits = sum(_covered(r, k, case[k]) for r in rows)  # as results/noise.md: a parameter not selected (NaN) is a miss
            hits_first = sum(_covered(r, k, case[k]) for r in first)
            unselected = sum(not np.isfinite(r[k][1]) for r in rows)
            lo, hi = clopper_pearson(hits, len(rows))
            res["params"][k] = {"missed_at_100": k in params, "coverage_first": hits_first / len(first),
                                "coverage_all": hits / len(rows), "n": len(rows), "not_selected": unselected,
                                "ci95": [lo, hi], "nominal_in_ci": lo <= NOMINAL <= hi}
        out["cases"][name] = res
        print(f"{name}: " + ", ".join(f"{k} {100 * v['coverage_first']:.0f} % -> {100 * v['coverage_all']:.1f} % of {v['n']}"
                                      for k, v in res["params"].items()), flush=True)
    out["chance_in_goal_at_100"] = chance_in_goal(100)
    out["seconds"] = time.perf_counter() - t_all
    out["load_end"] = round(os.getloadavg()[0], 2)
    return out


def markdown(res: dict) -> str:
    n0 = 100
    L = ["# Coverage with more logs (issue 29)", "",
         f"Written by `python -m experiments.noise_more_logs --extra {res['extra']}` in {res['seconds']:.0f} s (load average "
         f"{res['load_start']} at start, {res['load_end']} at end). `results/noise.md` counts each case over {n0} logs. With "
         f"{n0} logs a share has a binomial standard error of 2.2 points, and an interval covering exactly 95 % shows 93-97 % "
         f"with probability {100 * res['chance_in_goal_at_100']:.0f} %. So a case outside the goal may be noise or a real "
         f"shortfall. Each case that missed got {res['extra']} more logs (new seeds, the same simulator and the same "
         "`jaxcal noise` reading). The coverage below is over all the logs, with its exact (Clopper-Pearson) 95 % interval; "
         "as in `results/noise.md`, a log whose chosen model lacks the parameter counts as a miss.",
         "", "| case | parameter | covered, first 100 | covered, all logs | logs | of them, not in the chosen model | "
         "95 % interval of the share | holds 95 %? |",
         "|---|---|---|---|---|---|---|---|"]
    for name, r in res["cases"].items():
        for k, v in r["params"].items():
            mark = "" if v["missed_at_100"] else " (met at 100)"
            L.append(f"| {r['label']} | {k}{mark} | {100 * v['coverage_first']:.0f} % | {100 * v['coverage_all']:.1f} % | {v['n']} | "
                     f"{v['not_selected']} | {100 * v['ci95'][0]:.1f}-{100 * v['ci95'][1]:.1f} % | {'yes' if v['nominal_in_ci'] else '**no**'} |")
    L += ["", "Where the interval of the share holds 95 %, the miss at 100 logs is within binomial noise. Where it does not, "
          "the intervals are too narrow (or too wide) for that case, and `results/noise.md`'s figure is a real shortfall.", ""]
    return "\n".join(L)


def main(extra: int, report_only: bool = False) -> None:
    if report_only:
        res = json.loads((RESULTS / "noise_more_logs.json").read_text())
    else:
        res = run(extra)
        (RESULTS / "noise_more_logs.json").write_text(json.dumps(res, indent=1) + "\n")
    (RESULTS / "noise_more_logs.md").write_text(markdown(res))
    print("wrote results/noise_more_logs.md" + ("" if report_only else ", .json"), flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--extra", type=int, default=300, help="logs added to each case that missed the goal (default 300)")
    ap.add_argument("--report-only", action="store_true", help="rebuild the .md from the .json")
    a = ap.parse_args()
    main(a.extra, a.report_only)
