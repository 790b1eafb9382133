"""Does a diagnosed model remove each effect on held-out data? (issue 17, "apply for every effect")

For every effect a ``diagnosed`` model carries (:data:`jaxcal.methods.diagnosed.CARRIED`, both
sensors), one sensor truth is drawn (datasheet scale within +-3 %, bias within +-400 / +-300 LSB,
the effect alone at a plausible MEMS size, :data:`EFFECTS`), and two rich-motion recordings are
simulated with it (:func:`jaxcal.diagnose.simulate.motion`, the forward model of
:mod:`jaxcal.diagnose.effects`, white noise 3 mg / 1 mrad/s, LSB rounding):

* training: motion seed ``2 k``, temperature cycle 25 -> 40 -> 25 degC;
* held-out: motion seed ``2 k + 1`` (other rotations, other noise), temperature ramp 25 -> 40 degC.

``jaxcal diagnose`` (diag baseline) runs on the training recording and its model
(:func:`jaxcal.methods.diagnosed.diagnosed_model_state`) is applied to the held-out one. Reported:
RMS (per component, g or rad/s) of calibrated output minus the true specific force / body rate of
the held-out recording, interior samples (1 s dropped at each end, where a time offset's resampling
holds the edge sample), for

* ``before``: the diagnosis's baseline alone (no effect), fitted on the training recording;
* ``linear``: the 12-parameter affine ``linear`` method fitted on the training recording;
* ``after``: the diagnosed model (baseline + the named effects at their refit values);
* ``oracle``: the true sensor model inverted by the same ``apply`` (the noise floor).

Real rigs (``--part real``): the same proof where the reference is imperfect. ``diagnose`` (diag
baseline, as ``jaxcal diagnose --model-out`` runs it) on one recording with a pose reference, its
model applied to a DIFFERENT recording of the same rig and scored against that recording's own mocap
(:func:`jaxcal.eval.mocap.calibrated_rms`: calibrated output minus the pose-derived specific force /
body rate, each sensor in the band ``diagnose`` trusts on the scored recording, valid rows only):
BROAD trial 07 -> 21 and 21 -> 07 (same myon aktos-t IMU type and OptiTrack system, already
synchronised and expressed in the IMU frame by the dataset authors) and TUM-VI room1 first half ->
second half and back. Reported: as recorded (the maker's calibration), ``before`` (the diagnosis's
baseline alone), ``after`` (the diagnosed model), the scored recording's own diagnosis in-sample,
each carried effect dropped from ``after`` in turn (does it help on the other recording?), and the
time offsets and lever arms found on each recording side by side.

``python -m experiments.apply_effects [--quick] [--part sim|real|all]`` writes
``results/apply_effects.json`` and ``.md`` (quick: ``results/apply_effects_quick.*``, 4000 samples
(40 s) per simulated recording and one seed, real pairs BROAD 21 -> 07 and TUM-VI first -> second
half only; full: 20000 samples and three seeds, all four real pairs). One part alone keeps the
other part's results in the files.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal import methods
from jaxcal.diagnose import diagnose_banded
from jaxcal.diagnose import effects as E
from jaxcal.diagnose.simulate import RichConfig, motion
from jaxcal.eval.mocap import half
from jaxcal.methods.diagnosed import apply as diagnosed_apply
from jaxcal.methods.diagnosed import diagnosed_model_state, without_effect
from jaxcal.recording import Recording, load_recording, recording_from_dict

__all__ = ["EFFECTS", "simulate", "oracle_state", "run_effect", "run", "markdown", "REAL_RECORDINGS", "REAL_PAIRS",
           "REAL_PAIRS_QUICK", "run_real", "real_markdown", "main"]

# (sensor, effect) -> parameters at a plausible MEMS size (vocabulary units)
EFFECTS: dict[tuple[str, str], dict[str, np.ndarray]] = {
    ("acc", "lever_arm"): {"r": np.array([0.03, -0.02, 0.025])},
    ("acc", "misalignment"): {"m": np.array([4e-3, -3e-3, 5e-3, 2e-3, -4e-3, 3e-3])},
    ("acc", "scale_nonlinearity"): {"k2": np.array([0.01, -0.008, 0.012])},
    ("acc", "time_offset"): {"tau": np.array([0.012])},
    ("acc", "temperature_bias"): {"k": np.array([1e-3, -8e-4, 6e-4])},
    ("acc", "temperature_scale"): {"k": np.array([8e-4, -6e-4, 5e-4])},
    ("gyr", "g_sensitivity"): {"G": np.array([[2.4e-3, 0, 6e-4], [0, -1.5e-3, 0], [9e-4, 0, 1.8e-3]])},
    ("gyr", "misalignment"): {"m": np.array([4e-3, -3e-3, 5e-3, 2e-3, -4e-3, 3e-3])},
    ("gyr", "scale_nonlinearity"): {"k2": np.array([0.01, -0.008, 0.012])},
    ("gyr", "time_offset"): {"tau": np.array([0.008])},
    ("gyr", "temperature_bias"): {"k": np.array([3e-4, -2e-4, 2.5e-4])},
    ("gyr", "temperature_scale"): {"k": np.array([8e-4, -6e-4, 5e-4])},
}
SENSOR_TRUTH_SEED = 2026
EDGE_S = 1.0  # seconds dropped at each end of the held-out RMS
RESULTS = Path(__file__).resolve().parent.parent / "results"


def _sensor_truth(rng: np.random.Generator, cfg: RichConfig) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per sensor the true scale (LSB per unit) and bias (LSB), as :mod:`jaxcal.diagnose.simulate` draws them."""
    out = {}
    for s, spec, bmax in (("acc", cfg.acc_lsb_per_g, cfg.acc_bias_max_lsb), ("gyr", cfg.gyr_lsb_per_rads, cfg.gyr_bias_max_lsb)):
        out[s] = (spec * (1.0 + rng.uniform(-cfg.scale_tol, cfg.scale_tol, 3)), rng.uniform(-bmax, bmax, 3))
    return out


