"""The performance record: jaxcal's speed on this machine, measured in one run.

    python benchmarks/run.py [--quick] [--json OUT] [--md OUT] [--only KEY ...]

Writes the markdown record (``--md OUT``, default ``results/performance.md``: the machine described,
compile time apart from run time) and the JSON (``--json OUT``, default ``results/performance.json``);
``--only KEY`` (repeatable) runs only the named measurements. Every time is the median of several
repetitions of an already compiled function, each ended by ``block_until_ready``; compile times are
measured with the persistent compilation cache off. Keys:

- ``online_realtime_factor``: seconds of 100 Hz Dataset-2 data per second of compute for jaxcal's
  ``online`` (one streaming pass, ``online_pass``'s jitted scan, float64), ``diag`` (headline) and ``affine``;
- ``scan_vs_loop``: the online-thesis adaptive loop as one ``lax.scan`` (the library's own function,
  initial training switched off: ``init_epochs = 0``) vs a Python loop of one jitted step per sequence
  doing the same updates (written here from the library's step functions); final parameters compared;
- ``sweep_gain_64``: 64 online-thesis configurations (8 gyroscope x 8 accelerometer learning rates) as
  the one call ``jaxcal sweep`` makes (each distinct initial training once, the adaptive loop vmapped) vs
  one after another through a jitted single-configuration function (metrics in mg and mrad/s);
- ``sharded_equals_unsharded``: a tiny sweep on 4 forced host devices (subprocess) vs one device;
- ``jax_vs_torch``: the same online-thesis adaptive loop written plainly in eager PyTorch on the CPU
  (``benchmarks/torch_online_thesis.py``, the optional ``bench`` extra) vs the library's ``lax.scan``,
  from the same initial parameters and data: torch run time / jax run time, final parameters compared;
- ``nn_epoch_bound_fraction``: the thesis NN's epoch at l = 1000 vs its FLOP count at the measured GEMM
  rate, with the per-epoch, padded-rows and epochs-to-converge costs before and after
  (``benchmarks/nn_epoch.py``);
- ``reproduce_minutes``: the measured ``make run-full``, read from ``results/reproduce.json`` (written by
  ``experiments.run_all``; not re-run here);
- ``not_measured``: keys that could not be measured in this run, each with why.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # `python benchmarks/run.py` from the repository root
    sys.path.insert(0, str(ROOT))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

from jaxcal import online_thesis as ot  # noqa: E402
from jaxcal import sweep as sw  # noqa: E402
from jaxcal.online import OnlineHP, make_filter, online_scan_jit, spec_sequences  # noqa: E402
from jaxcal.sensor import Diag  # noqa: E402
from jaxcal.simulate.dataset2 import Dataset2Config, dataset2  # noqa: E402

RESULTS = ROOT / "results"
SMALL_D2 = Dataset2Config(n_train=50, n_val=10, n_test_acc=100, n_test_gyr=100)


def _median_time(fn, reps: int) -> tuple[float, list[float]]:
    """Median and all wall times of ``reps`` calls of ``fn`` (each blocks until its result is ready)."""
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), ts


def _compile(jitted, *args, **kw):
    """(compile seconds, compiled function) of ``jitted`` at these arguments."""
    t0 = time.perf_counter()
    c = jitted.lower(*args, **kw).compile()
    return time.perf_counter() - t0, c


def machine() -> dict:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu_model": cpu,
        "cpu_count": os.cpu_count(),
        "sched_affinity_cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "platform": f"{platform.machine()} {platform.system()} {platform.release()}",
        "python": platform.python_version(),
        "jax_version": jax.__version__,
        "jaxlib_version": getattr(jax.lib, "__version__", None) or __import__("jaxlib").__version__,
        "devices": [str(d) for d in jax.devices()],
        "load_average_at_start": list(os.getloadavg()),
        "env": {k: os.environ.get(k) for k in ("XLA_FLAGS", "OPENBLAS_NUM_THREADS", "JAX_PLATFORMS")},
    }


# ----------------------------------------------------------------------------- online real-time factor


def online_realtime_factor(reps: int) -> dict:
    d = dataset2(jax.random.PRNGKey(0))
    m, n = d.train.acc.shape[:2]
    data_s = m * n * d.dt
    out: dict = {"dataset": f"Dataset 2 (default config), {m} sequences x {n} samples at {1 / d.dt:.0f} Hz",
                 "data_s": data_s, "function": "online_pass's jitted scan (float64), compiled once"}
    with jax.enable_x64(True):
        f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
        aspec = Diag(f64(d.acc_spec.s), f64(d.acc_spec.b))
        gspec = Diag(f64(d.gyr_spec.s), f64(d.gyr_spec.b))
        batch = spec_sequences(f64(d.train.acc), f64(d.train.gyr), aspec, gspec)
        hp = OnlineHP(*[jnp.asarray(v) for v in OnlineHP()])
        dt = f64(d.dt)
        for kind in ("diag", "affine"):
            st0 = make_filter(kind).init(hp, jnp.float64)
            c, fn = _compile(online_scan_jit, st0, batch, dt, hp, kind=kind)
            jax.block_until_ready(fn(st0, batch, dt, hp))  # warm-up
            run_s, all_s = _median_time(lambda: fn(st0, batch, dt, hp), reps)  # noqa: B023
            out[kind] = {"compile_s": c, "run_s": run_s, "run_s_all": all_s, "realtime_factor": data_s / run_s}
    out["kind"] = "diag"
    out["value"] = out["diag"]["realtime_factor"]
    out["run_s"] = out["diag"]["run_s"]
    return out


# ----------------------------------------------------------------------------- scan vs Python loop


def _step_fn(acc_spec: Diag, gyr_spec: Diag):
    """One adaptive-loop step of the library's ``_online_thesis`` (gyroscope then accelerometer update),
    from the library's step functions; jitted on its own, for a Python loop over sequences."""
    cal_a = partial(ot.calibrate_acc, spec=acc_spec)
    cal_g = partial(ot.calibrate_gyr, spec=gyr_spec)

    @jax.jit
    def step(carry, a_raw, g_raw, dt, hp):
        acc_p, gyr_p, s_a, s_g = carry
        opt_g, opt_a = optax.adam(hp.gyr_lr), optax.adam(hp.acc_lr)
        a_c = jax.lax.stop_gradient(cal_a(acc_p, a_raw))
        g_loss_fn = lambda p: ot.gyro_loss(cal_g(p, g_raw), a_c, dt)  # noqa: E731
        gyr_p, s_g, _ = ot.adam_steps(g_loss_fn, gyr_p, s_g, opt_g, hp.gyr_steps)
        phi_c = jax.lax.stop_gradient(cal_g(gyr_p, g_raw))
        a_c1 = jax.lax.stop_gradient(cal_a(acc_p, a_raw[0]))
        a_loss_fn = lambda p: ot.acc_loss(a_c1, cal_a(p, a_raw[-1]), phi_c, dt, hp.w)  # noqa: E731
        acc_p, s_a, _ = ot.adam_steps(a_loss_fn, acc_p, s_a, opt_a, hp.acc_steps)
        return acc_p, gyr_p, s_a, s_g

    return step


