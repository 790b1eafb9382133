"""The chapter-3 NN's training cost on this machine, before and after issue 16's changes.

Used by ``benchmarks/run.py`` (keys ``nn_epoch_bound_fraction`` and ``nn_costs``); runnable alone:

    python -m benchmarks.nn_epoch [--reps 5]

Measured in one run, compile apart, medians of repeated compiled calls:

1. **the machine's bound**: float32 GEMM throughput (``2048 x 2048`` products, jitted) and
   streaming bandwidth (``y = 2 x + 1`` over 64 MB);
2. **one epoch** of the thesis network (3 -> 7500 -> 3, full-batch Adam step + validation loss) at
   l = 1000, with the gradient over all rows at once (before) and over blocks of 200 rows (after,
   :func:`jaxcal.nn.row_chunked_value_and_grad`);
3. **padded vs exact rows** at l = 18: the old sweep trained every size on the 1000-row padded set
   with 0/1 weights; now each size trains on its own rows;
4. **epochs to converge** at l = 1000: the previous recipe's measured complete run on this CPU
   (``results/offline_cpu_timing.json``, ``python -m benchmarks.offline_cpu --full-l1000``) vs one
   complete run of the current recipe here.

The epoch's bound is its floating-point work at the measured GEMM rate (its memory traffic, once
the hidden layer is blocked, is the weights only, ~0.2 MB, far below the compute time):
``30 L H + 12 V H`` flops (forward ``12 L H``, backward ``18 L H``, validation forward ``12 V H``).
The network's matrix products have an inner or outer dimension of 3, which no CPU runs at GEMM
speed; the fraction says how far from that ideal the epoch is.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal.constants import ACC_RANGE_G
from jaxcal.metrics import euclidean_error
from jaxcal.nn import MLP, fit_nn, nn_calibrate
from jaxcal.normalise import bounds_from_spec
from jaxcal.offline import NNTrainSpec
from jaxcal.simulate.dataset1 import dataset1
from jaxcal.train import TrainConfig

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "results"
WIDTH = 7500


def _median(fn, reps: int) -> float:
    jax.block_until_ready(fn())
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def machine_bound(reps: int) -> dict:
    """Measured float32 GEMM rate (flop/s) and streaming bandwidth (bytes/s).

    Args:
        reps: repetitions per median.
    """
    n = 2048
    a = jax.random.normal(jax.random.PRNGKey(0), (n, n), jnp.float32)
    mm = jax.jit(lambda x, y: x @ y)
    t_mm = _median(lambda: mm(a, a), reps)
    big = jnp.ones((16 * 2**20,), jnp.float32)  # 64 MB
    st = jax.jit(lambda x: 2.0 * x + 1.0)
    t_st = _median(lambda: st(big), reps)
    return {"gemm_flops_per_s": 2 * n**3 / t_mm, "gemm_n": n, "stream_bytes_per_s": 2 * big.nbytes / t_st,
            "stream_mb": big.nbytes / 2**20}


def _epochs_fn(data, mlp, bounds, row_chunk, epochs: int):
    """A jitted fixed-length training (patience > epochs: no early stop), for per-epoch timing."""
    (y, x, w), val = data
    cfg = TrainConfig(learning_rate=1e-5, patience=epochs + 1)
    f = jax.jit(lambda k: fit_nn(k, mlp, bounds, (y, x, w), val, cfg, epochs, False, row_chunk)[1].best_val)
    return lambda: f(jax.random.PRNGKey(0))


def epoch_times(reps: int, epochs: int = 20) -> dict:
    """Seconds per epoch: l = 1000 plain vs row-blocked; l = 18 padded to 1000 rows vs exact rows.

    Args:
        reps: repetitions per median.
        epochs: epochs per timed call.
    """
    d = dataset1(jax.random.PRNGKey(0))
    mlp = MLP((WIDTH,))
    bounds = bounds_from_spec(d.spec, ACC_RANGE_G)
    val = (d.val.acc, d.val.acc_ref)
    y, x = d.train.acc, d.train.acc_ref
    ones = jnp.ones(y.shape[0])
    w18 = ones.at[18:].set(0.0)
    out = {}
    for name, data, chunk in (
        ("l1000_plain", ((y, x, ones), val), None),
        ("l1000_blocked", ((y, x, ones), val), 200),
        ("l18_padded_1000_rows", ((y, x, w18), val), None),
        ("l18_exact_rows", ((y[:18], x[:18], ones[:18]), val), None),
    ):
        out[name] = _median(_epochs_fn(data, mlp, bounds, chunk, epochs), reps) / epochs
    out["blocked_speedup"] = out["l1000_plain"] / out["l1000_blocked"]
    out["exact_rows_speedup_l18"] = out["l18_padded_1000_rows"] / out["l18_exact_rows"]
    out["epochs_per_call"] = epochs
    return out


def epoch_flops(rows: int, val_rows: int, width: int = WIDTH) -> float:
    """Floating-point operations of one full-batch epoch of the 3 -> width -> 3 network.

    Args:
        rows: training rows.
        val_rows: validation rows (one forward pass for early stopping).
        width: hidden units.
    """
    return 30.0 * rows * width + 12.0 * val_rows * width


def convergence(before_file: Path = RESULTS / "offline_cpu_timing.json") -> dict:
    """One complete training of the current recipe at l = 1000 (epochs, seconds, test error) beside the
    previous recipe's complete run on this CPU, as recorded by ``benchmarks.offline_cpu``.

    Args:
        before_file: the previous recipe's record.
    """
    d = dataset1(jax.random.PRNGKey(0))
    mlp = MLP((WIDTH,))
    bounds = bounds_from_spec(d.spec, ACC_RANGE_G)
    spec = NNTrainSpec()
    y, x = d.train.acc, d.train.acc_ref
    val = (d.val.acc, d.val.acc_ref)

    def train(k):
        cal, res = fit_nn(k, mlp, bounds, (y, x, jnp.ones(y.shape[0])), val, spec.train_config(), spec.max_epochs,
                          spec.warm_start, spec.row_chunk)
        return nn_calibrate(mlp, cal, d.test.acc), res.epochs

    f = jax.jit(train)
    t0 = time.perf_counter()
    c = f.lower(jax.random.PRNGKey(4)).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    cal, ep = jax.block_until_ready(c(jax.random.PRNGKey(4)))
    run_s = time.perf_counter() - t0
    after = {"epochs": int(ep), "run_s": run_s, "compile_s": compile_s,
             "test_mean_mg": 1e3 * float(np.asarray(euclidean_error(d.test.acc_ref, cal)).mean()),
             "recipe": spec._asdict()}
    out = {"after": after}
    if before_file.exists():
        b = json.loads(before_file.read_text()).get("full_one_training_l1000")
        if b:
            out["before"] = {**b, "source": f"{before_file.relative_to(ROOT)} (python -m benchmarks.offline_cpu "
                             "--full-l1000; Adam 2e-2 from the random initialisation, padded rows)"}
            out["time_ratio"] = b["run_s"] / run_s
    return out


def nn_costs(reps: int) -> dict:
    """Everything above, and the bound fraction of the current (blocked) epoch at l = 1000.

    Args:
        reps: repetitions per median.
    """
    m = machine_bound(reps)
    e = epoch_times(reps)
    flops = epoch_flops(1000, 184)
    bound_s = flops / m["gemm_flops_per_s"]
    return {
        "machine": m,
        "epoch_s": e,
        "epoch_flops_l1000": flops,
        "epoch_bound_s": bound_s,
        "value": bound_s / e["l1000_blocked"],
        "value_plain": bound_s / e["l1000_plain"],
        "convergence": convergence(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=5)
    print(json.dumps(nn_costs(ap.parse_args().reps), indent=1))


__all__ = ["convergence", "epoch_flops", "epoch_times", "machine_bound", "nn_costs"]

if __name__ == "__main__":
    main()