def simulate(seed: int, cfg: RichConfig, truth: dict[str, tuple[np.ndarray, np.ndarray]], thetas: dict[str, np.ndarray],
             rng: np.random.Generator) -> tuple[Recording, np.ndarray, np.ndarray]:
    """One recording of the given sensor truth on the motion of ``seed``; returns it with the true
    specific force (g) and body rate (rad/s).

    Args:
        seed: motion seed (PRNG key of :func:`jaxcal.diagnose.simulate.motion`).
        cfg: recording settings (length, rate, temperature profile, noise).
        truth: per sensor ``(scale, bias)`` in LSB.
        thetas: per sensor flat effect parameters (:func:`jaxcal.diagnose.effects.theta_from_params`).
        rng: noise generator.
    """
    inp, temp = motion(jax.random.PRNGKey(seed), cfg)
    rec = {"t": np.arange(cfg.n) / cfg.fs, "fs": cfg.fs, "acc_ref": np.asarray(inp.f, np.float64), "gyr_ref": np.asarray(inp.w, np.float64),
           "acc_lsb_per_g": cfg.acc_lsb_per_g, "gyr_lsb_per_rads": cfg.gyr_lsb_per_rads, "acc_bias_lsb": 0.0, "gyr_bias_lsb": 0.0,
           "temp": np.asarray(temp, np.float64)}
    with jax.enable_x64(True):
        inp64 = E.as_jax(inp)
        for s, sig in (("acc", cfg.acc_noise_g), ("gyr", cfg.gyr_noise_rads)):
            u = np.asarray(E.effects_forward(s, jnp.asarray(thetas[s]), inp64))
            sc, b = truth[s]
            rec[s] = np.round(sc * (u + sig * rng.standard_normal(u.shape)) + b)
    return recording_from_dict(rec, "simulated recording"), rec["acc_ref"], rec["gyr_ref"]


def oracle_state(truth: dict[str, tuple[np.ndarray, np.ndarray]], effects: dict[tuple[str, str], dict], t0: float) -> dict:
    """The ``diagnosed`` state of the true sensor (true scale/bias, the true effect, ``T0 = t0``).

    Args:
        truth: per sensor ``(scale, bias)``.
        effects: ``{(sensor, name): params}``.
        t0: the reference temperature (degC) the effect is defined around.
    """
    st: dict = {s: {"S": np.diag(sc), "b": b.copy()} for s, (sc, b) in truth.items()}
    for (s, name), p in effects.items():
        th = E.theta_from_params(s, {name: p})
        v = E.params_from_theta(s, name, th)[E.slot(s, name).param]
        st[s][name] = np.asarray(v, np.float64).reshape(() if name == "time_offset" else np.shape(v))
        if name.startswith("temperature"):
            st[s]["T0"] = np.asarray(t0)
    return st


