"""The performance record: jaxcal's speed on this machine, measured in one run.

    python benchmarks/run.py [--quick] [--json OUT]

Writes ``results/performance.md`` (the machine described, compile time apart from run time) and the
JSON (``--json OUT``, default ``results/performance.json``). Every time is the median of several
repetitions of an already compiled function, each ended by ``block_until_ready``; compile times are
measured with the persistent compilation cache off. Keys:

- ``online_realtime_factor``: seconds of 100 Hz Dataset-2 data per second of compute for jaxcal's
  ``online`` (one streaming pass, ``online_pass``'s jitted scan, float64), ``diag`` (headline) and ``affine``;
- ``scan_vs_loop``: the online-thesis adaptive loop as one ``lax.scan`` (the library's own function,
  initial training switched off: ``init_epochs = 0``) vs a Python loop of one jitted step per sequence
  doing the same updates (written here from the library's step functions); final parameters compared;
- ``sweep_gain_64``: 64 online-thesis configurations (8 gyroscope x 8 accelerometer learning rates) as
  one vmapped call vs one after another through the same jitted single-configuration function;
- ``sharded_equals_unsharded``: a tiny sweep on 4 forced host devices (subprocess) vs one device;
- ``not_measured``: the record's other keys, each with why it is not measured in this version.
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
from jaxcal.online import OnlineHP, _online_scan_jit, make_filter, spec_sequences  # noqa: E402
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
            c, fn = _compile(_online_scan_jit, st0, batch, dt, hp, kind=kind)
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
        gyr_p, s_g, _ = ot._adam_steps(g_loss_fn, gyr_p, s_g, opt_g, hp.gyr_steps)
        phi_c = jax.lax.stop_gradient(cal_g(gyr_p, g_raw))
        a_c1 = jax.lax.stop_gradient(cal_a(acc_p, a_raw[0]))
        a_loss_fn = lambda p: ot.acc_loss(a_c1, cal_a(p, a_raw[-1]), phi_c, dt, hp.w)  # noqa: E731
        acc_p, s_a, _ = ot._adam_steps(a_loss_fn, acc_p, s_a, opt_a, hp.acc_steps)
        return acc_p, gyr_p, s_a, s_g

    return step


def scan_vs_loop(reps: int) -> dict:
    d = dataset2(jax.random.PRNGKey(0))
    hp = ot.default_hparams(jax.random.PRNGKey(1), init_epochs=0)  # adaptive loop only
    dt = jnp.asarray(d.dt, jnp.float32)
    acc, gyr = d.train.acc, d.train.gyr
    m = acc.shape[0]

    # scan: the library's jitted function (no validation set), initial training of 0 epochs.
    c_scan, scan_fn = _compile(ot._run_sequences, acc, gyr, dt, d.acc_spec, d.gyr_spec, hp, init_every=ot.INIT_EVERY)
    scan_call = lambda: scan_fn(acc, gyr, dt, d.acc_spec, d.gyr_spec, hp)  # noqa: E731
    res = jax.block_until_ready(scan_call())
    t_scan, all_scan = _median_time(scan_call, reps)

    # loop: the same initial parameters (init_epochs = 0: the scaled initial weights), one jitted step per sequence.
    k_a, k_g = jax.random.split(hp.key)
    acc_p0 = ot._init_params(k_a, hp.acc_init_scale)
    gyr_p0 = ot._init_params(k_g, hp.gyr_init_scale)
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
        "what": "adaptive loop only (init_epochs = 0); scan: jaxcal.online_thesis._run_sequences; "
                "loop: Python for over sequences of one jitted step (same calibrate/loss/_adam_steps functions)",
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
    key = jax.random.PRNGKey(1)
    hps = [ot.default_hparams(key, gyr_lr=float(g), acc_lr=float(a)) for g in gyr_lrs for a in acc_lrs]
    stacked = ot.stack_hparams(hps)

    def one(data, hp):
        r = ot.run_dataset(data, hp)
        ea, eg = ot.test_set_errors((r.acc_params, r.gyr_params), data)
        return jnp.stack([ea.mean(), eg.mean(), r.e_a[-1], r.e_g[-1]])

    c_one, one_c = _compile(jax.jit(one), d, hps[0])
    c_vm, vm_c = _compile(jax.jit(jax.vmap(one, in_axes=(None, 0))), d, stacked)
    seq_out = jax.block_until_ready(jnp.stack([one_c(d, hp) for hp in hps]))
    vm_out = jax.block_until_ready(vm_c(d, stacked))
    t_seq, all_seq = _median_time(lambda: [one_c(d, hp) for hp in hps], reps)
    t_vm, all_vm = _median_time(lambda: vm_c(d, stacked), reps)
    finite = np.isfinite(np.asarray(seq_out)) & np.isfinite(np.asarray(vm_out))
    return {
        "dataset": f"Dataset 2, {cfg.n_train} training / {cfg.n_val} validation sequences"
                   + (" (small, --quick)" if quick else " (default config)"),
        "configurations": "8 gyr_lr (1e-5..1e-3, log) x 8 acc_lr (1e-5..1e-4, log), other hyperparameters default "
                          f"(init_epochs {int(hps[0].init_epochs)}); whole algorithm + test-set errors per configuration",
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


# ----------------------------------------------------------------------------- report

NOT_MEASURED = {
    "jax_vs_torch": "torch is not installed here (the optional `bench` extra with a plain PyTorch online-thesis "
                    "does not exist yet); no number until it is written and run",
    "nn_epoch_bound_fraction": "the roofline bound of one offline NN epoch is not computed yet (comes in a later version)",
    "reproduce_minutes": "needs a timed `make run-full` on a fresh clone, which this benchmark does not run (comes later)",
}


def _markdown(res: dict) -> str:
    m = res["machine"]
    rt, sl, sg, sh = (res[k] for k in ("online_realtime_factor", "scan_vs_loop", "sweep_gain_64", "sharded_equals_unsharded"))
    f = lambda x: f"{x:.3g}"  # noqa: E731
    lines = [
        "# Performance record" + (" (quick form)" if res["quick"] else ""),
        "",
        f"Written by `python benchmarks/run.py{' --quick' if res['quick'] else ''}` in {res['wall_s']:.0f} s. "
        f"Every run time is the median of {res['repetitions']} repetitions ({sg['repetitions']} for `sweep_gain_64`) "
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
        f"| `online_realtime_factor` ({rt['kind']}) | **{rt['value']:.0f}** s of data / s | {rt['data_s']:.0f} s of "
        f"100 Hz data in {rt['diag']['run_s'] * 1e3:.1f} ms | {rt['diag']['compile_s']:.2f} s |",
        f"| `online_realtime_factor` (affine, beside it) | {rt['affine']['realtime_factor']:.0f} | "
        f"{rt['affine']['run_s'] * 1e3:.1f} ms | {rt['affine']['compile_s']:.2f} s |",
        f"| `scan_vs_loop` | **{sl['value']:.2f}x** (loop / scan) | scan {f(sl['scan']['run_s'])} s, loop "
        f"{f(sl['loop']['run_s'])} s ({sl['loop']['per_step_us']:.0f} us per step) | scan {sl['scan']['compile_s']:.2f} s, "
        f"step {sl['loop']['compile_s']:.2f} s |",
        f"| `sweep_gain_64` | **{sg['value']:.2f}x** (sequential / vmapped) | sequential {f(sg['sequential']['run_s'])} s, "
        f"vmapped {f(sg['vmapped']['run_s'])} s | one {sg['sequential']['compile_s']:.2f} s, vmapped "
        f"{sg['vmapped']['compile_s']:.2f} s |",
        f"| `sharded_equals_unsharded` | **{str(sh['value']).lower()}** | max abs diff {sh['max_abs_diff']:.3g}, "
        f"max rel diff {sh['max_rel_diff']:.3g} (devices {sh['n_devices'][0]} vs {sh['n_devices'][1]}) | |",
        "",
        "## Notes",
        "",
        f"- `online_realtime_factor`: {rt['dataset']}; {rt['function']}. Goal in the record: >= 1000.",
        f"- `scan_vs_loop`: {sl['dataset']}; {sl['what']}. Same final parameters: "
        f"**{str(sl['same_final_params']).lower()}** (rtol {sl['tolerance']['rtol']}, atol {sl['tolerance']['atol']}; "
        f"max abs difference {sl['max_abs_param_diff']:.3g} on parameters up to {sl['max_abs_param']:.3g}).",
        f"- `sweep_gain_64`: {sg['dataset']}; {sg['configurations']}. Vmapped vs sequential metrics: max abs "
        f"difference {sg['max_abs_metric_diff_vmapped_vs_sequential']} ({sg['nonfinite_metrics']} non-finite).",
        f"- `sharded_equals_unsharded`: {sh['what']}; rtol {sh['tolerance']['rtol']}.",
        "",
        "## Not measured in this version",
        "",
        *[f"- `{k}`: {v}" for k, v in res["not_measured"].items()],
        "",
    ]
    return "\n".join(lines)


def main(quick: bool, json_out: Path) -> dict:
    # Real compile times: the persistent cache would serve them from disk.
    jax.config.update("jax_enable_compilation_cache", False)
    t0 = time.perf_counter()
    reps = 3 if quick else 7
    res: dict = {"quick": quick, "machine": machine(), "repetitions": reps}
    for name, fn in (("online_realtime_factor", lambda: online_realtime_factor(reps)),
                     ("scan_vs_loop", lambda: scan_vs_loop(reps)),
                     ("sweep_gain_64", lambda: sweep_gain_64(3 if quick else 1, quick)),
                     ("sharded_equals_unsharded", sharded_equals_unsharded)):
        t = time.perf_counter()
        res[name] = fn()
        print(f"{name}: {res[name]['value']} ({time.perf_counter() - t:.1f} s)", flush=True)
    res["not_measured"] = NOT_MEASURED
    res["load_average_at_end"] = list(os.getloadavg())
    res["wall_s"] = time.perf_counter() - t0
    json_out.parent.mkdir(parents=True, exist_ok=True)
    json_out.write_text(json.dumps(res, indent=1) + "\n")
    (RESULTS / "performance.md").write_text(_markdown(res))
    print(f"wrote {json_out} and {RESULTS / 'performance.md'} in {res['wall_s']:.0f} s")
    return res


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small Dataset 2 for the 64-configuration sweep, 3 repetitions")
    ap.add_argument("--json", type=Path, default=RESULTS / "performance.json", help="JSON output path")
    a = ap.parse_args()
    main(a.quick, a.json)
