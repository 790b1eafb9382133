"""CPU cost of the chapter-3 NN sweep: per-epoch times measured here, full sweep extrapolated.

    python -m benchmarks.offline_cpu [--epochs 40]

The full Table 3.1 sweep (8 subset sizes x 5 seeds of the thesis's 7500-unit network, early
stopping after ~10^4 epochs each) was run on a GPU (`results/offline.md`); on a 2-core CPU it
takes hours. This benchmark measures, in one run on this machine, with compile time separate:

1. one training at l = 1000 for a fixed number of epochs (patience > epochs, so no early stop);
2. the whole sweep (8 sizes x 5 seeds, one jitted vmap over padded subsets) for the same epochs;
3. 5 seeds vmapped vs the same 5 trainings one by one (compiled once);

optionally (``--full-l1000``) one complete early-stopped training at l = 1000 with the full run's
settings; and extrapolates (1) and (2) to the epoch counts the full run used (read from
``results/offline_adam_h100.json``), labelled as extrapolations. This is the cost of the previous
recipe (:data:`jaxcal.offline.ADAM_FROM_RANDOM`, padded subsets); the current one is measured by
``benchmarks/run.py`` (``nn_epoch_bound_fraction``). Writes ``results/offline_cpu_timing.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from jaxcal.nn import MLP, THESIS_LEAKY_SLOPE, THESIS_OFFLINE_WIDTHS
from jaxcal.normalise import bounds_from_spec
from jaxcal.offline import ADAM_FROM_RANDOM, THESIS_SIZES, nn_calibrate_subsets
from jaxcal.simulate.dataset1 import dataset1, nested_subset_weights

RESULTS = Path(__file__).resolve().parent.parent / "results"


def _timed(fn, *args):
    """(compile seconds, run seconds, output) of a jitted function."""
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    t1 = time.perf_counter()
    out = jax.block_until_ready(compiled(*args))
    return t1 - t0, time.perf_counter() - t1, out


def full_l1000(out: dict, data, mlp: MLP, bounds) -> None:
    """One real training at l = 1000 with the full run's settings (early stopping included), timed."""
    spec = ADAM_FROM_RANDOM  # lr 2e-2, patience 6000, max 30000 epochs
    full_w = jnp.ones((1, data.train.acc.shape[0]))

    def one(key):
        return nn_calibrate_subsets(key, mlp, bounds, (data.train.acc, data.train.acc_ref), full_w,
                                    (data.val.acc, data.val.acc_ref), data.test.acc, spec)

    c, r, (pred, ep, _) = _timed(one, jax.random.PRNGKey(1))
    err = jnp.mean(jnp.linalg.norm(pred[0] - data.test.acc_ref, axis=-1))
    out["full_one_training_l1000"] = {"compile_s": c, "run_s": r, "epochs": int(ep[0]),
                                      "test_mean_mg": float(err) * 1e3,
                                      "load_average_1min_at_end": os.getloadavg()[0]}


def main(epochs: int = 40, n_seeds: int = 5, full: bool = False) -> dict:
    # Measure real compile times: the persistent cache (set by the Makefile) would serve them from disk.
    jax.config.update("jax_enable_compilation_cache", False)
    data = dataset1(jax.random.PRNGKey(0))
    mlp = MLP(widths=THESIS_OFFLINE_WIDTHS, slope=THESIS_LEAKY_SLOPE)
    bounds = bounds_from_spec(data.spec, 2.0)
    spec = ADAM_FROM_RANDOM._replace(patience=epochs + 1, max_epochs=epochs)
    train = (data.train.acc, data.train.acc_ref)
    val = (data.val.acc, data.val.acc_ref)
    keys = jax.random.split(jax.random.PRNGKey(1), n_seeds)
    full_w = jnp.ones((1, data.train.acc.shape[0]))

    def one(key):
        return nn_calibrate_subsets(key, mlp, bounds, train, full_w, val, data.test.acc, spec)[0]

    def sweep(keys):
        def per_seed(key):
            w = nested_subset_weights(jax.random.fold_in(key, 7), data.train.acc.shape[0], THESIS_SIZES)
            return nn_calibrate_subsets(key, mlp, bounds, train, w, val, data.test.acc, spec)[0]

        return jax.vmap(per_seed)(keys)

    c1, r1, _ = _timed(one, keys[0])
    cs, rs, _ = _timed(sweep, keys)
    cv, rv, _ = _timed(jax.vmap(one), keys)
    loop = jax.jit(one).lower(keys[0]).compile()
    jax.block_until_ready(loop(keys[0]))
    t0 = time.perf_counter()
    for k in keys:
        jax.block_until_ready(loop(k))
    rl = time.perf_counter() - t0

    out = {
        "machine": f"{platform.machine()} {platform.system()}, {os.cpu_count()} CPUs, jax {jax.__version__}, "
        f"devices {[str(d) for d in jax.devices()]}",
        "load_average_1min_at_end": os.getloadavg()[0],
        "epochs_measured": epochs,
        "one_training_l1000": {"compile_s": c1, "run_s": r1, "s_per_epoch": r1 / epochs},
        "sweep_8_sizes_x_seeds": {"n_trainings": len(THESIS_SIZES) * n_seeds, "compile_s": cs, "run_s": rs,
                                   "s_per_sweep_epoch": rs / epochs},
        "vmap_vs_loop": {"n_seeds": n_seeds, "vmapped_run_s": rv, "vmapped_compile_s": cv, "one_by_one_run_s": rl,
                         "loop_over_vmap_ratio": rl / rv},
    }
    full = RESULTS / "offline_adam_h100.json"
    if full.exists():
        o = json.loads(full.read_text())
        rows = o.get("table", [])
        ep = [sum(r["nn_epochs_per_seed"]) / len(r["nn_epochs_per_seed"]) for r in rows if r["l"] == 1000]
        if ep:
            out["extrapolated_one_training_l1000_s"] = ep[0] * r1 / epochs
            out["extrapolated_from_epochs"] = ep[0]
        # A vmapped while_loop runs until its slowest member stops: the longest training of the full run.
        max_ep = max(max(r["nn_epochs_per_seed"]) for r in rows)
        out["extrapolated_sweep_s"] = max_ep * rs / epochs
        out["extrapolated_sweep_from_epochs"] = max_ep
    if full:
        full_l1000(out, data, mlp, bounds)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "offline_cpu_timing.json").write_text(json.dumps(out, indent=1))
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--epochs", type=int, default=40, help="epochs per measured training")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--full-l1000", action="store_true",
                    help="also time one complete early-stopped training at l = 1000 (~10 min on 2 cores)")
    a = ap.parse_args()
    main(a.epochs, a.seeds, a.full_l1000)