def _rms(a: np.ndarray, ref: np.ndarray, edge: int) -> float:
    e = (a - ref)[edge:-edge]
    return float(np.sqrt(np.mean(e**2)))


def run_effect(sensor: str, name: str, params: dict, cfg: RichConfig, seed: int) -> dict:
    """Train on one recording, test on another (same sensor truth), for one concealed effect.

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        name: effect name.
        params: the effect's parameters.
        cfg: recording settings (the training one; the held-out one uses a temperature ramp).
        seed: run seed (motion seeds ``2 seed``, ``2 seed + 1``; noise and sensor truth from it).
    """
    rng = np.random.default_rng([SENSOR_TRUTH_SEED, seed])
    truth = _sensor_truth(rng, cfg)
    thetas = {s: E.theta_from_params(s, {name: params} if s == sensor else {}) for s in ("acc", "gyr")}
    train, _, _ = simulate(2 * seed, cfg, truth, thetas, rng)
    test, f, w = simulate(2 * seed + 1, cfg._replace(temp_profile="ramp"), truth, thetas, rng)
    t0 = time.perf_counter()
    preps, results = diagnose_banded(train, "diag")
    t_diag = time.perf_counter() - t0
    after_fit = diagnosed_model_state(preps, results, "diag", train)
    before_fit = diagnosed_model_state(preps, results, "diag", train, baseline_only=True)
    model = methods.CalibrationModel("diagnosed", after_fit.sensors, after_fit.state, after_fit.meta)
    before = methods.CalibrationModel("diagnosed", before_fit.sensors, before_fit.state, before_fit.meta)
    lin = methods.fit("linear", train)
    t_mean = float(np.mean(np.asarray(train.temp)))
    oracle = diagnosed_apply(oracle_state(truth, {(sensor, name): params}, t_mean), {}, test)
    ref = f if sensor == "acc" else w
    edge = int(EDGE_S * cfg.fs)
    key = f"{sensor}_cal"
    named = {s: list(r.selected) for s, r in results.items()}
    est = after_fit.state[sensor].get(name)
    return {
        "sensor": sensor, "effect": name, "seed": seed, "true": {k: np.asarray(v).tolist() for k, v in params.items()},
        "named": named, "carried": after_fit.meta["effects"],
        "estimate": None if est is None else np.asarray(est).tolist(),
        "rms_before": _rms(before.apply(test)[key], ref, edge),
        "rms_linear": _rms(lin.apply(test)[key], ref, edge),
        "rms_after": _rms(model.apply(test)[key], ref, edge),
        "rms_oracle": _rms(oracle[key], ref, edge),
        "other_sensor_after": _rms(model.apply(test)["gyr_cal" if sensor == "acc" else "acc_cal"], w if sensor == "acc" else f, edge),
        "other_sensor_oracle": _rms(oracle["gyr_cal" if sensor == "acc" else "acc_cal"], w if sensor == "acc" else f, edge),
        "diagnose_s": t_diag,
    }


def run(quick: bool) -> dict:
    """Every effect of :data:`EFFECTS` (quick: 4000 samples, one seed; full: 20000, three seeds)."""
    n, seeds = (4000, (1,)) if quick else (20000, (1, 2, 3))
    cfg = RichConfig(n=n)
    t0 = time.perf_counter()
    rows = []
    for (s, name), p in EFFECTS.items():
        for seed in seeds:
            r = run_effect(s, name, p, cfg, seed)
            rows.append(r)
            print(f"{s} {name} seed {seed}: before {r['rms_before']:.3g} linear {r['rms_linear']:.3g} after {r['rms_after']:.3g} "
                  f"oracle {r['rms_oracle']:.3g}; named {r['named']}", flush=True)
    return {"config": {"quick": quick, "n_samples": n, "fs": cfg.fs, "seeds": list(seeds), "baseline": "diag",
                       "acc_noise_g": cfg.acc_noise_g, "gyr_noise_rads": cfg.gyr_noise_rads, "edge_dropped_s": EDGE_S,
                       "train_temperature": "cycle 25-40-25 degC", "heldout_temperature": "ramp 25-40 degC"},
            "rows": rows, "runtime_s": time.perf_counter() - t0}


