"""multipos leave-one-pose-out folds on a CPU: all in one ``vmap`` against one after another.

    python -m benchmarks.multipos_folds [--reps N] [--json OUT]

On the Xsens multi-position session (``data/imu_tk_xsens_multipos``: 40 poses, 39 transitions, so
40 folds), :func:`jaxcal.multipos.leave_poses_out` fits every fold inside one compiled ``lax.map``;
``batch`` folds go through one ``vmap``. This measures, in one run, ``batch = 40`` (one vmap, what
the library did before) and ``batch = 1`` (one fold after another, the CPU default of
:func:`jaxcal.multipos.fold_batch`), each compiled once with the persistent cache off, then run
``reps`` times (median, each ended by ``block_until_ready``), and compares the two results. A
vmapped Levenberg-Marquardt ``while_loop`` runs every fold until the slowest has converged and
holds all 40 folds' intermediates at once. Writes ``results/multipos_folds.json``.
"""

from __future__ import annotations

import argparse
import json
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

from jaxcal import multipos as mp  # noqa: E402
from jaxcal.methods import multipos as mm  # noqa: E402
from jaxcal.multipos.heldout import fold_scores  # noqa: E402
from jaxcal.recording import load_recording  # noqa: E402

XSENS = ROOT / "data" / "imu_tk_xsens_multipos" / "xsens.npz"


def xsens_data() -> tuple[mp.MultiposData, mp.MultiposConfig]:
    """The Xsens session's prepared poses and transitions and ``calibrate --method multipos``'s config."""
    rec = load_recording(XSENS)
    opts = mm.MultiposOptions()
    config, det = mm.multipos_config(rec, opts), mm.detect_options(rec, opts)
    _, iv, _ = mp.detect_and_fit(rec.t, rec.acc, rec.gyr, config, detect=det, check=False)
    return mp.prepare(rec.t, rec.acc, rec.gyr, iv, gyr_limit=det.gyr_limit, midpoint=config.midpoint), config


def measure(reps: int) -> dict:
    """Compile and run times of the Xsens folds at ``batch`` 40 and 1, and their largest difference."""
    data, config = xsens_data()
    P = data.pose_acc.shape[0]
    out: dict = {"recording": str(XSENS.relative_to(ROOT)), "folds": P, "repetitions": reps}
    results = {}
    with jax.enable_x64(True):
        d = jax.tree_util.tree_map(jnp.asarray, data)
        aw = jnp.asarray(1.0 - np.eye(P))
        gw = jnp.asarray(1.0 - np.eye(P)[:, : P - 1])
        for name, batch in (("vmap_all", P), ("one_after_another", 1)):
            t0 = time.perf_counter()
            compiled = fold_scores.lower(d, config, aw, gw, batch).compile()
            compile_s = time.perf_counter() - t0
            ts = []
            for _ in range(reps):
                t0 = time.perf_counter()
                res = jax.block_until_ready(compiled(d, aw, gw))
                ts.append(time.perf_counter() - t0)
            results[name] = [np.asarray(x) for x in res]
            out[name] = {"batch": batch, "compile_s": compile_s, "run_s": statistics.median(ts), "run_s_all": ts}
    (ea0, eg0, *_), (ea1, eg1, *_) = results["vmap_all"], results["one_after_another"]
    ok = np.isfinite(eg0) & np.isfinite(eg1)
    out["max_abs_diff"] = {"acc_g": float(np.max(np.abs(ea0 - ea1))), "gyr_rad": float(np.max(np.abs(eg0 - eg1)[ok]))}
    out["run_ratio"] = out["vmap_all"]["run_s"] / out["one_after_another"]["run_s"]
    out["compile_ratio"] = out["vmap_all"]["compile_s"] / out["one_after_another"]["compile_s"]
    out["load_average_at_end"] = list(os.getloadavg())
    out["jax_version"] = jax.__version__
    out["devices"] = [str(x) for x in jax.devices()]
    return out


def run_cli(doc: str, measure_fn, default_reps: int, reps_help: str, json_name: str) -> tuple[dict, Path]:
    """The multipos benchmarks' command line (this one and ``benchmarks.multipos_compile``): ``--reps``
    and ``--json``, the persistent compilation cache off (real compile times), ``measure_fn(reps)``'s
    result written as JSON. Returns the result and the path written."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=default_reps, help=reps_help)
    ap.add_argument("--json", type=Path, default=ROOT / "results" / json_name, help="JSON output path")
    a = ap.parse_args()
    jax.config.update("jax_enable_compilation_cache", False)  # real compile times
    out = measure_fn(a.reps)
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(out, indent=1) + "\n")
    return out, a.json


def main() -> None:
    out, path = run_cli(__doc__, measure, 5, "timed runs of each compiled function (median reported)", "multipos_folds.json")
    v, s = out["vmap_all"], out["one_after_another"]
    print(f"{out['folds']} folds: one vmap run {v['run_s']:.2f} s (compile {v['compile_s']:.1f} s), one after another "
          f"{s['run_s']:.2f} s (compile {s['compile_s']:.1f} s): run ratio {out['run_ratio']:.2f}x, compile ratio "
          f"{out['compile_ratio']:.2f}x; max difference acc {out['max_abs_diff']['acc_g']:.2g} g, gyr "
          f"{out['max_abs_diff']['gyr_rad']:.2g} rad; wrote {path}")


if __name__ == "__main__":
    main()
