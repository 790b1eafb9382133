"""The ``online`` filter's real-time factor against the sequence propagation's loop unrolling.

    python benchmarks/online_unroll.py [--reps 5] [--unroll 1 2 4 8 16] [--json OUT]

``jaxcal.online.PROPAGATE_UNROLL`` (static) sets how many rotation steps one iteration of the
compiled loop in ``rotation.propagate_specific_force`` runs. Unrolling keeps every product and its
order, so the filter's result must be bit-identical for every value; only the loop's fixed cost per
iteration changes. For each value (one fresh ``jit`` each, persistent cache off) this times
``online_scan`` on Dataset 2 (500 sequences x 101 samples at 100 Hz, float64, ``diag`` and
``affine``): the median of ``--reps`` runs of the compiled function, its compile time, and the
largest difference of the final parameters from unroll 1. Ratios are measured in one run; the load
average is recorded.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxcal.online.filter as online  # noqa: E402  (PROPAGATE_UNROLL is read there when the filter is traced)
from jaxcal.online import OnlineHP, SequenceBatch, make_filter, online_scan, spec_sequences  # noqa: E402
from jaxcal.sensor import Diag  # noqa: E402
from jaxcal.simulate.dataset2 import dataset2  # noqa: E402


def filter_inputs() -> tuple[dict, SequenceBatch, float, OnlineHP]:
    """Dataset 2's training sequences as the filter streams them, in float64 (call inside
    ``jax.enable_x64(True)``): the run's description (``dataset``, ``data_s``, the load and cores),
    the spec-converted batch, ``dt`` and the default hyperparameters."""
    d = dataset2(jax.random.PRNGKey(0))
    m, n = d.train.acc.shape[:2]
    info = {"dataset": f"Dataset 2, {m} sequences x {n} samples at {1 / d.dt:.0f} Hz", "data_s": float(m * n * d.dt),
            "load_average_at_start": list(os.getloadavg()), "cores": len(os.sched_getaffinity(0))}
    f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    batch = spec_sequences(f64(d.train.acc), f64(d.train.gyr), Diag(f64(d.acc_spec.s), f64(d.acc_spec.b)),
                           Diag(f64(d.gyr_spec.s), f64(d.gyr_spec.b)))
    return info, batch, f64(d.dt), OnlineHP(*[jnp.asarray(v) for v in OnlineHP()])


def measure(unrolls: list[int], reps: int) -> dict:
    default = online.PROPAGATE_UNROLL
    with jax.enable_x64(True):
        info, batch, dt, hp = filter_inputs()
        data_s = info["data_s"]
        out: dict = {**info, "rows": []}
        ref: dict = {}
        try:
            for u in unrolls:
                online.PROPAGATE_UNROLL = u  # read when the filter is traced: a fresh jit below
                for kind in ("diag", "affine"):
                    st0 = make_filter(kind).init(hp, jnp.float64)
                    t0 = time.perf_counter()
                    fn = jax.jit(partial(online_scan, kind=kind)).lower(st0, batch, dt, hp).compile()
                    c = time.perf_counter() - t0
                    theta = np.asarray(jax.block_until_ready(fn(st0, batch, dt, hp))[0].theta)
                    ts = []
                    for _ in range(reps):
                        t0 = time.perf_counter()
                        jax.block_until_ready(fn(st0, batch, dt, hp))
                        ts.append(time.perf_counter() - t0)
                    ref.setdefault(kind, theta)
                    run = statistics.median(ts)
                    row = {"unroll": u, "kind": kind, "compile_s": c, "run_s": run, "run_s_all": ts,
                           "realtime_factor": data_s / run, "max_abs_diff_vs_first": float(np.max(np.abs(theta - ref[kind])))}
                    out["rows"].append(row)
                    print(f"unroll {u:3d} {kind:6s} run {run * 1e3:8.1f} ms  RTF {data_s / run:7.0f}  compile {c:5.1f} s  "
                          f"diff {row['max_abs_diff_vs_first']:.1e}", flush=True)
        finally:
            online.PROPAGATE_UNROLL = default
    out["load_average_at_end"] = list(os.getloadavg())
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--unroll", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    jax.config.update("jax_enable_compilation_cache", False)
    res = measure(a.unroll, a.reps)
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
