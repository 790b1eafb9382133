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

``python -m experiments.apply_effects [--quick]`` writes ``results/apply_effects.json`` and ``.md``
(quick: ``results/apply_effects_quick.*``, 4000 samples (40 s) per recording and one seed; full:
20000 samples and three seeds).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal import methods
from jaxcal.diagnose import diagnose_banded
from jaxcal.diagnose import effects as E
from jaxcal.diagnose.simulate import RichConfig, motion
from jaxcal.methods.diagnosed import apply as diagnosed_apply
from jaxcal.methods.diagnosed import diagnosed_model_state
from jaxcal.recording import Recording, recording_from_dict

__all__ = ["EFFECTS", "simulate", "oracle_state", "run_effect", "run", "markdown", "main"]

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


def main(quick: bool = False, out: str | Path = RESULTS) -> None:
    """Run and write ``OUT/apply_effects.{json,md}`` (quick: ``apply_effects_quick.*``, so a quick run
    never overwrites the full results).

    Args:
        quick: 4000 samples and one seed instead of 20000 and three.
        out: output directory.
    """
    res = run(quick)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "apply_effects_quick" if quick else "apply_effects"
    (out / f"{stem}.json").write_text(json.dumps(res, indent=1))
    (out / f"{stem}.md").write_text(markdown(res))
    print(markdown(res))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="4000 samples, one seed")
    ap.add_argument("--out", default=str(RESULTS), help="output directory (default results/)")
    a = ap.parse_args()
    main(a.quick, a.out)
