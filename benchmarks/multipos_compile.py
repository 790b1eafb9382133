"""One multipos fit: compile and run time with and without XLA's backend optimisation passes.

    python -m benchmarks.multipos_compile [--reps N] [--json OUT]

On the Xsens multi-position session (``data/imu_tk_xsens_multipos``, 40 poses), this compiles, in
one run with the persistent cache off, :func:`jaxcal.multipos.fit_prepared` (one fit, what
``calibrate --method multipos``, the field path's rest fits and the in-sample scores run) and
:func:`jaxcal.multipos.heldout.fold_scores` (the leave-one-pose-out loop, one fold after another)
twice each: with XLA's defaults and with :data:`jaxcal.multipos.fit.FIT_COMPILER_OPTIONS`, each
compiled ``reps`` times and run ``reps`` times (medians; each run ended by ``block_until_ready``); the
largest difference between the two results is reported. A single fit runs in milliseconds and
compiles in seconds, so fewer optimisation passes pay there; the fold loop runs the fit 40 times
and keeps them. Writes ``results/multipos_compile.json``.
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.multipos_folds import XSENS, run_cli, xsens_data  # noqa: E402
from jaxcal.multipos.fit import FIT_COMPILER_OPTIONS, fit_prepared  # noqa: E402
from jaxcal.multipos.heldout import fold_scores  # noqa: E402


def _timed(lower, args: tuple, options: dict, reps: int) -> tuple[dict, list[np.ndarray]]:
    """Lower (``lower()``) and compile with ``options`` ``reps`` times, jax's in-memory caches
    cleared before each (the persistent cache is off, so each compile is a real one), then run the
    last ``reps`` times: median times and the result's leaves."""
    cs = []
    for _ in range(reps):
        jax.clear_caches()
        lowered = lower()
        t0 = time.perf_counter()
        compiled = lowered.compile(compiler_options=options)
        cs.append(time.perf_counter() - t0)
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        res = jax.block_until_ready(compiled(*args))
        ts.append(time.perf_counter() - t0)
    return ({"compile_s": statistics.median(cs), "compile_s_all": cs, "run_s": statistics.median(ts), "run_s_all": ts},
            [np.asarray(x) for x in jax.tree_util.tree_leaves(res)])


def _max_diff(a: list[np.ndarray], b: list[np.ndarray]) -> float:
    return max(float(np.nanmax(np.abs(x - y))) if x.size else 0.0 for x, y in zip(a, b, strict=True))


def measure(reps: int) -> dict:
    """Compile and run times of one fit and of the fold loop, XLA's defaults against the fit's options."""
    data, config = xsens_data()
    P = data.pose_acc.shape[0]
    out: dict = {"recording": str(XSENS.relative_to(ROOT)), "poses": P, "repetitions": reps, "options": FIT_COMPILER_OPTIONS}
    with jax.enable_x64(True):
        d = jax.tree_util.tree_map(jnp.asarray, data)
        aw = jnp.asarray(1.0 - np.eye(P))
        gw = jnp.asarray(1.0 - np.eye(P)[:, : P - 1])
        def fit():
            return jax.jit(fit_prepared, static_argnames=("config",)).lower(d, config)

        def folds():
            return fold_scores.lower(d, config, aw, gw, 1)

        for name, lower, args in (("one_fit", fit, (d,)), ("fold_loop", folds, (d, aw, gw))):
            base, r0 = _timed(lower, args, {}, reps)
            fast, r1 = _timed(lower, args, FIT_COMPILER_OPTIONS, reps)
            out[name] = {"defaults": base, "fit_options": fast, "max_abs_diff": _max_diff(r0, r1),
                         "compile_ratio": base["compile_s"] / fast["compile_s"], "run_ratio": fast["run_s"] / base["run_s"],
                         "total_saved_s": base["compile_s"] + base["run_s"] - fast["compile_s"] - fast["run_s"]}
    out["load_average_at_end"] = list(os.getloadavg())
    out["jax_version"] = jax.__version__
    return out


def main() -> None:
    out, path = run_cli(__doc__, measure, 3, "compiles and timed runs of each function (medians reported)",
                        "multipos_compile.json")
    for name in ("one_fit", "fold_loop"):
        r = out[name]
        b, f = r["defaults"], r["fit_options"]
        print(f"{name}: compile {b['compile_s']:.2f} -> {f['compile_s']:.2f} s, run {1e3 * b['run_s']:.1f} -> "
              f"{1e3 * f['run_s']:.1f} ms, saved {r['total_saved_s']:+.2f} s, max difference {r['max_abs_diff']:.2g}")
    print(f"{out['poses']} poses; wrote {path}")


if __name__ == "__main__":
    main()