def scan_vs_loop(reps: int) -> dict:
    d = dataset2(jax.random.PRNGKey(0))
    hp = ot.default_hparams(jax.random.PRNGKey(1), init_epochs=0)  # adaptive loop only
    dt = jnp.asarray(d.dt, jnp.float32)
    acc, gyr = d.train.acc, d.train.gyr
    m = acc.shape[0]

    # scan: the library's jitted function (no validation set), initial training of 0 epochs.
    c_scan, scan_fn = _compile(ot.run_sequences, acc, gyr, dt, d.acc_spec, d.gyr_spec, hp, init_every=ot.INIT_EVERY)
    scan_call = lambda: scan_fn(acc, gyr, dt, d.acc_spec, d.gyr_spec, hp)  # noqa: E731
    res = jax.block_until_ready(scan_call())
    t_scan, all_scan = _median_time(scan_call, reps)

    # loop: the same initial parameters (init_epochs = 0: the scaled initial weights), one jitted step per sequence.
    k_a, k_g = jax.random.split(hp.key)
    acc_p0 = ot.init_params(k_a, hp.acc_init_scale)
    gyr_p0 = ot.init_params(k_g, hp.gyr_init_scale)
    carry0 = (acc_p0, gyr_p0, optax.adam(hp.acc_lr).init(acc_p0), optax.adam(hp.gyr_lr).init(gyr_p0))
    step = _step_fn(d.acc_spec, d.gyr_spec)
    seqs = [(acc[i], gyr[i]) for i in range(m)]  # sliced beforehand: the loop times the steps, not the slicing
    t0 = time.perf_counter()
    step_c = step.lower(carry0, *seqs[0], dt, hp).compile()
    c_loop = time.perf_counter() - t0

    def loop():
        carry = carry0
        for a, g in seqs:
            carry = step_c(carry, a, g, dt, hp)
        return carry

    final = jax.block_until_ready(loop())
    t_loop, all_loop = _median_time(loop, reps)

    diffs = jax.tree.map(lambda x, y: float(jnp.max(jnp.abs(x - y))), (final[0], final[1]), (res.acc_params, res.gyr_params))
    scale = jax.tree.map(lambda y: float(jnp.max(jnp.abs(y))), (res.acc_params, res.gyr_params))
    max_abs = max(jax.tree.leaves(diffs))
    max_param = max(jax.tree.leaves(scale))
    rtol, atol = 1e-4, 1e-5
    same = all(bool(jnp.allclose(x, y, rtol=rtol, atol=atol)) for x, y in
               zip(jax.tree.leaves((final[0], final[1])), jax.tree.leaves((res.acc_params, res.gyr_params)), strict=True))
    return {
        "dataset": f"Dataset 2 (default config): {m} sequences of {acc.shape[1]} samples, float32",
        "what": "adaptive loop only (init_epochs = 0); scan: jaxcal.online_thesis.run_sequences; "
                "loop: Python for over sequences of one jitted step (same calibrate/loss/adam_steps functions)",
        "scan": {"compile_s": c_scan, "run_s": t_scan, "run_s_all": all_scan},
        "loop": {"compile_s": c_loop, "run_s": t_loop, "run_s_all": all_loop, "per_step_us": t_loop / m * 1e6},
        "value": t_loop / t_scan,
        "ratio": "loop run time / scan run time",
        "same_final_params": same,
        "tolerance": {"rtol": rtol, "atol": atol},
        "max_abs_param_diff": max_abs,
        "max_abs_param": max_param,
    }