def markdown(res: dict) -> str:
    """The results table (median over seeds of the per-component RMS against truth)."""
    c = res["config"]
    unit = {"acc": "mg", "gyr": "mrad/s"}
    L = ["# Applying a diagnosed model to held-out data (issue 17)", "",
         f"`python -m experiments.apply_effects{' --quick' if c['quick'] else ''}`: {c['n_samples']} samples at {c['fs']:g} Hz per "
         f"recording, seeds {c['seeds']}, {res['runtime_s']:.0f} s. Each effect alone on one sensor; `diagnose` (diag baseline) on a "
         f"training recording ({c['train_temperature']}), its model applied to a held-out recording of the same sensor "
         f"(other motion and noise, {c['heldout_temperature']}). RMS per component of calibrated output minus the true specific "
         f"force / body rate, {c['edge_dropped_s']:g} s dropped at each end; noise {1e3 * c['acc_noise_g']:g} mg / "
         f"{1e3 * c['gyr_noise_rads']:g} mrad/s per axis. Median over seeds.", "",
         "| sensor | effect | true | named on training | also named | before (baseline) | linear (affine) | after (diagnosed) | oracle (true model) |",
         "|---|---|---|---|---|---|---|---|---|"]
    keys = list(dict.fromkeys((r["sensor"], r["effect"]) for r in res["rows"]))
    for s, name in keys:
        rs = [r for r in res["rows"] if (r["sensor"], r["effect"]) == (s, name)]
        med = {k: 1e3 * float(np.median([r[k] for r in rs])) for k in ("rms_before", "rms_linear", "rms_after", "rms_oracle")}
        hits = sum(name in r["named"].get(s, []) for r in rs)
        true = ", ".join(f"{k}={np.round(np.asarray(v), 4).tolist()}" for k, v in rs[0]["true"].items())
        extra = sorted({f"{ss} {n} ({sum(n in r['named'].get(ss, []) for r in rs)}/{len(rs)})" for r in rs
                        for ss, ns in r["named"].items() for n in ns if (ss, n) != (s, name)})
        L.append(f"| {s} | {name} | {true} | {hits}/{len(rs)} | {', '.join(extra) or '-'} | {med['rms_before']:.3f} {unit[s]} | {med['rms_linear']:.3f} | "
                 f"**{med['rms_after']:.3f}** | {med['rms_oracle']:.3f} |")
    L += ["", "also named: effects the diagnosis named besides the concealed one (the model carries them too). "
          "before: the diagnosis's baseline alone; linear: the 12-parameter `linear` method on the training recording; "
          "after: the diagnosed model (what `jaxcal diagnose --model-out` writes, applied as `jaxcal apply` does); oracle: the true sensor model through the same `apply` "
          "(what perfect estimates would give: the noise floor; below it for a time offset, whose cubic-spline resampling "
          "smooths the white noise a little)."]
    return "\n".join(L) + "\n"


# ----------------------------------------------------------------------------- real rigs

DATA = Path(__file__).resolve().parent.parent / "data"
REAL_RECORDINGS: dict[str, tuple[Path, int | None]] = {  # name -> (recording, half: None whole, 0 first, 1 second)
    "BROAD 07": (DATA / "broad_07_undisturbed_fast_rotation_B" / "07_undisturbed_fast_rotation_B.npz", None),
    "BROAD 21": (DATA / "broad_21_undisturbed_fast_combined" / "21_undisturbed_fast_combined.npz", None),
    "TUM-VI room1 1st half": (DATA / "tumvi_room1_512_16" / "room1.npz", 0),
    "TUM-VI room1 2nd half": (DATA / "tumvi_room1_512_16" / "room1.npz", 1),
}
REAL_PAIRS = (("BROAD 07", "BROAD 21"), ("BROAD 21", "BROAD 07"),
              ("TUM-VI room1 1st half", "TUM-VI room1 2nd half"), ("TUM-VI room1 2nd half", "TUM-VI room1 1st half"))
