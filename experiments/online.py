"""Chapter 4 reproduction: the thesis's online adaptive calibration on Dataset 2.

Regenerates Fig. 4.2-4.4 (dataset), 4.11-4.12 (after initial training), 4.13-4.14 (validation
errors e_g, e_a at every iteration), 4.15-4.18 (after calibration) and Tables 4.1-4.2 over several
seeds (one vmapped jit: each seed draws its own Dataset 2 and its own initial weights), beside the
thesis's numbers, spec conversion and the quantisation floor. Writes ``results/online.md``,
``results/online.json`` and ``results/figures/online_*.png`` (quick form: ``online_quick.*``). jaxcal's own
streaming calibration beyond the thesis is ``experiments.online_beyond`` (``results/online_beyond.md``).

Usage: ``python -m experiments.online [--quick]``.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import platform
import time

import jax
import jax.numpy as jnp
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from jaxcal import online_thesis as ot  # noqa: E402
from jaxcal.metrics import euclidean_error  # noqa: E402
from jaxcal.sensor import diag_inverse, spec_convert  # noqa: E402
from jaxcal.simulate import Dataset2Config, dataset2  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
FIGS = RESULTS / "figures"

# Published values (thesis Tables 4.1, 4.2 and section 4.6.1): inputs to compare against, not results.
THESIS = {
    "acc_mean_mg": 9.283,
    "acc_std_mg": 7.133,
    "gyr_mean_mrads": 13.62,
    "gyr_std_mrads": 19.55,
    "val_e_a_end_mg": 10.0,  # "converges to an error of about 10 mg"
    "val_e_g_end_mrads": 6.0,  # "an error of about 6 mrad/s after the last evaluation"
}


def _stack(trees):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def _errors(data, acc_p, gyr_p):
    """Per-sample test errors (eq. 3.8) of a calibration: (acc in g, gyro in rad/s)."""
    return ot.test_set_errors((acc_p, gyr_p), data)


def _run_seeds(datas, hps):
    """One jit: vmap the whole algorithm (initial training + scan) over (dataset, hparams) pairs."""

    def one(d, hp):
        r = ot.run_dataset(d, hp)
        ea, eg = _errors(d, r.acc_params, r.gyr_params)
        ea0, eg0 = _errors(d, r.acc_params0, r.gyr_params0)
        return r, (ea, eg, ea0, eg0)

    in_axes = (jax.tree.map(lambda _: 0, datas)._replace(dt=None), 0)
    return jax.jit(jax.vmap(one, in_axes=in_axes))(datas, hps)


def _stats(x, scale):
    x = np.asarray(x) * scale
    return {"mean": float(x.mean()), "std": float(x.std())}


def _across(per_seed):
    """mean +- std across seeds of per-seed numbers."""
    a = np.asarray(per_seed)
    return float(a.mean()), float(a.std())


def _fmt(m, s):
    return f"{m:.3f} ± {s:.3f}"


# ----------------------------------------------------------------------------- figures


def _sphere(ax):
    u, v = np.mgrid[0 : 2 * np.pi : 40j, 0 : np.pi : 20j]
    ax.plot_wireframe(np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v), color="0.85", lw=0.3)


def fig_dataset(data, path):
    """Fig. 4.2: training accelerometer samples on the unit sphere (static blue, rotating red)."""
    f = np.asarray(data.train.acc_true)
    fig = plt.figure(figsize=(6, 5.5))
    ax = fig.add_subplot(projection="3d")
    mov = f[:, 1:-1].reshape(-1, 3)
    st = np.concatenate([f[:, 0], f[:, -1]])
    ax.scatter(*mov[::3].T, s=0.5, c="tab:red", label="rotating samples")
    ax.scatter(*st.T, s=4, c="tab:blue", label="static start/end samples")
    ax.set_xlabel("$a_x$ [g]")
    ax.set_ylabel("$a_y$ [g]")
    ax.set_zlabel("$a_z$ [g]")
    ax.set_title(f"Dataset 2 training set: {f.shape[0]} sequences of {f.shape[1]} samples")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def fig_rates(data, path_train, path_test):
    """Fig. 4.3 (training rate profiles, eq. 4.4) and Fig. 4.4 (test rate, eq. 4.7)."""
    w = np.asarray(data.train.gyr_true)
    t = np.arange(w.shape[1]) * data.dt
    fig, ax = plt.subplots(figsize=(6, 4))
    for m in range(20):
        ax.plot(t, w[m, :, 0], lw=0.8)
    ax.set_xlabel("time in sequence [s]")
    ax.set_ylabel("true rate $\\varphi_{gt,x}$ [rad/s]")
    ax.set_title("Training rate profiles, x axis, first 20 sequences (eq. 4.4)")
    fig.tight_layout()
    fig.savefig(path_train, dpi=120)
    plt.close(fig)

    wt = np.asarray(data.test_gyr.true)
    fig, ax = plt.subplots(figsize=(6, 4))
    for k, lab in enumerate("xyz"):
        ax.plot(wt[:, k], lw=2.5 - 0.7 * k, label=f"$\\varphi_{{gt,{lab}}}$")
    ax.set_xlabel("test sample n")
    ax.set_ylabel("true rate [rad/s]")
    ax.set_title("Gyroscope test set: 0.35 sin(t) on every axis (eq. 4.7)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path_test, dpi=120)
    plt.close(fig)


def fig_calibrated(data, acc_cal, gyr_cal, e_acc, e_gyr, title, path, hist=True):
    """Fig. 4.11/4.12 (after initial training) or 4.15-4.18 (after calibration)."""
    ncol = 4 if hist else 2
    fig = plt.figure(figsize=(4.4 * ncol, 4.2))
    ax = fig.add_subplot(1, ncol, 1, projection="3d")
    _sphere(ax)
    tr = np.asarray(data.test_acc.true)
    ca = np.asarray(acc_cal)
    ax.scatter(*tr.T, s=12, facecolors="none", edgecolors="tab:red", lw=0.6, label="ground truth")
    ax.scatter(*ca.T, s=2, c="tab:blue", label="calibrated")
    ax.set_xlabel("$a_x$ [g]")
    ax.set_ylabel("$a_y$ [g]")
    ax.set_zlabel("$a_z$ [g]")
    ax.set_title("Accelerometer test set")
    ax.legend(fontsize=7, loc="upper left")
    ax = fig.add_subplot(1, ncol, 2)
    wt = np.asarray(data.test_gyr.true)
    gc = np.asarray(gyr_cal)
    ax.plot(wt[:, 0], c="tab:blue", lw=2, label="ground truth, x")
    ax.plot(gc[:, 0], c="tab:red", lw=1, label="calibrated, x")
    ax.plot(gc[:, 1], c="tab:orange", lw=0.6, label="calibrated, y")
    ax.plot(gc[:, 2], c="tab:green", lw=0.6, label="calibrated, z")
    ax.set_xlabel("test sample n")
    ax.set_ylabel("angular rate [rad/s]")
    ax.set_title("Gyroscope test set")
    ax.legend(fontsize=7)
    if hist:
        ax = fig.add_subplot(1, ncol, 3)
        ea = np.asarray(e_acc) * 1e3
        ax.hist(ea, bins=40, color="tab:blue")
        ax.axvline(ea.mean(), c="k", ls="--", label=f"mean {ea.mean():.2f} mg")
        ax.set_xlabel("error $e_{a,n}$ [mg]")
        ax.set_ylabel("test samples")
        ax.set_title("Accelerometer error (Fig. 4.16)")
        ax.legend(fontsize=8)
        ax = fig.add_subplot(1, ncol, 4)
        eg = np.asarray(e_gyr) * 1e3
        ax.hist(eg, bins=40, color="tab:red")
        ax.axvline(eg.mean(), c="k", ls="--", label=f"mean {eg.mean():.2f} mrad/s")
        ax.set_xlabel("error $e_{g,n}$ [mrad/s]")
        ax.set_ylabel("test samples")
        ax.set_title("Gyroscope error (Fig. 4.18)")
        ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def fig_convergence(e_g, e_a, path):
    """Fig. 4.13 (e_g, e_a vs iteration, every seed) and Fig. 4.14 (both on one axis)."""
    e_g = np.asarray(e_g) * 1e3
    e_a = np.asarray(e_a) * 1e3
    it = np.arange(e_g.shape[1])
    fig, axs = plt.subplots(1, 3, figsize=(15, 4))
    for s in range(e_g.shape[0]):
        axs[0].plot(it, e_g[s], lw=0.6, alpha=0.6)
        axs[1].plot(it, e_a[s], lw=0.6, alpha=0.6)
    axs[0].plot(it, e_g.mean(0), c="k", lw=1.5, label=f"mean of {e_g.shape[0]} seeds")
    axs[1].plot(it, e_a.mean(0), c="k", lw=1.5, label=f"mean of {e_a.shape[0]} seeds")
    axs[0].set_ylabel("$e_{g,i}$ [mrad/s]")
    axs[1].set_ylabel("$e_{a,i}$ [mg]")
    axs[0].set_title("Gyroscope, validation set (Fig. 4.13 left)")
    axs[1].set_title("Accelerometer, validation set (Fig. 4.13 right)")
    axs[2].plot(it, e_g.mean(0), c="tab:red", label="$e_g$ [mrad/s]")
    axs[2].plot(it, e_a.mean(0), c="tab:blue", label="$e_a$ [mg]")
    axs[2].set_ylabel("error [mrad/s or mg]")
    axs[2].set_title("Convergence of both sensors (Fig. 4.14)")
    for ax in axs:
        ax.set_xlabel("iteration i (0 = after initial training)")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ----------------------------------------------------------------------------- main


def _time_one_pass(data, hp):
    """Compile (persistent cache off) and run one training; returns compile s, run s, loop-only s.

    Loop-only: the same compiled function with ``init_epochs = 0`` (a traced hyperparameter), i.e.
    the 500 sequence updates and 501 validation evaluations without the initial training.
    """
    cache_was = jax.config.jax_enable_compilation_cache
    jax.config.update("jax_enable_compilation_cache", False)
    try:
        t0 = time.perf_counter()
        compiled = ot.run_online_thesis.lower(data, hp).compile()
        t1 = time.perf_counter()
    finally:
        jax.config.update("jax_enable_compilation_cache", cache_was)
    jax.block_until_ready(compiled(data, hp))  # first call: allocation etc.

    def best_of(h, n=2):
        ts = []
        for _ in range(n):
            t = time.perf_counter()
            jax.block_until_ready(compiled(data, h))
            ts.append(time.perf_counter() - t)
        return min(ts)

    return t1 - t0, best_of(hp), best_of(hp._replace(init_epochs=jnp.asarray(0)))


def _sweep(data, hp_base):
    """Sensitivity of the errors to the online learning rates and NN_a's initial scale (one vmapped jit)."""
    grid = [(float(hp_base.gyr_lr), a) for a in (1e-5, 3e-5, 1e-4, 3e-4)]
    grid += [(g, float(hp_base.acc_lr)) for g in (3e-5, 3e-4)]
    grid = [(g, a, float(hp_base.acc_init_scale)) for g, a in grid]
    grid += [(float(hp_base.gyr_lr), float(hp_base.acc_lr), 1.0)]
    hps = ot.stack_hparams(
        [hp_base._replace(gyr_lr=jnp.asarray(g), acc_lr=jnp.asarray(a), acc_init_scale=jnp.asarray(c)) for g, a, c in grid]
    )

    def one(hp):
        r = ot.run_dataset(data, hp)
        ea, eg = _errors(data, r.acc_params, r.gyr_params)
        return ea.mean(), eg.mean(), r.e_a[-50:].mean(), r.e_g[-50:].mean()

    ea, eg, va, vg = (np.asarray(x) for x in jax.jit(jax.vmap(one))(hps))
    return [
        {"gyr_lr": g, "acc_lr": a, "acc_init_scale": c, "test_acc_mg": float(ea[i] * 1e3), "test_gyr_mrads": float(eg[i] * 1e3),
         "val_e_a_last50_mg": float(va[i] * 1e3), "val_e_g_last50_mrads": float(vg[i] * 1e3)}
        for i, (g, a, c) in enumerate(grid)
    ]