# ----------------------------------------------------------------------------- 64 configurations


def sweep_gain_64(reps: int, quick: bool) -> dict:
    cfg = SMALL_D2 if quick else Dataset2Config()
    d = dataset2(jax.random.PRNGKey(0), cfg)
    gyr_lrs = np.logspace(-5, -3, 8)
    acc_lrs = np.logspace(-5, -4, 8)
    key = sw.weights_key(0)  # seed 0 of the sweep: its dataset is PRNGKey(0), as d
    hps = [ot.default_hparams(key, gyr_lr=float(g), acc_lr=float(a)) for g in gyr_lrs for a in acc_lrs]

    def one(data, hp):
        r = ot.run_dataset(data, hp)
        ea, eg = ot.test_set_errors((r.acc_params, r.gyr_params), data)
        return 1e3 * jnp.stack([ea.mean(), eg.mean(), r.e_a[-1], r.e_g[-1]])

    # vmapped: the one call `jaxcal sweep` makes for these 64 configurations (a batch of the online-thesis
    # target: each distinct initial training once, here one, then the adaptive loop vmapped over the 64).
    spec = sw.SweepSpec(grid={"gyr_lr": [float(g) for g in gyr_lrs], "acc_lr": [float(a) for a in acc_lrs]}, seeds=(0,),
                        dataset=cfg)
    (batch,) = sw.plan(spec)
    prep = sw.TARGETS["online-thesis"].prepare(spec, batch.key, batch.configs)
    c_one, one_c = _compile(jax.jit(one), d, hps[0])
    c_vm, vm_c = _compile(prep.fn.func, prep.shared, prep.per_config, **prep.fn.keywords)
    cols = ("test_acc_mg", "test_gyr_mrads", "val_e_a_final_mg", "val_e_g_final_mrads")

    def vm_call():
        return vm_c(prep.shared, prep.per_config)

    seq_out = jax.block_until_ready(jnp.stack([one_c(d, hp) for hp in hps]))
    vm_out = jnp.stack([jax.block_until_ready(vm_call())[c] for c in cols], axis=1)
    t_seq, all_seq = _median_time(lambda: [one_c(d, hp) for hp in hps], reps)
    t_vm, all_vm = _median_time(vm_call, reps)
    finite = np.isfinite(np.asarray(seq_out)) & np.isfinite(np.asarray(vm_out))
    return {
        "dataset": f"Dataset 2, {cfg.n_train} training / {cfg.n_val} validation sequences"
                   + (" (small, --quick)" if quick else " (default config)"),
        "configurations": "8 gyr_lr (1e-5..1e-3, log) x 8 acc_lr (1e-5..1e-4, log), other hyperparameters default "
                          f"(init_epochs {int(hps[0].init_epochs)}); whole algorithm + test-set errors per configuration; "
                          "vmapped: the jaxcal sweep call (the initial training, shared by the 64, run once)",
        "n_configs": len(hps),
        "repetitions": reps,
        "sequential": {"compile_s": c_one, "run_s": t_seq, "run_s_all": all_seq},
        "vmapped": {"compile_s": c_vm, "run_s": t_vm, "run_s_all": all_vm},
        "value": t_seq / t_vm,
        "ratio": "sequential run time / vmapped run time (both compiled once)",
        "max_abs_metric_diff_vmapped_vs_sequential": float(np.max(np.abs(np.asarray(seq_out) - np.asarray(vm_out))[finite]))
        if finite.any() else None,
        "nonfinite_metrics": int((~finite).sum()),
    }


# ----------------------------------------------------------------------------- sharded vs unsharded

_SHARD_SNIPPET = """
import json, jax
from jaxcal import sweep as sw
from jaxcal.simulate.dataset2 import Dataset2Config
spec = sw.SweepSpec(grid={"w": [0.7, 0.8, 0.9]}, fixed={"init_epochs": 50}, seeds=(0,),
                    dataset=Dataset2Config(n_train=20, n_val=4, n_test_acc=50, n_test_gyr=50))
res = sw.run_sweep(spec)
print(json.dumps({"n_devices": jax.device_count(), "devices_used": res.timing["devices"], "rows": res.rows,
                  "total_s": res.timing["total_s"]}))
"""