"""(diagnosed, scored) pairs of the full run; the quick run keeps :data:`REAL_PAIRS_QUICK`."""
REAL_PAIRS_QUICK = (("BROAD 21", "BROAD 07"), ("TUM-VI room1 1st half", "TUM-VI room1 2nd half"))
README_CHECKS = {  # the dataset READMEs' independent checks (cross-correlation, least squares with numpy)
    "BROAD 07": {"tau_s": 0.0042, "r_m": [0.0011, -0.0018, 0.0078]},
    "BROAD 21": {"tau_s": 0.0040, "r_m": [0.0017, -0.0020, 0.0054]},
    "TUM-VI room1 1st half": {"tau_s": 0.0, "r_m": [0.002, -0.014, -0.003]},
    "TUM-VI room1 2nd half": {"tau_s": 0.0, "r_m": [0.002, -0.014, -0.003]},
}


def _load_real(name: str) -> Recording:
    path, k = REAL_RECORDINGS[name]
    rec = load_recording(path)  # as the command line reads it
    return rec if k is None else half(rec, k)


def _identity_outputs(rec: Recording) -> dict[str, np.ndarray]:
    """The recording as recorded (its maker's calibration) in g and rad/s."""
    if rec.acc_unit != "g" or rec.gyr_unit != "rad/s":
        raise ValueError("the real recordings here are in physical units")
    return {"acc_cal": np.asarray(rec.acc, np.float64), "gyr_cal": np.asarray(rec.gyr, np.float64)}


def _diagnose_real(rec: Recording) -> dict:
    """``jaxcal diagnose --model-out`` on one real recording (the CLI's library calls), with its models."""
    from jaxcal.diagnose.report import build_report_banded, promise_violations

    t0 = time.perf_counter()
    preps, results = diagnose_banded(rec, "diag")
    wall = time.perf_counter() - t0
    rep = build_report_banded(preps, results, "diag", wall)
    mods = {}
    for key, bo in (("after", False), ("before", True)):
        f = diagnosed_model_state(preps, results, "diag", rec, baseline_only=bo)
        mods[key] = methods.CalibrationModel("diagnosed", f.sensors, f.state, f.meta)
    sig = {s: float(preps[s].sigma_by_sensor[s]) for s in preps}
    values = {}
    for s, name, param in (("acc", "time_offset", "tau"), ("gyr", "time_offset", "tau"), ("acc", "lever_arm", "r")):
        e = next((e for e in rep["effects"] if e["sensor"] == s and e["name"] == name and not e.get("forced")), None)
        values[f"{s} {name}"] = None if e is None else {"value": np.ravel(e["params"][param]).tolist(),
                                                        "stderr": np.ravel(e["stderr"][param]).tolist()}
    return {"models": mods, "sigma": sig, "time_s": wall, "named": [f"{e['sensor']} {e['name']}" for e in rep["effects"] if not e.get("forced")],
            "carried": mods["after"].meta["effects"], "not_carried": mods["after"].meta["not_carried"], "values": values,
            "promise_violations": promise_violations(rep), "heldout_rms": {s: {"baseline": rep["baseline"][s]["heldout_rms"],
                                                                               "final": rep["final"][s]["heldout_rms"]} for s in rep["baseline"]}}


def _score(rec: Recording, outputs: dict, sig: dict) -> dict:
    from jaxcal.eval.mocap import calibrated_rms

    return calibrated_rms(rec, outputs, sig)