def main(quick: bool) -> None:
    FIGS.mkdir(parents=True, exist_ok=True)
    pre = "online_quick" if quick else "online"  # make run's quick form never overwrites the full results
    n_seeds = 2 if quick else 5
    config = Dataset2Config()  # 500 training sequences of 101 samples: the thesis's dataset, both forms
    hp_base = ot.default_hparams(jax.random.PRNGKey(0))
    seeds = [100 + s for s in range(n_seeds)]  # held out: hyperparameters were tuned on seeds 0-3
    datas = [dataset2(jax.random.PRNGKey(s), config) for s in seeds]
    hps = [hp_base._replace(key=jax.random.fold_in(jax.random.PRNGKey(1000), s)) for s in seeds]

    t0 = time.perf_counter()
    res, (ea, eg, ea0, eg0) = _run_seeds(_stack(datas)._replace(dt=datas[0].dt), ot.stack_hparams(hps))
    jax.block_until_ready(ea)
    t_seeds = time.perf_counter() - t0
    compile_s, run_s, loop_s = _time_one_pass(datas[0], hps[0])
    sweep = None if quick else _sweep(datas[0], hps[0])
    data_seconds = config.n_train * config.n_samples / config.fs

    # Baselines per seed: spec conversion and the quantisation floor (true parameters).
    spec_a, spec_g, q_a, q_g = [], [], [], []
    for d in datas:
        spec_a.append(euclidean_error(d.test_acc.true, spec_convert(d.test_acc.raw, d.acc_spec)))
        spec_g.append(euclidean_error(d.test_gyr.true, spec_convert(d.test_gyr.raw, d.gyr_spec)))
        q_a.append(euclidean_error(d.test_acc.true, diag_inverse(d.acc_true_model, d.test_acc.raw)))
        q_g.append(euclidean_error(d.test_gyr.true, diag_inverse(d.gyr_true_model, d.test_gyr.raw)))

    def rows(per_seed_err, scale):
        means = [float(np.mean(e)) * scale for e in per_seed_err]
        stds = [float(np.std(e)) * scale for e in per_seed_err]
        return {"mean": _across(means), "std": _across(stds), "per_seed_mean": means, "per_seed_std": stds}

    inside = np.asarray(jnp.linalg.norm(datas[0].test_gyr.true, axis=-1) < 0.3)
    table = {
        "acc_mg": {
            "online_thesis": rows(list(ea), 1e3),
            "after_initial_training": rows(list(ea0), 1e3),
            "spec_conversion": rows(spec_a, 1e3),
            "quantisation_floor": rows(q_a, 1e3),
        },
        "gyr_mrads": {
            "online_thesis": rows(list(eg), 1e3),
            "after_initial_training": rows(list(eg0), 1e3),
            "spec_conversion": rows(spec_g, 1e3),
            "quantisation_floor": rows(q_g, 1e3),
            "online_thesis_inside_training_range": rows([np.asarray(e)[inside] for e in eg], 1e3),
            "spec_conversion_inside_training_range": rows([np.asarray(e)[inside] for e in spec_g], 1e3),
        },
    }
    e_g = np.asarray(res.e_g)
    e_a = np.asarray(res.e_a)
    val = {
        "e_g_initial_mrads": _across(e_g[:, 0] * 1e3),
        "e_g_final_mrads": _across(e_g[:, -1] * 1e3),
        "e_g_last50_mrads": _across(e_g[:, -50:].mean(1) * 1e3),
        "e_a_initial_mg": _across(e_a[:, 0] * 1e3),
        "e_a_final_mg": _across(e_a[:, -1] * 1e3),
        "e_a_last50_mg": _across(e_a[:, -50:].mean(1) * 1e3),
    }

    # Figures (first seed for the single-run figures).
    d0 = datas[0]
    take = lambda tree, i: jax.tree.map(lambda x: x[i], tree)  # noqa: E731
    p_a, p_g = take(res.acc_params, 0), take(res.gyr_params, 0)
    p_a0, p_g0 = take(res.acc_params0, 0), take(res.gyr_params0, 0)
    fig_dataset(d0, FIGS / f"{pre}_dataset.png")
    fig_rates(d0, FIGS / f"{pre}_train_rates.png", FIGS / f"{pre}_test_rates.png")
    fig_calibrated(
        d0,
        ot.calibrate_acc(p_a0, d0.test_acc.raw, d0.acc_spec),
        ot.calibrate_gyr(p_g0, d0.test_gyr.raw, d0.gyr_spec),
        ea0[0], eg0[0],
        f"After initial training, seed {seeds[0]} (Fig. 4.11, 4.12)",
        FIGS / f"{pre}_after_initial.png",
        hist=False,
    )
    fig_convergence(res.e_g, res.e_a, FIGS / f"{pre}_convergence.png")
    fig_calibrated(
        d0,
        ot.calibrate_acc(p_a, d0.test_acc.raw, d0.acc_spec),
        ot.calibrate_gyr(p_g, d0.test_gyr.raw, d0.gyr_spec),
        ea[0], eg[0],
        f"After online calibration, seed {seeds[0]} (Fig. 4.15-4.18)",
        FIGS / f"{pre}_after_calibration.png",
    )

    hp_json = {k: (None if k == "key" else float(v)) for k, v in hp_base._asdict().items()}
    hp_json["key"] = "fold_in(PRNGKey(1000), seed); dataset: PRNGKey(seed); seeds 100+ (tuning used 0-3)"
    out = {
        "quick": quick,
        "seeds": seeds,
        "dataset": config._asdict(),
        "hparams": hp_json,
        "network": "3-5-10-5-3 leaky ReLU 0.1 (Fig. 4.5), inputs eq. 3.7 with +-2 g / +-250 deg/s",
        "convention": "physical: a_phi,n+1 = R_n^T a_c,n and a_phi,N = R_tot^T a_c,1",
        "thesis": THESIS,
        "test_tables": table,
        "validation": val,
        "sensitivity_first_seed": sweep,
        "e_g_mean_curve_mrads": (e_g.mean(0) * 1e3).tolist(),
        "e_a_mean_curve_mg": (e_a.mean(0) * 1e3).tolist(),
        "timing": {
            "machine": f"{platform.machine()} CPU, {jax.devices()[0].platform}, jax {jax.__version__}",
            "one_pass_compile_s": compile_s,
            "one_pass_run_s": run_s,
            "data_seconds_per_pass": data_seconds,
            "real_time_factor": data_seconds / run_s,
            "loop_only_run_s": loop_s,
            "real_time_factor_loop_only": data_seconds / loop_s,
            "all_seeds_vmapped_incl_compile_s": t_seeds,
        },
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{pre}.json").write_text(json.dumps(out, indent=1))
    md = _markdown(out)
    (RESULTS / f"{pre}.md").write_text(md)


def _sweep_md(sweep, hp) -> list[str]:
    if not sweep:
        return []
    out = [
        "## Sensitivity to the online learning rates and NN_a's initial scale (seed 100, one vmapped jit)",
        "",
        "| gyr_lr | acc_lr | acc_init_scale | test acc mean [mg] | test gyr mean [mrad/s] | val e_a, last 50 [mg] | val e_g, last 50 [mrad/s] |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in sweep:
        used = all(math.isclose(r[k], hp[k], rel_tol=1e-5) for k in ("gyr_lr", "acc_lr", "acc_init_scale"))
        mark = " (used)" if used else ""
        out.append(
            f"| {r['gyr_lr']:g} | {r['acc_lr']:g} | {r['acc_init_scale']:g}{mark} | {r['test_acc_mg']:.2f} | {r['test_gyr_mrads']:.2f} | "
            f"{r['val_e_a_last50_mg']:.2f} | {r['val_e_g_last50_mrads']:.2f} |"
        )
    return out + [""]


def _markdown(o) -> str:
    t = o["test_tables"]
    a, g = t["acc_mg"], t["gyr_mrads"]
    th = o["thesis"]
    n = len(o["seeds"])
    hp = o["hparams"]
    tim = o["timing"]
    v = o["validation"]
    pre = "online_quick" if o["quick"] else "online"

    def row(name, r):
        return f"| {name} | {_fmt(*r['mean'])} | {_fmt(*r['std'])} |"

    acc_better = a["online_thesis"]["mean"][0] < th["acc_mean_mg"]
    gyr_better = g["online_thesis"]["mean"][0] < th["gyr_mean_mrads"]
    lines = [
        "# Online adaptive calibration (thesis chapter 4), reproduced",
        "",
        f"Written by `python -m experiments.online{' --quick' if o['quick'] else ''}`. Dataset 2 "
        f"({o['dataset']['n_train']} training sequences of {o['dataset']['n_samples']} samples at "
        f"{o['dataset']['fs']:.0f} Hz, 100 validation sequences, 500 + 500 test samples), {n} seeds: "
        "seed s (100, 101, ...) draws its own dataset (true scales within ±3 % of spec, biases up to "
        f"{o['dataset']['acc_bias_max']:.0f} / {o['dataset']['gyr_bias_max']:.0f} LSB) and its own initial "
        "weights. All seeds run as one `jax.vmap` of one `jit` (initial training + one `lax.scan` over the "
        "sequences, with e_g and e_a on the validation set at every iteration).",
        "",
        "Algorithm as published (sections 4.3-4.5): two 3-5-10-5-3 leaky-ReLU(0.1) networks on eq. 3.7 "
        "inputs; initial training on every tenth training sequence with spec-converted targets (eq. 4.8); "
        "then per sequence a gyroscope update (eq. 4.9-4.10, NN_a fixed) and an accelerometer update "
        f"(eq. 4.11-4.13, NN_phi fixed, a_phi,N a fixed target, w = {hp['w']:.2f}).",
        "",
        "Choices the thesis does not state (ours): initial training "
        f"{hp['init_epochs']:.0f} full-batch Adam epochs at lr {hp['init_lr']:g}; per sequence "
        f"{hp['gyr_steps']:.0f} Adam step(s) for NN_phi at lr {hp['gyr_lr']:g} and {hp['acc_steps']:.0f} for "
        f"NN_a at lr {hp['acc_lr']:g}, Adam moments carried from sequence to sequence; flax default "
        f"(LeCun-normal) initial weights scaled by {hp['acc_init_scale']:g} for NN_a and "
        f"{hp['gyr_init_scale']:g} for NN_phi. These were picked by vmapped sweeps on seeds 0-3 during "
        "development (online learning rates 1e-5..1e-3, 1/5/20 steps per sequence, initial-training "
        "learning rate and epochs, initial scale 0.3/1/3); every number here is on held-out seeds "
        "100 and up, and the full run (`python -m experiments.online`) re-measures the sensitivity below.",
        "",
        "**Rotation convention.** Eq. 4.9 and 4.12 as printed rotate with R_n (a_phi,n+1 = R_n a_c,n). "
        "jaxcal simulates and calibrates with the physical convention of CONVENTIONS.md, "
        "a_phi,n+1 = R_n^T a_c,n and a_phi,N = R_tot^T a_c,1 (R_tot = R_1 ... R_{N-1}); with the true "
        "calibration this loss is at float noise, with the printed sign it is not "
        "(`tests/test_online_thesis.py`). On data simulated with the printed eq. 4.5 the printed loss is "
        "the consistent one: the printed world is the physical one with the gyroscope's sign flipped, so "
        "the two are the same problem and the choice should not change the numbers, only which data "
        "the method fits.",
        "",
        "## Table 4.1 - accelerometer, test set (500 static orientations)",
        "",
        f"Mean ± std across {n} seeds of each seed's test mean and test standard deviation of eq. 3.8 errors.",
        "",
        "| method | mean error [mg] | error std [mg] |",
        "|---|---|---|",
        f"| thesis (one run) | {th['acc_mean_mg']:.3f} | {th['acc_std_mg']:.3f} |",
        row("jaxcal online-thesis", a["online_thesis"]),
        row("after initial training only", a["after_initial_training"]),
        row("spec conversion (eq. 4.8)", a["spec_conversion"]),
        row("true parameters (quantisation floor)", a["quantisation_floor"]),
        "",
        "## Table 4.2 - gyroscope, test set (0.35 sin t on every axis, 500 samples)",
        "",
        "| method | mean error [mrad/s] | error std [mrad/s] |",
        "|---|---|---|",
        f"| thesis (one run) | {th['gyr_mean_mrads']:.2f} | {th['gyr_std_mrads']:.2f} |",
        row("jaxcal online-thesis", g["online_thesis"]),
        row("after initial training only", g["after_initial_training"]),
        row("spec conversion (eq. 4.8)", g["spec_conversion"]),
        row("true parameters (quantisation floor)", g["quantisation_floor"]),
        row("online-thesis, samples with \\|w\\| < 0.3 rad/s only", g["online_thesis_inside_training_range"]),
        row("spec conversion, samples with \\|w\\| < 0.3 rad/s only", g["spec_conversion_inside_training_range"]),
        "",
        "## Validation errors during calibration (Fig. 4.13, 4.14)",
        "",
        "| | after initial training (i = 0) | last iteration | mean of last 50 | thesis, end |",
        "|---|---|---|---|---|",
        f"| e_g [mrad/s] | {_fmt(*v['e_g_initial_mrads'])} | {_fmt(*v['e_g_final_mrads'])} | "
        f"{_fmt(*v['e_g_last50_mrads'])} | about {th['val_e_g_end_mrads']:.0f} |",
        f"| e_a [mg] | {_fmt(*v['e_a_initial_mg'])} | {_fmt(*v['e_a_final_mg'])} | "
        f"{_fmt(*v['e_a_last50_mg'])} | about {th['val_e_a_end_mg']:.0f} |",
        "",
        "## Reading the numbers",
        "",
        f"- Accelerometer: jaxcal's reproduction is {'better' if acc_better else 'worse'} than the thesis's "
        f"single run on the mean ({a['online_thesis']['mean'][0]:.2f} vs {th['acc_mean_mg']:.2f} mg), the "
        f"same order; it is {a['spec_conversion']['mean'][0] / a['online_thesis']['mean'][0]:.1f}x better than "
        f"spec conversion and {a['online_thesis']['mean'][0] / a['quantisation_floor']['mean'][0]:.0f}x above "
        "the quantisation floor that the true parameters reach. The error distribution has a long tail "
        f"(test std {a['online_thesis']['std'][0]:.2f} mg against a mean of {a['online_thesis']['mean'][0]:.2f}; "
        "histogram): the accelerometer update sees one sample per sequence, and an Adam step on it moves "
        "the whole network, so orientations far from recent sequences are left worse. In the sensitivity "
        "table the NN_a initial scale that the development seeds favoured (0.3) is not better on seed 100: "
        "the difference between the two scales is within the seed-to-seed spread.",
        f"- Gyroscope: jaxcal is {'better' if gyr_better else 'worse'} than the thesis on the test mean "
        f"({g['online_thesis']['mean'][0]:.2f} vs {th['gyr_mean_mrads']:.2f} mrad/s; spec conversion "
        f"{g['spec_conversion']['mean'][0]:.2f}). The test error is dominated by the stretches where the "
        "test rate has 0.35 rad/s on all three axes at once (|w| up to 0.61 rad/s), a corner of rate space "
        "that the training sequences (eq. 4.4, each axis independently up to ±0.35 rad/s) hardly visit, "
        "so the small network extrapolates there (the calibrated rate flattens near the peaks in the "
        "figure). On the test samples with |w| < 0.3 rad/s the error is "
        f"{g['online_thesis_inside_training_range']['mean'][0]:.2f} mrad/s "
        f"(spec conversion {g['spec_conversion_inside_training_range']['mean'][0]:.2f}), close to the "
        f"validation e_g ({v['e_g_last50_mrads'][0]:.2f}). The thesis shows the same pattern (Fig. 4.17: "
        "samples 80-160, i.e. the first peak, are worse; its std exceeds its mean); our extrapolation "
        "error at the peaks is larger than in the thesis's run.",
        "- Differences to the thesis come from: unstated hyperparameters (epochs, learning rates, "
        "steps per sequence: ours above), initialisation and seeds (the thesis reports one run), our "
        "simulated biases and scale errors (the thesis does not state its values), and the rotation "
        "sign (physical here, see above).",
        "",
        *_sweep_md(o["sensitivity_first_seed"], hp),
        "## Timing",
        "",
        f"Machine: {tim['machine']} (shared, so times vary). One pass of online-thesis (initial training + "
        f"{o['dataset']['n_train']} sequences + {o['dataset']['n_train'] + 1} validation evaluations): "
        f"compile {tim['one_pass_compile_s']:.1f} s (persistent cache off), run {tim['one_pass_run_s']:.2f} s, "
        f"of which the adaptive loop alone (init_epochs = 0) takes {tim['loop_only_run_s']:.2f} s. "
        f"A pass processes {tim['data_seconds_per_pass']:.0f} s of 100 Hz data: a real-time factor of "
        f"{tim['real_time_factor']:.0f} with the initial training, {tim['real_time_factor_loop_only']:.0f} for "
        "the adaptive loop alone (seconds of data per second of compute; the loop includes the per-iteration "
        "validation). "
        f"All {n} seeds, vmapped, including compilation: {tim['all_seeds_vmapped_incl_compile_s']:.1f} s.",
        "",
        "## Figures",
        "",
        f"- `figures/{pre}_dataset.png` - Fig. 4.2: training accelerometer samples (static ends blue, rotating red).",
        f"- `figures/{pre}_train_rates.png` - Fig. 4.3: training rate profiles (eq. 4.4).",
        f"- `figures/{pre}_test_rates.png` - Fig. 4.4: gyroscope test rate (eq. 4.7).",
        f"- `figures/{pre}_after_initial.png` - Fig. 4.11, 4.12: test sets after the initial training.",
        f"- `figures/{pre}_convergence.png` - Fig. 4.13, 4.14: e_g and e_a at every iteration, every seed.",
        f"- `figures/{pre}_after_calibration.png` - Fig. 4.15-4.18: test sets and error histograms after calibration.",
        "",
        f"![convergence](figures/{pre}_convergence.png)",
        "",
        f"![after calibration](figures/{pre}_after_calibration.png)",
        "",
        f"Beyond the thesis (jaxcal `online` at the quantisation floor, against the Cramer-Rao bound, under drift): "
        f"[{pre.replace('online', 'online_beyond')}.md]({pre.replace('online', 'online_beyond')}.md), written by "
        f"`python -m experiments.online_beyond{' --quick' if o['quick'] else ''}`.",
    ]
    return "\n".join(lines) + "\n"


def report_only(quick: bool) -> None:
    """Rewrite ``online[_quick].md`` from the JSON the run wrote (``online[_quick].json``), without recomputing anything."""
    pre = "online_quick" if quick else "online"
    (RESULTS / f"{pre}.md").write_text(_markdown(json.loads((RESULTS / f"{pre}.json").read_text())))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 seeds instead of 5")
    parser.add_argument("--report-only", action="store_true",
                        help="only rewrite the .md from the existing JSON results (no recomputation)")
    a = parser.parse_args()
    report_only(a.quick) if a.report_only else main(a.quick)