def _shard_run(n_devices: int) -> dict:
    env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=str(ROOT))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    if n_devices > 1:
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={n_devices}"
    else:
        env.pop("XLA_FLAGS", None)
    out = subprocess.run([sys.executable, "-c", _SHARD_SNIPPET], env=env, capture_output=True, text=True,
                         timeout=600, cwd=ROOT)
    if out.returncode != 0:
        raise RuntimeError(f"sharded sweep subprocess failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def sharded_equals_unsharded() -> dict:
    four, one = _shard_run(4), _shard_run(1)
    metrics = [k for k, v in one["rows"][0].items() if isinstance(v, float) and k != "w"]
    diffs = [abs(a[k] - b[k]) for a, b in zip(four["rows"], one["rows"], strict=True) for k in metrics]
    rel = [abs(a[k] - b[k]) / max(abs(b[k]), 1e-12) for a, b in zip(four["rows"], one["rows"], strict=True) for k in metrics]
    rtol = 1e-5
    return {
        "what": "run_sweep of 3 configurations (w 0.7/0.8/0.9, Dataset 2 with 20 training sequences, init_epochs 50), "
                "each in a fresh subprocess: 4 forced host devices (padded to 4, one per device) vs 1 device",
        "value": bool(max(rel) <= rtol and len(four["rows"]) == len(one["rows"])),
        "tolerance": {"rtol": rtol},
        "max_abs_diff": max(diffs),
        "max_rel_diff": max(rel),
        "n_devices": [four["n_devices"], one["n_devices"]],
        "devices_used": [four["devices_used"], one["devices_used"]],
        "sweep_s": [four["total_s"], one["total_s"]],
    }


# ----------------------------------------------------------------------------- JAX vs PyTorch


def _torch_runs(make, run, reps: int) -> tuple[float, float, list[float], float, tuple]:
    """(first-run s, median s, all timed s, process CPU s per wall s of the timed calls, (last inputs, last
    output)) of ``run(*make())``: one warm-up call then ``reps`` timed ones, each on fresh inputs from ``make``
    (not timed; torch on the CPU is synchronous: the call returns when the work is done)."""
    ts, cpu, last = [], 0.0, ()
    for i in range(reps + 1):
        args = make()
        t0, c0 = time.perf_counter(), time.process_time()
        out = run(*args)
        ts.append(time.perf_counter() - t0)
        cpu += (time.process_time() - c0) if i else 0.0
        last = (args, out)
    return ts[0], statistics.median(ts[1:]), ts[1:], cpu / sum(ts[1:]), last


def jax_vs_torch(reps: int) -> dict:
    """The online-thesis adaptive loop: the library's jitted ``lax.scan`` vs the same updates in eager PyTorch.

    Both start from the same initial weights (jaxcal's flax ones, copied into ``torch.nn``) and the same
    Dataset 2 training sequences, with ``init_epochs = 0`` as in ``scan_vs_loop``. torch gets as many threads
    as the cores JAX keeps busy on this work (measured: process CPU time / wall time); a torch run with a
    thread per core is timed once beside it on the first 50 sequences. Final parameters, per-sequence losses
    and calibrated test-set outputs of the last timed runs are compared.
    """
    try:
        import torch

        from benchmarks import torch_online_thesis as tot
    except ImportError as e:
        return {"value": None, "not_measured": f"torch is not installed ({e}); `pip install -e '.[bench]'` installs it"}

    d = dataset2(jax.random.PRNGKey(0))
    hp = ot.default_hparams(jax.random.PRNGKey(1), init_epochs=0)  # adaptive loop only
    dt = jnp.asarray(d.dt, jnp.float32)
    acc, gyr = d.train.acc, d.train.gyr
    m, n = acc.shape[:2]

    # JAX: the library's function, AOT-compiled (compile time apart), then timed.
    c_jax, jax_fn = _compile(ot.run_sequences, acc, gyr, dt, d.acc_spec, d.gyr_spec, hp, init_every=ot.INIT_EVERY)
    last: dict = {}

    def jax_call():
        last["res"] = jax_fn(acc, gyr, dt, d.acc_spec, d.gyr_spec, hp)
        return last["res"]

    t0 = time.perf_counter()
    jax.block_until_ready(jax_call())
    first_jax = time.perf_counter() - t0
    c0 = time.process_time()
    t_jax, all_jax = _median_time(jax_call, reps)
    jax_cpu_per_wall = (time.process_time() - c0) / sum(all_jax)  # cores XLA:CPU keeps busy on this work
    res = last["res"]

    # torch: the same initial parameters (init_epochs = 0: the scaled flax initial weights), data and bounds.
    k_a, k_g = jax.random.split(hp.key)
    p_a0 = ot.init_params(k_a, hp.acc_init_scale)
    p_g0 = ot.init_params(k_g, hp.gyr_init_scale)
    tt = lambda x: torch.from_numpy(np.array(x, dtype=np.float32))  # noqa: E731
    a_t, g_t = tt(acc), tt(gyr)
    ab, gb = tuple(map(tt, ot.acc_bounds(d.acc_spec))), tuple(map(tt, ot.gyr_bounds(d.gyr_spec)))
    cfg = tot.TorchLoopConfig(gyr_lr=float(hp.gyr_lr), gyr_steps=int(hp.gyr_steps), acc_lr=float(hp.acc_lr),
                              acc_steps=int(hp.acc_steps), w=float(hp.w), dt=float(dt))

    make_nets = lambda: (tot.mlp_from_flax(p_a0), tot.mlp_from_flax(p_g0))  # noqa: E731
    torch_call = lambda net_a, net_g: tot.adaptive_loop(a_t, g_t, ab, gb, net_a, net_g, cfg)  # noqa: E731
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    # torch gets the cores XLA:CPU actually uses here (its pool has one thread per core, but the scan's small ops
    # run on one of them: process CPU time / wall time of the jax runs, rounded).
    threads = max(1, min(cores, round(jax_cpu_per_wall)))
    threads_before = torch.get_num_threads()
    torch.set_num_threads(threads)
    first_t, t_torch, all_torch, torch_cpu_per_wall, ((net_a, net_g), out) = _torch_runs(make_nets, torch_call, reps)
    all_cores = None
    if cores != threads:  # beside it: torch with a thread per core, once on the first 50 sequences (see the note)
        torch.set_num_threads(cores)
        n_all = min(50, m)
        t0 = time.perf_counter()
        tot.adaptive_loop(a_t[:n_all], g_t[:n_all], ab, gb, *make_nets(), cfg)
        all_cores = {"threads": cores, "sequences": n_all, "per_sequence_us": (time.perf_counter() - t0) / n_all * 1e6}
        torch.set_num_threads(threads)
    # What eager torch dispatches per sequence: ATen calls (nested ones included) on the first 20 sequences.
    from torch.profiler import ProfilerActivity, profile

    n_prof = min(20, m)
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        tot.adaptive_loop(a_t[:n_prof], g_t[:n_prof], ab, gb, *make_nets(), cfg)
    aten_per_seq = sum(e.count for e in prof.key_averages() if e.key.startswith("aten::")) / n_prof
    torch.set_num_threads(threads_before)

    # Equivalence: final parameters, per-sequence losses and calibrated test-set outputs of the last timed runs.
    p_torch = (tot.flax_from_mlp(net_a), tot.flax_from_mlp(net_g))
    p_jax = (res.acc_params, res.gyr_params)
    leaves_t, leaves_j = jax.tree.leaves(p_torch), jax.tree.leaves(p_jax)
    max_param_diff = max(float(np.max(np.abs(np.asarray(x) - y))) for x, y in zip(leaves_j, leaves_t, strict=True))
    max_param = max(float(np.max(np.abs(np.asarray(x)))) for x in leaves_j)
    rtol, atol = 1e-4, 1e-5
    same = all(np.allclose(y, np.asarray(x), rtol=rtol, atol=atol) for x, y in zip(leaves_j, leaves_t, strict=True))
    loss_diff = {k: float(np.max(np.abs(np.asarray(getattr(res, k)) - getattr(out, k).numpy()))) for k in ("gyr_loss", "acc_loss")}
    loss_scale = {k: float(np.max(np.abs(np.asarray(getattr(res, k))))) for k in ("gyr_loss", "acc_loss")}
    pt = jax.tree.map(jnp.asarray, p_torch)
    out_diff = {
        "acc_g": float(jnp.max(jnp.abs(ot.calibrate_acc(pt[0], d.test_acc.raw, d.acc_spec)
                                       - ot.calibrate_acc(res.acc_params, d.test_acc.raw, d.acc_spec)))),
        "gyr_rads": float(jnp.max(jnp.abs(ot.calibrate_gyr(pt[1], d.test_gyr.raw, d.gyr_spec)
                                          - ot.calibrate_gyr(res.gyr_params, d.test_gyr.raw, d.gyr_spec)))),
    }
    return {
        "dataset": f"Dataset 2 (default config): {m} sequences of {n} samples, float32",
        "what": "online-thesis adaptive loop only (init_epochs = 0; gyroscope then accelerometer Adam update per "
                "sequence, default hyperparameters): jax = jaxcal.online_thesis.run_sequences (one jitted lax.scan); "
                "torch = benchmarks/torch_online_thesis.adaptive_loop (eager torch.nn + torch.optim.Adam(fused=True), "
                "Python for over sequences, R_tot as a pairwise tree of bmm), same initial weights and data",
        "torch_version": torch.__version__,
        "threads": threads,
        "threads_note": f"torch.set_num_threads({threads}): the cores jax keeps busy on this work (process CPU time / "
                        f"wall time of its timed runs {jax_cpu_per_wall:.2f}; XLA:CPU's pool has a thread for each of the "
                        f"{cores} cores, but the scan's small ops run on one); torch's own CPU / wall {torch_cpu_per_wall:.2f}",
        "cores": cores,
        "jax_s": t_jax,
        "torch_s": t_torch,
        "ratio": t_torch / t_jax,
        "value": t_torch / t_jax,
        "ratio_is": "torch run time / jax run time (median of repetitions, compile and first runs apart)",
        "jax": {"compile_s": c_jax, "first_run_s": first_jax, "run_s": t_jax, "run_s_all": all_jax,
                "per_sequence_us": t_jax / m * 1e6, "cpu_per_wall": jax_cpu_per_wall},
        "torch": {"first_run_s": first_t, "run_s": t_torch, "run_s_all": all_torch, "per_sequence_us": t_torch / m * 1e6,
                  "aten_calls_per_sequence": aten_per_seq, "cpu_per_wall": torch_cpu_per_wall},
        "torch_all_cores": all_cores,
        "same_final_params": same,
        "tolerance": {"rtol": rtol, "atol": atol},
        "max_param_diff": max_param_diff,
        "max_abs_param": max_param,
        "max_loss_diff": loss_diff,
        "max_loss": loss_scale,
        "max_test_output_diff": out_diff,
    }


# ----------------------------------------------------------------------------- report

NOT_MEASURED: dict[str, str] = {}


def nn_epoch_bound_fraction(reps: int) -> dict:
    """The chapter-3 NN's epoch against the machine's bound, and the before/after costs (``benchmarks.nn_epoch``)."""
    from benchmarks.nn_epoch import nn_costs

    return nn_costs(reps)


def reproduce_minutes() -> dict:
    """The measured ``make run-full`` (and ``make run``), as ``experiments.run_all`` recorded them.

    Not re-run here (it takes longer than this record's budget): ``results/reproduce.json`` is
    written by ``make run-full`` itself, on a fresh clone, and ``results/reproduce_quick.json`` by
    ``make run``; this reads them.
    """
    out: dict = {"value": None}
    for key, name in (("run_full", "reproduce.json"), ("run", "reproduce_quick.json")):
        f = RESULTS / name
        if f.exists():
            out[key] = json.loads(f.read_text())
    if "run_full" in out:
        out["value"] = out["run_full"]["minutes"]
    return out


def _jax_vs_torch_md(jt: dict) -> tuple[list[str], list[str]]:
    """(table rows, notes) of the ``jax_vs_torch`` key."""
    f = lambda x: f"{x:.3g}"  # noqa: E731
    ac = jt["torch_all_cores"]
    rows = [f"| `jax_vs_torch` | **{jt['ratio']:.1f}x** (torch / jax) | torch {f(jt['torch_s'])} s "
            f"({jt['torch']['per_sequence_us']:.0f} us per sequence, {jt['threads']} thread{'s' * (jt['threads'] > 1)}), "
            f"jax {f(jt['jax_s'])} s "
            f"({jt['jax']['per_sequence_us']:.0f} us per sequence) | jax {jt['jax']['compile_s']:.2f} s "
            f"(torch: none; first run {f(jt['torch']['first_run_s'])} s) |"]
    lose = ("" if jt["ratio"] >= 1 else
            f" **jax is slower here** ({jt['jax']['per_sequence_us']:.0f} vs {jt['torch']['per_sequence_us']:.0f} us per "
            "sequence): see the report for the measured per-step overhead.")
    notes = [
        f"- `jax_vs_torch`: {jt['dataset']}; {jt['what']}; torch {jt['torch_version']}. {jt['threads_note']}. "
        f"Same final parameters: **{str(jt['same_final_params']).lower()}** (rtol {jt['tolerance']['rtol']}, atol "
        f"{jt['tolerance']['atol']}; max abs difference {jt['max_param_diff']:.3g} on parameters up to "
        f"{jt['max_abs_param']:.3g}); per-sequence losses differ by at most {jt['max_loss_diff']['gyr_loss']:.3g} "
        f"(gyroscope, losses up to {jt['max_loss']['gyr_loss']:.3g}) and {jt['max_loss_diff']['acc_loss']:.3g} "
        f"(accelerometer, up to {jt['max_loss']['acc_loss']:.3g}); calibrated test-set outputs by "
        f"{jt['max_test_output_diff']['acc_g']:.3g} g and {jt['max_test_output_diff']['gyr_rads']:.3g} rad/s. "
        "Why jax is faster: the scan runs each sequence's two updates as one compiled XLA loop body, while eager "
        "PyTorch dispatches every small op from Python ("
        f"{jt['torch']['aten_calls_per_sequence']:.0f} ATen calls per sequence, nested ones included, by torch.profiler: "
        f"forward, backward and Adam on 3-to-10-wide tensors, about "
        f"{jt['torch']['per_sequence_us'] / jt['torch']['aten_calls_per_sequence']:.1f} us each), so its time is "
        "per-op overhead, not arithmetic." + lose,
    ]
    if ac:
        notes.append(
            f"- `jax_vs_torch` with a torch thread per core ({ac['threads']}), once on the first {ac['sequences']} sequences: "
            f"{ac['per_sequence_us']:.0f} us per sequence (vs {jt['torch']['per_sequence_us']:.0f} with "
            f"{jt['threads']}). Extra threads cannot help ops on 3-to-10-wide tensors, and with 2 threads torch's `sin`, "
            "`sqrt` and fused Adam open OpenMP parallel regions even on ~100-element tensors: when the machine's other "
            "core is busy (it is shared), each costs 0.5-1.5 ms (torch.profiler) instead of microseconds; in a "
            "separate check (not rerun here) with `OMP_WAIT_POLICY=PASSIVE`, 2 threads took 2.3-2.5 ms per sequence, as 1 did. "
            "So the run with as many threads as jax uses is the headline.")
    return rows, notes
    return rows, notes


def _markdown(res: dict) -> str:
    m = res["machine"]
    rt, sl, sg, sh = (res.get(k) for k in ("online_realtime_factor", "scan_vs_loop", "sweep_gain_64", "sharded_equals_unsharded"))
    jt = res.get("jax_vs_torch")
    jt_rows, jt_notes = _jax_vs_torch_md(jt) if jt and jt.get("value") is not None else ([], [])
    f = lambda x: f"{x:.3g}"  # noqa: E731
    rows, notes = [], []
    if rt:
        rows += [
            f"| `online_realtime_factor` ({rt['kind']}) | **{rt['value']:.0f}** s of data / s | {rt['data_s']:.0f} s of "
            f"100 Hz data in {rt['diag']['run_s'] * 1e3:.1f} ms | {rt['diag']['compile_s']:.2f} s |",
            f"| `online_realtime_factor` (affine, beside it) | {rt['affine']['realtime_factor']:.0f} | "
            f"{rt['affine']['run_s'] * 1e3:.1f} ms | {rt['affine']['compile_s']:.2f} s |",
        ]
        notes.append(f"- `online_realtime_factor`: {rt['dataset']}; {rt['function']}. Goal in the record: >= 1000.")
    if sl:
        rows.append(
            f"| `scan_vs_loop` | **{sl['value']:.2f}x** (loop / scan) | scan {f(sl['scan']['run_s'])} s, loop "
            f"{f(sl['loop']['run_s'])} s ({sl['loop']['per_step_us']:.0f} us per step) | scan {sl['scan']['compile_s']:.2f} s, "
            f"step {sl['loop']['compile_s']:.2f} s |")
        notes.append(
            f"- `scan_vs_loop`: {sl['dataset']}; {sl['what']}. Same final parameters: "
            f"**{str(sl['same_final_params']).lower()}** (rtol {sl['tolerance']['rtol']}, atol {sl['tolerance']['atol']}; "
            f"max abs difference {sl['max_abs_param_diff']:.3g} on parameters up to {sl['max_abs_param']:.3g}).")
    if sg:
        rows.append(
            f"| `sweep_gain_64` | **{sg['value']:.2f}x** (sequential / vmapped) | sequential {f(sg['sequential']['run_s'])} s, "
            f"vmapped {f(sg['vmapped']['run_s'])} s | one {sg['sequential']['compile_s']:.2f} s, vmapped "
            f"{sg['vmapped']['compile_s']:.2f} s |")
        notes.append(
            f"- `sweep_gain_64`: {sg['dataset']}; {sg['configurations']}. Vmapped vs sequential metrics: max abs "
            f"difference {sg['max_abs_metric_diff_vmapped_vs_sequential']} ({sg['nonfinite_metrics']} non-finite).")
    if sh:
        rows.append(
            f"| `sharded_equals_unsharded` | **{str(sh['value']).lower()}** | max abs diff {sh['max_abs_diff']:.3g}, "
            f"max rel diff {sh['max_rel_diff']:.3g} (devices {sh['n_devices'][0]} vs {sh['n_devices'][1]}) | |")
        notes.append(f"- `sharded_equals_unsharded`: {sh['what']}; rtol {sh['tolerance']['rtol']}.")
    nb = res.get("nn_epoch_bound_fraction")
    if nb:
        es, mb, cv = nb["epoch_s"], nb["machine"], nb["convergence"]
        rows.append(
            f"| `nn_epoch_bound_fraction` | **{nb['value']:.3f}** (bound / epoch) | epoch at l = 1000: "
            f"{es['l1000_blocked'] * 1e3:.1f} ms row-blocked, {es['l1000_plain'] * 1e3:.1f} ms all rows at once "
            f"(fraction {nb['value_plain']:.3f}); bound {nb['epoch_bound_s'] * 1e3:.2f} ms | |")
        before = cv.get("before")
        notes.append(
            f"- `nn_epoch_bound_fraction`: one full-batch Adam epoch of the thesis network (3 -> 7500 -> 3) at l = 1000 "
            f"with the validation loss, {nb['epoch_flops_l1000'] / 1e6:.0f} Mflop; bound = that work at the measured "
            f"float32 GEMM rate ({mb['gemm_flops_per_s'] / 1e9:.0f} Gflop/s, {mb['gemm_n']}^2 products; streaming "
            f"{mb['stream_bytes_per_s'] / 1e9:.1f} GB/s). Row blocks of 200 keep each block's 200 x 7500 activations "
            f"(6 MB in all buffers) near the 2 MB L2 instead of streaming 30 MB arrays: {es['blocked_speedup']:.2f}x per "
            "epoch. What is left: every product has an inner or outer dimension of 3, which no BLAS runs at GEMM "
            "speed, and each block still makes ~8 elementwise passes over its activations; a hand-written gradient "
            "(tried) was no faster than XLA's.")
        notes.append(
            f"- Padded vs exact rows (l = 18): {es['l18_padded_1000_rows'] * 1e3:.1f} ms per epoch on the old padded "
            f"1000 rows vs {es['l18_exact_rows'] * 1e3:.2f} ms on its own 18 rows ({es['exact_rows_speedup_l18']:.0f}x).")
        if before:
            notes.append(
                f"- Epochs to converge at l = 1000, one seed: previous recipe (Adam 2e-2 from the random "
                f"initialisation) {before['epochs']} epochs, {before['run_s']:.0f} s, {before['test_mean_mg']:.3f} mg "
                f"({before['source']}); current recipe (ridge warm start, Adam 3e-5, early stopping at 0.1 %) "
                f"{cv['after']['epochs']} epochs, {cv['after']['run_s']:.1f} s, {cv['after']['test_mean_mg']:.3f} mg: "
                f"**{cv['time_ratio']:.0f}x** less time for the same error.")
    rp = res.get("reproduce_minutes")
    if rp and rp.get("value") is not None:
        rf = rp["run_full"]
        rows.append(f"| `reproduce_minutes` | **{rp['value']:.1f}** min (`make run-full`) | "
                    + ", ".join(f"{k.split('.')[-1]} {v:.0f} s" for k, v in rf["experiments"].items()) + " | |")
        q = rp.get("run")
        notes.append(
            f"- `reproduce_minutes`: read from `results/reproduce.json`, written by `make run-full` ({rf['command']}) "
            f"on {rf['machine']}, load average {rf['load_average_1min_at_end']:.1f} at the end; not re-run by this "
            "benchmark." + (f" `make run` ({q['command']}): {q['minutes']:.1f} min." if q else ""))
    rows += jt_rows
    notes += jt_notes
    sweep_reps = f" ({sg['repetitions']} for `sweep_gain_64`)" if sg else ""
    lines = [
        "# Performance record" + (" (quick form)" if res["quick"] else "")
        + (f" (only {', '.join(res['only'])})" if res.get("only") else ""),
        "",
        f"Written by `python benchmarks/run.py{' --quick' if res['quick'] else ''}"
        + "".join(f" --only {k}" for k in res.get("only") or ()) + f"` in {res['wall_s']:.0f} s. "
        f"Every run time is the median of {res['repetitions']} repetitions{sweep_reps} "
        "of an already compiled and once-run function (each ended by "
        "`block_until_ready`); compile times are separate, with the persistent compilation cache off. "
        "Numbers are for this machine only.",
        "",
        "## Machine",
        "",
        f"- CPU: {m['cpu_model']}; {m['cpu_count']} logical cores (affinity {m['sched_affinity_cores']})",
        f"- {m['platform']}, Python {m['python']}, jax {m['jax_version']}, jaxlib {m['jaxlib_version']}",
        f"- devices: {', '.join(m['devices'])}",
        f"- load average (1/5/15 min): at start {'/'.join(f'{x:.2f}' for x in m['load_average_at_start'])}, "
        f"at end {'/'.join(f'{x:.2f}' for x in res['load_average_at_end'])}",
        "",
        "## Results",
        "",
        "| key | value | measured | compile |",
        "|---|---|---|---|",
        *rows,
        "",
        "## Notes",
        "",
        *notes,
        "",
        "## Not measured in this version",
        "",
        *([f"- `{k}`: {v}" for k, v in res["not_measured"].items()] or ["- none: every key of the record was measured."]),
        "",
    ]
    return "\n".join(lines)


MEASUREMENTS = ("online_realtime_factor", "scan_vs_loop", "sweep_gain_64", "nn_epoch_bound_fraction", "jax_vs_torch",
                "sharded_equals_unsharded", "reproduce_minutes")


def main(quick: bool, json_out: Path, md_out: Path = RESULTS / "performance.md", only: list[str] | None = None) -> dict:
    # Real compile times: the persistent cache would serve them from disk.
    jax.config.update("jax_enable_compilation_cache", False)
    t0 = time.perf_counter()
    reps = 3 if quick else 7
    res: dict = {"quick": quick, "machine": machine(), "repetitions": reps}
    if only:
        res["only"] = list(only)
    runs = {"online_realtime_factor": lambda: online_realtime_factor(reps),
            "scan_vs_loop": lambda: scan_vs_loop(reps),
            "sweep_gain_64": lambda: sweep_gain_64(3 if quick else 1, quick),
            "nn_epoch_bound_fraction": lambda: nn_epoch_bound_fraction(reps),
            "reproduce_minutes": reproduce_minutes,
            # after the in-process JAX measurements: torch is imported here, and only here
            "jax_vs_torch": lambda: jax_vs_torch(reps),
            "sharded_equals_unsharded": sharded_equals_unsharded}
    for name in MEASUREMENTS:
        if only and name not in only:
            continue
        t = time.perf_counter()
        res[name] = runs[name]()
        print(f"{name}: {res[name]['value']} ({time.perf_counter() - t:.1f} s)", flush=True)
    res["not_measured"] = dict(NOT_MEASURED)
    if res.get("jax_vs_torch", {}).get("value", 0) is None:  # torch missing: say so instead of a number
        res["not_measured"]["jax_vs_torch"] = res["jax_vs_torch"]["not_measured"]
    if res.get("reproduce_minutes", {}).get("value", 0) is None:
        res["not_measured"]["reproduce_minutes"] = "no results/reproduce.json: run `make run-full` first"
    res["load_average_at_end"] = list(os.getloadavg())
    res["wall_s"] = time.perf_counter() - t0
    json_out.parent.mkdir(parents=True, exist_ok=True)
    json_out.write_text(json.dumps(res, indent=1) + "\n")
    md_out.parent.mkdir(parents=True, exist_ok=True)
    md_out.write_text(_markdown(res))
    print(f"wrote {json_out} and {md_out} in {res['wall_s']:.0f} s")
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small Dataset 2 for the 64-configuration sweep, 3 repetitions")
    ap.add_argument("--json", type=Path, default=RESULTS / "performance.json", help="JSON output path")
    ap.add_argument("--md", type=Path, default=RESULTS / "performance.md", help="markdown output path")
    ap.add_argument("--only", action="append", choices=MEASUREMENTS, metavar="KEY",
                    help=f"run only this measurement (repeatable; one of {', '.join(MEASUREMENTS)})")
    a = ap.parse_args()
    main(a.quick, a.json, a.md, a.only)