def run_real(quick: bool) -> dict:
    """Each pair of :data:`REAL_PAIRS` (quick: :data:`REAL_PAIRS_QUICK`): diagnose the first
    recording, apply its model to the second and score it against the second's mocap."""
    from jaxcal.diagnose import prepare

    pairs = REAL_PAIRS_QUICK if quick else REAL_PAIRS
    t_start = time.perf_counter()
    load0 = os.getloadavg()
    recs: dict[str, Recording] = {}
    diags: dict[str, dict] = {}
    sigs: dict[str, dict] = {}
    missing = sorted({str(REAL_RECORDINGS[n][0]) for p in pairs for n in p if not REAL_RECORDINGS[n][0].exists()})
    if missing:
        return {"missing": missing}
    for a, _ in pairs:
        if a not in diags:
            recs[a] = _load_real(a)
            diags[a] = _diagnose_real(recs[a])
            sigs[a] = diags[a]["sigma"]
            print(f"{a}: diagnosed in {diags[a]['time_s']:.0f} s, named {diags[a]['named']}, carried {diags[a]['carried']}", flush=True)
    rows = []
    for a, b in pairs:
        if b not in recs:
            recs[b] = _load_real(b)
        if b not in sigs:  # the band diagnose would trust on b (its first step)
            sigs[b] = {s: float(v) for s, v in prepare(recs[b], pose_sigma=None).sigma_by_sensor.items()}
        rb, sig = recs[b], sigs[b]
        after = diags[a]["models"]["after"]
        sc = {"as_recorded": _score(rb, _identity_outputs(rb), sig),
              "before": _score(rb, diags[a]["models"]["before"].apply(rb), sig),
              "after": _score(rb, after.apply(rb), sig)}
        if b in diags:  # b's own diagnosis, in-sample (fitted on b itself: not held out)
            sc["own_before"] = _score(rb, diags[b]["models"]["before"].apply(rb), sig)
            sc["own_after"] = _score(rb, diags[b]["models"]["after"].apply(rb), sig)
        drops = []
        for s, names in after.meta["effects"].items():
            for name in names:
                r_wo = _score(rb, without_effect(after, s, name).apply(rb), sig)
                drops.append({"sensor": s, "effect": name, "rms_after": sc["after"][s]["rms"], "rms_without": r_wo[s]["rms"],
                              "other_sensor_without": {o: v["rms"] for o, v in r_wo.items() if o != s}})
        row = {"diagnosed": a, "scored": b, "n_diagnosed": recs[a].n, "n_scored": rb.n, "sigma_scored": sig,
               "scores": sc, "drop_one": drops, "carried": diags[a]["carried"]}
        rows.append(row)
        print(f"{a} -> {b}: " + "; ".join(f"{s} as recorded {sc['as_recorded'][s]['rms']:.4g} before {sc['before'][s]['rms']:.4g} "
                                          f"after {sc['after'][s]['rms']:.4g}" for s in sc["after"]), flush=True)
        for d in drops:
            print(f"   drop {d['sensor']} {d['effect']}: {d['rms_after']:.5g} -> {d['rms_without']:.5g}", flush=True)
    diag_out = {n: {k: v for k, v in d.items() if k != "models"} | {"n_samples": recs[n].n, "duration_s": float(recs[n].t[-1] - recs[n].t[0]),
                                                                      "readme_check": README_CHECKS[n]}
                for n, d in diags.items()}
    return {"quick": quick, "baseline": "diag", "pairs": [list(p) for p in pairs], "diagnoses": diag_out, "rows": rows,
            "runtime_s": time.perf_counter() - t_start, "loadavg_start": list(load0), "loadavg_end": list(os.getloadavg()),
            "cpus": os.cpu_count()}


def _vals(v: dict | None, k: float = 1e3, nd: int = 1) -> str:
    if v is None:
        return "not named"
    a, e = np.asarray(v["value"]) * k, 1.96 * np.asarray(v["stderr"]) * k
    if a.size == 1:
        return f"{a[0]:+.{nd}f} +- {e[0]:.{nd}f}"
    return "[" + ", ".join(f"{x:+.{nd}f}" for x in a) + "] +- [" + ", ".join(f"{x:.{nd}f}" for x in e) + "]"


def real_markdown(res: dict) -> str:
    """The real-rig section: pairs, effects dropped one at a time, values side by side."""
    L = ["## Real rigs: diagnosed on one recording, applied to another of the same rig", ""]
    if "missing" in res:
        return "\n".join(L + [f"Data not found: {', '.join(res['missing'])}; section skipped.", ""])
    unit = {"acc": ("mg", 1e3), "gyr": ("mrad/s", 1e3)}
    L += [f"`python -m experiments.apply_effects{' --quick' if res['quick'] else ''} --part real`: {res['runtime_s']:.0f} s on "
          f"{res['cpus']} shared CPU cores (load average {res['loadavg_start'][0]:.1f} at the start, {res['loadavg_end'][0]:.1f} at the end). "
          "`diagnose` (diag baseline, as `jaxcal diagnose --model-out` runs it) on the first recording of each pair; its model applied "
          "(as `jaxcal apply` does) to the second recording and scored against the second's own motion capture: RMS per component of "
          "calibrated output minus the specific force / body rate derived from its pose, each sensor in the band `diagnose` trusts on "
          "that recording (Gaussian width sigma below; outputs smoothed by the same kernel and decimated alike), reference gaps and the "
          "kernel around them dropped (`jaxcal.eval.mocap.calibrated_rms`). The reference carries its own noise, so no row reaches a "
          "noise floor: a lower RMS is a better calibration only up to what the mocap itself gets wrong.", "",
          "| diagnosed -> scored | sensor | sigma (ms) | as recorded | before (baseline of the diagnosis) | after (diagnosed model) | after / before | "
          "scored recording's own diagnosis, in-sample: baseline -> diagnosed | carried from the diagnosed recording |",
          "|---|---|---|---|---|---|---|---|---|"]
    for r in res["rows"]:
        sc = r["scores"]
        for s in sc["after"]:
            u, k = unit[s]
            own = f"{k * sc['own_before'][s]['rms']:.3f} -> {k * sc['own_after'][s]['rms']:.3f}" if "own_after" in sc else "- (not diagnosed in the quick run)"
            ratio = sc["after"][s]["rms"] / sc["before"][s]["rms"]
            flag = "" if ratio <= 1.0 else " (WORSE)"
            L.append(f"| {r['diagnosed']} -> {r['scored']} | {s} ({u}) | {1e3 * r['sigma_scored'][s]:.0f} | {k * sc['as_recorded'][s]['rms']:.3f} | "
                     f"{k * sc['before'][s]['rms']:.3f} | **{k * sc['after'][s]['rms']:.3f}** | {ratio:.3f}{flag} | {own} | "
                     f"{', '.join(r['carried'].get(s, [])) or 'baseline only'} |")
    L += ["", "Each carried effect dropped from the diagnosed model in turn (baseline and the other effects kept at their joint refit "
          "values, not refitted), scored on the other recording: an effect helps the transfer when dropping it raises the RMS of its "
          "sensor.", "",
          "| diagnosed -> scored | effect | after | after without it | verdict |", "|---|---|---|---|---|"]
    n_help = n_all = 0
    for r in res["rows"]:
        for d in r["drop_one"]:
            u, k = unit[d["sensor"]]
            delta = d["rms_without"] - d["rms_after"]
            helps = delta > 0
            n_all += 1
            n_help += helps
            rel = f"{k * delta:+.3f} {u}, {100 * delta / d['rms_after']:+.1f} % without it"
            verdict = f"helps ({rel})" if helps else f"HURTS the other recording ({rel})"
            L.append(f"| {r['diagnosed']} -> {r['scored']} | {d['sensor']} {d['effect']} | {k * d['rms_after']:.4f} {u} | "
                     f"{k * d['rms_without']:.4f} | {verdict} |")
    if not n_all:
        L.append("| (no effect carried) | | | | |")
    L += ["", f"{n_help} of {n_all} carried effects lower the other recording's RMS.", "",
          "Values found on each recording (95 % intervals, 1.96 s.e.; `diagnose`'s report), beside the dataset README's independent check "
          "(cross-correlation and least squares with numpy; the BROAD README's lag is |gyro| against the pose's |rate|, a delay of the IMU):", "",
          "| recording | samples | `diagnose` names | carried | acc time offset (ms) | gyr time offset (ms) | README lag (ms) | acc lever arm r (mm) | "
          "README r (mm) | own held-out rms acc / gyr: baseline -> final | promise kept | diagnose time (s) |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for n, d in res["diagnoses"].items():
        c = d["readme_check"]
        h = d["heldout_rms"]
        hr = " / ".join(f"{1e3 * h[s]['baseline']:.3f} -> {1e3 * h[s]['final']:.3f}" for s in ("acc", "gyr") if s in h)
        carried = "; ".join(f"{s}: {', '.join(v) or '-'}" for s, v in d["carried"].items())
        L.append(f"| {n} | {d['n_samples']} ({d['duration_s']:.0f} s) | {', '.join(d['named']) or 'nothing'} | {carried} | "
                 f"{_vals(d['values']['acc time_offset'], nd=2)} | {_vals(d['values']['gyr time_offset'], nd=2)} | {1e3 * c['tau_s']:.1f} | "
                 f"{_vals(d['values']['acc lever_arm'])} | {np.round(np.asarray(c['r_m']) * 1e3, 1).tolist()} | {hr} (mg / mrad/s) | "
                 f"{'yes' if not d['promise_violations'] else d['promise_violations']} | {d['time_s']:.0f} |")
    nc = sorted({f"{x['sensor']} {x['name']}" for d in res["diagnoses"].values() for x in d["not_carried"]})
    L += ["", f"Named but not carried (they do not transfer to another recording): {', '.join(nc) or 'none'}.", ""]
    cons = _consistency(res)
    if cons:
        L += ["Consistency between the two recordings of one rig (difference of the estimates, 95 % interval 1.96 x hypot of both "
              "standard errors; 'consistent' when the interval holds 0). The intervals hold each estimate's statistical error only, not what "
              "the reference gets wrong systematically (a mocap body or clock that differs between sessions, the band's kernel), so a "
              "difference far below a sample interval or a millimetre can still fall outside:", "",
              "| recordings | value | difference | 95 % interval | consistent |", "|---|---|---|---|---|"]
        for c in cons:
            k, u = (1e3, "ms") if "time_offset" in c["value"] else (1e3, "mm")
            d, h = np.asarray(c["difference"]) * k, np.asarray(c["halfwidth"]) * k
            txt = lambda a: ", ".join(f"{x:+.2f}" for x in a)  # noqa: E731
            L.append(f"| {c['a']} vs {c['b']} | {c['value']} ({u}) | {txt(d)} | +- {', '.join(f'{x:.2f}' for x in h)} | "
                     f"{'yes' if c['consistent'] else 'NO (' + str(sum(c['inside'])) + '/' + str(len(c['inside'])) + ' components)'} |")
        L.append("")
    worse = [f"{r['diagnosed']} -> {r['scored']} {s}" for r in res["rows"] for s in r["scores"]["after"]
             if r["scores"]["after"][s]["rms"] > r["scores"]["before"][s]["rms"]]
    L += [f"Transfers that made the other recording's fit worse than the diagnosis's baseline alone: {'; '.join(worse) or 'none'}.", ""]
    return "\n".join(L)


def _consistency(res: dict) -> list[dict]:
    """Per pair of diagnosed recordings of one rig (both sides of a pair diagnosed), the difference of
    each time offset and lever arm named on both, with its 95 % half-width."""
    out = []
    seen = set()
    for a, b in res["pairs"]:
        key = tuple(sorted((a, b)))
        if key in seen or a not in res["diagnoses"] or b not in res["diagnoses"]:
            continue
        seen.add(key)
        va, vb = res["diagnoses"][key[0]]["values"], res["diagnoses"][key[1]]["values"]
        for name in va:
            if va[name] is None or vb[name] is None:
                continue
            d = np.subtract(va[name]["value"], vb[name]["value"])
            h = 1.96 * np.hypot(va[name]["stderr"], vb[name]["stderr"])
            inside = (np.abs(d) <= h).tolist()
            out.append({"a": key[0], "b": key[1], "value": name, "difference": d.tolist(), "halfwidth": h.tolist(),
                        "inside": inside, "consistent": all(inside)})
    return out


def main(quick: bool = False, out: str | Path = RESULTS, part: str = "all") -> None:
    """Run and write ``OUT/apply_effects.{json,md}`` (quick: ``apply_effects_quick.*``, so a quick run
    never overwrites the full results); one part alone keeps the other's results in the files.

    Args:
        quick: 4000 samples and one seed instead of 20000 and three; two real pairs instead of four.
        out: output directory.
        part: ``"sim"``, ``"real"`` or ``"all"``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "apply_effects_quick" if quick else "apply_effects"
    js = out / f"{stem}.json"
    cur = json.loads(js.read_text()) if js.exists() else {}
    if part in ("sim", "all"):
        cur = run(quick) | ({"real": cur["real"]} if "real" in cur else {})
    if part in ("real", "all"):
        real = run_real(quick)
        cur = cur | {"real": real}
    js.write_text(json.dumps(cur, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    text = markdown(cur) if "rows" in cur else "# Applying a diagnosed model to held-out data (issue 17)\n"
    if "real" in cur:
        text += "\n" + real_markdown(cur["real"])
    (out / f"{stem}.md").write_text(text)
    print(text)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="4000 samples, one seed; two real pairs")
    ap.add_argument("--part", choices=("sim", "real", "all"), default="all", help="simulated effects, real rigs, or both (default)")
    ap.add_argument("--out", default=str(RESULTS), help="output directory (default results/)")
    a = ap.parse_args()
    main(a.quick, a.out, a.part)
