"""Noise parameters (``jaxcal noise``): interval coverage on simulated logs, agreement with allantools,
real recordings beside their datasheets, and the inflation a filter needs on dynamic data.

``python -m experiments.noise [--quick]`` writes ``results/noise.md``, ``results/noise.json`` and the
figures ``results/noise_*.png`` (quick form: ``noise_quick*``). Every number is produced here:

(a) coverage per composite case (white + random walk crossing over at 0.1, 1, 10 s; + a Gauss-Markov
    bias; + quantisation; EuRoC's published values), 1 h logs at 200 Hz with known parameters: the
    model the GMWM chose, the median error and the share of 95 % intervals covering the truth, beside
    the slope-line reading (both as ``jaxcal noise`` computes them, :func:`jaxcal.noise.sensor_noise`);
    and the record length predicted for a narrower K interval, checked on logs of that length;
(b) the overlapping ADEV against ``allantools.oadev`` on the same data;
(c) the real recordings with static stretches (``data/``), N/B/K beside their datasheets;
(d) the inflation factor: ``diagnose``'s noise model on dynamic data (BROAD trials: optical mocap
    reference, a rest at the end) against the static Allan white noise of the same IMU, processed
    through the same smoothing and decimation.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import time

import numpy as np

from jaxcal.allan import overlapping_adev, simulate_imu_noise
from jaxcal.constants import G0
from jaxcal.gmwm import GmwmConfig, quantised_rate, record_length
from jaxcal.noise import gauss_markov_adev, noise_report, sensor_noise
from jaxcal.recording import load_recording

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
DATA = ROOT / "data"

FS = 100.0
HOURS = 4.0
# gyro-like truth (rad/s): 0.69 deg/sqrt(h) white, 1.4 deg/h/sqrt(h)... random walk; white/RW crossover sqrt(3) N/K = 173 s
N_TRUE = 2e-4  # rad/s/sqrt(Hz)
K_TRUE = 2e-6  # rad/s^2/sqrt(Hz)
GM_SIGMA, GM_TAU = 3e-5, 50.0  # Gauss-Markov bias: stationary std (rad/s), correlation time (s)
PENALTY = GmwmConfig().penalty

# datasheet values (SI): see the md for sources
DATASHEETS = {
    "MPU-6050": {"acc_N": 400e-6 * G0, "gyr_N": np.radians(0.005),
                 "source": "InvenSense PS-MPU-6000A rev 3.4, Table 6.1/6.2: gyro rate noise spectral density 0.005 deg/s/sqrt(Hz), "
                           "accelerometer power spectral density 400 ug/sqrt(Hz)"},
    "Xsens MTi (1st generation, 16-bit ADC)": {
        "acc_N": None, "gyr_N": None,
        "source": "Xsens MT0100P (MTi and MTx User Manual), p. 17: noise densities are given only for non-default ranges "
                  "(0.004 m/s^2/sqrt(Hz) at +-18 g, 0.04 deg/s/sqrt(Hz) at +-150 deg/s); the default ranges of this unit "
                  "(+-50 m/s^2, +-300 deg/s; its scales 415 LSB per m/s^2 and 4778 LSB per rad/s fit them) refer to the "
                  "manual's table 1, which I could not retrieve"},
}


# composite cases (one axis, 1 h at 200 Hz, the EuRoC log's length and rate): white noise N0 plus a random walk
# meeting it at tau_c = sqrt(3) N / K, a Gauss-Markov bias, angle quantisation; and EuRoC's published values
CASE_FS, CASE_HOURS, N0 = 200.0, 1.0, 2e-4
GM_CASE_TAU = 5.0  # s; its sigma puts the Gauss-Markov ADEV peak (1.89 tau) at 1.5 x the white noise there
CASES = {
    "wn_rw_0.1s": {"label": "white + random walk, crossover 0.1 s", "model": "WN+RW", "N": N0, "K": np.sqrt(3) * N0 / 0.1},
    "wn_rw_1s": {"label": "white + random walk, crossover 1 s", "model": "WN+RW", "N": N0, "K": np.sqrt(3) * N0 / 1.0},
    "wn_rw_10s": {"label": "white + random walk, crossover 10 s", "model": "WN+RW", "N": N0, "K": np.sqrt(3) * N0 / 10.0},
    "wn_rw_gm": {"label": f"+ Gauss-Markov bias (tau {GM_CASE_TAU:g} s), crossover 10 s", "model": "WN+RW+GM", "N": N0,
                 "K": np.sqrt(3) * N0 / 10.0, "tau_gm": GM_CASE_TAU,
                 "sigma_gm": float(1.5 * N0 / np.sqrt(1.89 * GM_CASE_TAU) / gauss_markov_adev(np.array([1.89 * GM_CASE_TAU]), 1.0, GM_CASE_TAU)[0])},
    "wn_rw_qn": {"label": "+ quantisation (QN AVAR 1/4 of white at one sample), crossover 1 s", "model": "WN+QN+RW", "N": N0,
                 "K": np.sqrt(3) * N0 / 1.0, "Q": N0 * np.sqrt(0.25 / (3 * CASE_FS))},
    "euroc_acc": {"label": "EuRoC accelerometer (m/s^2): 2.0e-3 white, 3.0e-3 random walk", "model": "WN+RW", "N": 2.0e-3, "K": 3.0e-3},
    "euroc_gyr": {"label": "EuRoC gyroscope (rad/s): 1.7e-4 white, 1.9e-5 random walk", "model": "WN+RW", "N": 1.7e-4, "K": 1.9e-5},
}


def _case_log(case: dict, seed: int, hours: float = CASE_HOURS) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = int(hours * 3600 * CASE_FS)
    x = simulate_imu_noise(rng, n, CASE_FS, case["N"], B=case.get("sigma_gm", 0.0), K=case["K"], tau_b=case.get("tau_gm", 100.0))
    return quantised_rate(rng, x, CASE_FS, case["Q"]) if "Q" in case else x


def _case_row(case: dict, x: np.ndarray) -> dict:
    r = sensor_noise(x, CASE_FS)
    g, s = r.gmwm[0], r.slope
    row = {"model": "+".join(g.model), "wvic": g.wvic, "truth": {k: case[k] for k in PARAMS_OF_INTEREST if k in case}}
    for k in PARAMS_OF_INTEREST:
        row[k] = list(g.get(k))
    for k in ("N", "K"):
        row["slope_" + k] = [float(getattr(s, k)[0]), float(getattr(s, k + "_lo")[0]), float(getattr(s, k + "_hi")[0])]
    row["halfwidth_K"] = float(g.get("K")[2] / g.get("K")[0] - 1.0) if "K" in g.names else None
    row["fit"] = g
    return row


PARAMS_OF_INTEREST = ("N", "K", "Q", "sigma_gm", "tau_gm")


def _summary(rows: list[dict], case: dict) -> dict:
    def med(key, truth):
        v = np.array([r[key][0] for r in rows], float)
        return float(np.nanmedian(v / truth) - 1.0)

    def cov(key, truth):
        return float(np.mean([r[key][1] <= truth <= r[key][2] for r in rows]))

    def n_par(model: str) -> int:
        return sum(2 if q == "GM" else 1 for q in model.split("+"))

    plain = [min(r["wvic"], key=lambda k: r["wvic"][k] - (PENALTY - 2.0) * n_par(k)) for r in rows]  # WVIC with 2 per parameter
    out = {"logs": len(rows), "right_model": float(np.mean([r["model"] == case["model"] for r in rows])),
           "right_model_plain_wvic": float(np.mean([m == case["model"] for m in plain])),
           "models": {m: sum(r["model"] == m for r in rows) for m in sorted({r["model"] for r in rows})}}
    for k in ("N", "K", "Q", "sigma_gm", "tau_gm"):
        if k in case:
            out[k] = {"median_rel_error": med(k, case[k]), "coverage": cov(k, case[k])}
    for k in ("N", "K"):
        out["slope_" + k] = {"median_rel_error": med("slope_" + k, case[k]), "coverage": cov("slope_" + k, case[k])}
    return out


def _coverage(quick: bool, seeds: int) -> dict:
    out = {}
    for i, (name, case) in enumerate(CASES.items()):
        t0 = time.perf_counter()
        rows = [_case_row(case, _case_log(case, 10_000 * (i + 1) + s)) for s in range(seeds)]
        res = _summary(rows, case) | {"seconds_per_log": (time.perf_counter() - t0) / seeds}
        out[name] = res
        out[name + "_rows"] = [{k: v for k, v in r.items() if k != "fit"} for r in rows]
        if name == "wn_rw_10s":
            out["record_length"] = _record_check(case, rows, 6 if quick else 20)
        print(f"coverage {name}: {seeds} logs, right model {res['right_model']:.2f}, N {res['N']['median_rel_error']:+.3f} "
              f"cov {res['N']['coverage']:.2f}, K {res['K']['median_rel_error']:+.3f} cov {res['K']['coverage']:.2f}", flush=True)
    return out


def _record_check(case: dict, rows: list[dict], logs: int) -> dict:
    """Say how long to record, checked: the record length each 1 h log predicts for a K interval 2/3 as wide as
    the median it gave, then logs of the median predicted length, and the half-widths they give."""
    width = float(np.median([r["halfwidth_K"] for r in rows if r["halfwidth_K"] is not None]))
    target = 2.0 * width / 3.0
    pred = [record_length(r["fit"], "K", target) for r in rows if "K" in r["fit"].names]
    hours = float(np.median(pred)) / 3600.0
    got = [_case_row(case, _case_log(case, 90_000 + s, hours)) for s in range(logs)]
    return {"target_halfwidth": target, "halfwidth_1h_median": width, "predicted_hours_median": hours,
            "predicted_hours_range": [float(np.min(pred)) / 3600.0, float(np.max(pred)) / 3600.0], "logs": logs,
            "halfwidth_at_predicted_median": float(np.median([r["halfwidth_K"] for r in got if r["halfwidth_K"] is not None])),
            "K_coverage_at_predicted": float(np.mean([r["K"][1] <= case["K"] <= r["K"][2] for r in got]))}


def _allantools(quick: bool) -> dict:
    import allantools

    n = int((0.5 if quick else HOURS) * 3600 * FS)
    x = simulate_imu_noise(np.random.default_rng(7), n, FS, N_TRUE, B=GM_SIGMA, K=K_TRUE, tau_b=GM_TAU)[:, 0]
    t0 = time.perf_counter()
    r = overlapping_adev(x, FS)
    t_j = time.perf_counter() - t0
    t0 = time.perf_counter()
    taus, adev, _, nn = allantools.oadev(x, rate=FS, data_type="freq", taus=r.taus)
    t_a = time.perf_counter() - t0
    k = taus.size
    rel = np.abs(r.adev[:k, 0] / adev - 1.0)
    return {"samples": n, "taus_compared": int(k), "taus_jaxcal": int(r.taus.size), "max_rel_diff": float(rel.max()),
            "same_taus": bool(np.array_equal(taus, r.taus[:k])), "same_n_terms": bool(np.array_equal(nn, r.n_terms[:k])),
            "seconds_jaxcal": t_j, "seconds_allantools": t_a}


def _xsens(rec):
    # imu_tk's Xsens README: factory scales diag(415, 413, 415) LSB per m/s^2 and diag(4778, 4758, 4766) LSB per rad/s
    return rec.replace(acc_lsb_per_g=np.array([415.0, 413.0, 415.0]) * G0, gyr_lsb_per_rads=np.array([4778.0, 4758.0, 4766.0]))


REAL = [
    ("MPU-6050 long static log", "tomisuarez_mpu6050/tinit_calc.npz", None, "MPU-6050"),
    ("MPU-6050 static test", "tomisuarez_mpu6050/static_test.npz", None, "MPU-6050"),
    ("Xsens MTi, initial rest", "imu_tk_xsens_multipos/xsens.npz", _xsens, "Xsens MTi (1st generation, 16-bit ADC)"),
    ("x-io Fusion example", "xio_fusion_sensor_data/sensor_data.npz", None, None),
    ("BROAD 07 (myon aktos-t), rest", "broad_07_undisturbed_fast_rotation_B/07_undisturbed_fast_rotation_B.npz", None, None),
    ("BROAD 21 (myon aktos-t), rest", "broad_21_undisturbed_fast_combined/21_undisturbed_fast_combined.npz", None, None),
    ("TUM-VI room1 (BMI160)", "tumvi_room1_512_16/room1.npz", None, None),
]


def _real() -> list[dict]:
    rows = []
    for name, rel, fix, sheet in REAL:
        rec = load_recording(DATA / rel)
        if fix is not None:
            rec = fix(rec)
        try:
            rep = noise_report(rec)
        except ValueError as e:
            rows.append({"name": name, "file": rel, "refused": " ".join(str(e).split())})
            print(f"real {name}: refused: {e}", flush=True)
            continue
        row = {"name": name, "file": rel, "duration_s": rep.t_end - rep.t_start, "t_start_s": rep.t_start - float(rec.t[0]),
               "fs_hz": rep.fs, "how": rep.how, "warnings": rep.warnings}
        for s, r in rep.sensors.items():
            p = r.params
            row[s] = {"N": p.N.tolist(), "B": r.slope.B.tolist(), "K": [None if not np.isfinite(v) else float(v) for v in p.K],
                      "K_bound": r.K_bound.tolist(), "N_lo": p.N_lo.tolist(), "N_hi": p.N_hi.tolist(), "tau_B": r.slope.tau_B.tolist(),
                      "model": ["+".join(f.model) for f in r.gmwm], "slope_N": r.slope.N.tolist()}
        if sheet:
            row["datasheet"] = sheet
        rows.append(row)
        print(f"real {name}: {row['duration_s']:.0f} s, acc N {np.max(row['acc']['N']):.3g}, gyr N {np.max(row['gyr']['N']):.3g}", flush=True)
    return rows


def _inflation(quick: bool) -> list[dict]:
    """diagnose's noise model on dynamic data against the static white noise, same smoothing and decimation."""
    import jaxcal.diagnose as diag
    from jaxcal.diagnose import kinematics as K
    from jaxcal.diagnose.whiten import choose_lambda, fit_ar, reml_profile

    out = []
    trials = [("BROAD 07", "broad_07_undisturbed_fast_rotation_B/07_undisturbed_fast_rotation_B.npz"),
              ("BROAD 21", "broad_21_undisturbed_fast_combined/21_undisturbed_fast_combined.npz")]
    for name, rel in trials:
        rec = load_recording(DATA / rel)
        static = noise_report(rec)
        t0 = time.perf_counter()
        rep = diag.diagnose_recording(rec)
        el = time.perf_counter() - t0
        dt = float(np.median(np.diff(rec.t)))
        row = {"name": name, "file": rel, "static_s": static.t_end - static.t_start, "diagnose_seconds": el,
               "reference_band": {k: rep["reference_band"][k] for k in ("sigma_s", "sigma_by_sensor_s")}, "sensors": {}}
        sig_by = _sigma_by_sensor(rep)
        for s in ("acc", "gyr"):
            sig = sig_by[s]
            decim = max(1, int(round(_pose_sigma(rep, sig_by) / dt)))
            unit = G0 if s == "acc" else 1.0  # diagnose works in g / rad/s; the Allan report in SI
            x = np.asarray(getattr(rec, s), np.float64)
            xs = K._conv(x, K.gaussian_kernels(sig, dt)[0])
            pad = int(np.ceil(5 * sig / dt))
            seg = xs[static.start + pad: static.stop - pad: decim]
            seg = seg - seg.mean(0)
            rows_ok = np.ones(len(seg), bool)
            profs = [reml_profile(seg[:, i], rows_ok) for i in range(3)]
            lams = choose_lambda(profs)
            ars = [fit_ar(seg[:, i], rows_ok, 64, lam=lams[i]) for i in range(3)]
            sd_static = np.array([a.sigma for a in ars])
            sd_dyn = np.asarray(rep["sensors"][s]["noise"]["innovation_sd"], np.float64)
            n_static = static.sensors[s].params.N / unit  # g or rad/s per sqrt(Hz)
            expect = n_static / np.sqrt(2.0 * np.sqrt(np.pi) * sig)  # white noise after the Gaussian kernel
            row["sensors"][s] = {
                "kernel_sigma_s": sig, "decimation": decim,
                "static_allan_N": (n_static * unit).tolist(),
                "static_smoothed_rms_expected_from_N": expect.tolist(),
                "static_smoothed_rms": seg.std(0).tolist(),
                "static_innovation_sd": sd_static.tolist(),
                "dynamic_innovation_sd": sd_dyn.tolist(),
                "factor_innovation": (sd_dyn / sd_static).tolist(),
                "dynamic_final_rms": rep["final"][s].get("rms"),
                "dynamic_final_heldout_rms": rep["final"][s].get("heldout_rms"),
                "factor_rms": float(rep["final"][s]["rms"] / np.sqrt(np.mean(seg.std(0) ** 2))),
            }
        out.append(row)
        print(f"inflation {name}: diagnose {el:.0f} s; " + "; ".join(
            f"{s} innovation x{np.round(v['factor_innovation'], 1).tolist()}, rms x{v['factor_rms']:.1f}" for s, v in row["sensors"].items()),
            flush=True)
    return out


def _sigma_by_sensor(rep: dict) -> dict:
    """Each sensor's Gaussian kernel width (s) as diagnose chose it (``reference_band`` of its report)."""
    b = rep["reference_band"]
    return {k: float(v) for k, v in (b.get("sigma_by_sensor_s") or {"acc": b["sigma_s"], "gyr": b["sigma_s"]}).items()}


def _pose_sigma(rep: dict, by: dict) -> float:
    """The width that set diagnose's decimation (``round(sigma / dt)``)."""
    return float(rep["reference_band"]["sigma_s"])


def _figures(prefix: str, cov: dict, real: list[dict]) -> list[str]:
    from matplotlib.figure import Figure

    names = []
    fig = Figure(figsize=(10, 3.8), layout="constrained")
    axs = fig.subplots(1, 2)
    case = CASES["euroc_acc"]
    for ax, key, lab in ((axs[0], "N", "N [m/s^2/sqrt(Hz)]"), (axs[1], "K", "K [m/s^3/sqrt(Hz)]")):
        truth = case[key]
        for i, r in enumerate(cov["euroc_acc_rows"]):
            for k, dx, c in ((key, -0.15, "C0"), ("slope_" + key, 0.15, "C1")):
                v, lo, hi = r[k]
                ax.errorbar(i + dx, v, yerr=[[v - lo], [hi - v]], fmt="o", ms=3, color=c if lo <= truth <= hi else "C3",
                            elinewidth=0.8, label=None if i else ("GMWM" if k == key else "slope line"))
        ax.axhline(truth, color="k", lw=0.8)
        ax.set_xlabel("seed")
        ax.set_ylabel(lab)
        ax.legend(fontsize=8)
        ax.set_title(f"95 % intervals, EuRoC accelerometer values ({CASE_HOURS:g} h at {CASE_FS:g} Hz); red: misses", fontsize=9)
    names.append(f"{prefix}_coverage.png")
    fig.savefig(RESULTS / names[-1], dpi=100)
    ok = [r for r in real if "refused" not in r]
    fig = Figure(figsize=(10, 3.8), layout="constrained")
    axs = fig.subplots(1, 2)
    for ax, s, scale, lab in ((axs[0], "acc", 1e6 / G0, "N [ug/sqrt(Hz)]"), (axs[1], "gyr", np.degrees(1.0), "N [deg/s/sqrt(Hz)]")):
        for i, r in enumerate(ok):
            n = np.asarray(r[s]["N"]) * scale
            ax.plot([i] * 3, n, "o", color="C0", ms=4)
            sheet = DATASHEETS.get(r.get("datasheet") or "", {}).get(f"{s}_N")
            if sheet:
                ax.plot(i, sheet * scale, "k_", ms=18, mew=2)
        ax.set_xticks(range(len(ok)), [r["name"].split(",")[0][:22] for r in ok], rotation=30, ha="right", fontsize=7)
        ax.set_yscale("log")
        ax.set_ylabel(lab)
        ax.set_title(f"{s}: static Allan white noise per axis (dots), datasheet (bars)", fontsize=9)
    names.append(f"{prefix}_real.png")
    fig.savefig(RESULTS / names[-1], dpi=100)
    return names


def _fmt(v, scale=1.0, digits=3):
    return "-" if v is None else f"{v * scale:.{digits}g}"


def _short_stretches(real: list[dict]) -> str:
    """The paragraph on what short static stretches can and cannot show, with this run's durations."""
    rows = [r for r in real if r.get("duration_s")]
    if not rows:
        return ""
    short = [r["duration_s"] for r in rows if r["duration_s"] < 100.0]
    longest = max(rows, key=lambda r: r["duration_s"])
    text = "Short stretches: N rests on the short cluster times, so "
    if short:
        text += (f"a {min(short):.0f}-{max(short):.0f} s stretch still pins it to the interval in the table "
                 f"({min(short):.0f}-{max(short):.0f} non-overlapping 1 s clusters, more with the overlaps), ")
    else:
        text += "even a short stretch pins it to the interval in the table, "
    return text + ("but it cannot see bias instability or random walk: its B is the bottom of a short curve (an upper bound at "
                   "best) and K only an upper bound (min over tau of the ADEV's upper interval end times sqrt(3/tau)). The "
                   f"longest stretch here ({longest['name']}, {longest['duration_s']:.0f} s) is the only one whose curve turns "
                   "up, and even it shows no clean +1/2 random-walk line: K is a bound there too. A B or K worth using needs a "
                   "static log of hours.")


def _innovation_spread(inflation: list[dict]) -> str:
    """How far the innovation-sd ratio swings across trials and kernels (why it is not the number to use)."""
    f = [x for r in inflation for v in r["sensors"].values() for x in v["factor_innovation"]]
    kernels = sorted({round(1e3 * v["kernel_sigma_s"]) for r in inflation for v in r["sensors"].values()})
    return (f"kernels of {', '.join(str(k) for k in kernels)} ms here; the innovation ratio swings from "
            f"{min(f):.0f}x to {max(f):.0f}x across trials and axes")


def _coverage_md(c: dict) -> list[str]:
    """Part (a) of the markdown: the coverage table per case, the other parameters, EuRoC, the record length."""
    L = ["## (a) Coverage on simulated static logs, GMWM beside the slope-line reading", "",
         f"Each log is one axis, {CASE_HOURS:g} h at {CASE_FS:g} Hz ({int(CASE_HOURS * 3600 * CASE_FS):,} samples), of a composite process "
         f"with known parameters; white noise N = {N0:g} u/sqrt(Hz) unless stated, K such that the random walk meets it at the "
         "crossover tau_c = sqrt(3) N / K. `jaxcal noise` (`jaxcal.noise.sensor_noise`) reads each log twice: the GMWM "
         "(`jaxcal.gmwm`: every candidate model fitted jointly to the Allan variance at all dyadic cluster times, weighted by "
         f"the estimator's exact covariance, chosen by WVIC with {PENALTY:g} per parameter) and, as a second opinion, the slope "
         "line (`jaxcal.allan.fit_noise`: N read at tau = 1 s, K on the +1/2 line). Errors are medians over the logs; "
         "'covered' is the share of 95 % intervals holding the truth (goal 93-97 %).", "",
         "| case | logs | right model (WVIC 2/param) | GMWM N error | N covered | GMWM K error | K covered | "
         "slope-line N error | N covered | slope-line K error | K covered | s per log |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, case in CASES.items():
        r = c[name]
        L.append(f"| {case['label']} | {r['logs']} | {100 * r['right_model']:.0f} % ({100 * r['right_model_plain_wvic']:.0f} %) | "
                 + " | ".join(f"{100 * r[k]['median_rel_error']:+.1f} % | {100 * r[k]['coverage']:.0f} %" for k in ("N", "K", "slope_N", "slope_K"))
                 + f" | {r['seconds_per_log']:.1f} |")
    g, q, rl = c["wn_rw_gm"], c["wn_rw_qn"], c["record_length"]
    L += ["", "Models chosen per case: " + "; ".join(f"{n}: " + ", ".join(f"{m} {k}" for m, k in c[n]["models"].items()) for n in CASES) + ".",
          "", f"The other parameters: Gauss-Markov sigma {100 * g['sigma_gm']['median_rel_error']:+.1f} % (covered "
          f"{100 * g['sigma_gm']['coverage']:.0f} %), tau {100 * g['tau_gm']['median_rel_error']:+.1f} % ({100 * g['tau_gm']['coverage']:.0f} %); "
          f"quantisation Q {100 * q['Q']['median_rel_error']:+.1f} % ({100 * q['Q']['coverage']:.0f} %). The plain WVIC (2 per "
          "parameter, its asymptotic optimism) admits a spurious process (a rate ramp, flicker or quantisation) too often, the "
          "figure in brackets; the penalty used asks each added parameter to be significant.", "",
          "EuRoC's values (issue 29): the slope line reads the accelerometer's N "
          f"{100 * c['euroc_acc']['slope_N']['median_rel_error']:+.0f} % (the random walk already equals the white noise near 1.2 s, "
          "where it reads N); the GMWM reads all four densities within "
          f"{100 * max(abs(c[s][k]['median_rel_error']) for s in ('euroc_acc', 'euroc_gyr') for k in ('N', 'K')):.1f} % (median).", "",
          "Say how long to record: on the crossover-10 s case, the 1 h logs gave K a median 95 % half-width of "
          f"+{100 * rl['halfwidth_1h_median']:.0f} %; each predicted the length that makes it +{100 * rl['target_halfwidth']:.0f} % "
          f"(`jaxcal.gmwm.record_length`: the fitted model's covariance at the longer length), median {rl['predicted_hours_median']:.2f} h "
          f"(range {rl['predicted_hours_range'][0]:.2f}-{rl['predicted_hours_range'][1]:.2f} h). {rl['logs']} logs of that length gave a "
          f"median half-width of +{100 * rl['halfwidth_at_predicted_median']:.0f} %, and their K intervals covered the truth in "
          f"{100 * rl['K_coverage_at_predicted']:.0f} %.", ""]
    return L


def _markdown(res: dict) -> str:
    c, a = res["coverage"], res["allantools"]
    L = ["# Noise parameters (`jaxcal noise`)", "",
         f"Written by `experiments/noise.py` ({'quick' if res['quick'] else 'full'} form) in {res['seconds']:.0f} s "
         f"(load average at start {res['load_start']}, at end {res['load_end']}; 2-core machine shared with other jobs).", ""]
    L += _coverage_md(c)
    L += ["## (b) Agreement with allantools", "",
          f"`jaxcal.allan.overlapping_adev` against `allantools.oadev(data_type='freq')` on the same {a['samples']:,}-sample log "
          f"(white + Gauss-Markov + random walk), {a['taus_compared']} cluster times (allantools drops the last one): "
          f"max relative difference {a['max_rel_diff']:.1e} (0: bit-identical; tests/test_allan.py measures 1.5e-14 on two-column data); same taus: {a['same_taus']}, same number of terms: {a['same_n_terms']}. "
          f"Time: jaxcal {a['seconds_jaxcal']:.2f} s, allantools {a['seconds_allantools']:.2f} s.", "",
          "## (c) Real recordings with static stretches", "",
          "Each row is `jaxcal noise REC` with its default stretch (the longest static interval found). Values are the range over the "
          "three axes. K is an upper bound (<=) where the stretch is too short for the random-walk line to show.", "",
          "| recording | static stretch | acc N [ug/sqrt(Hz)] | acc B, slope line [ug] | acc K [ug/s/sqrt(Hz)] | gyr N [deg/s/sqrt(Hz)] | "
          "gyr B, slope line [deg/h] | "
          "gyr K [deg/h/sqrt(h)] | N 95 % interval | GMWM models (acc; gyr) | datasheet N (acc, gyr) |",
          "|---|---|---|---|---|---|---|---|---|---|---|"]
    ug, dps, dph, dphh = 1e6 / G0, np.degrees(1.0), np.degrees(1.0) * 3600, np.degrees(1.0) * 3600 * 60
    for r in res["real"]:
        if "refused" in r:
            L.append(f"| {r['name']} | none: {r['refused']} | - | - | - | - | - | - | - | - | - |")
            continue

        def rng(s, k, sc):
            v = np.asarray([x for x in r[s][k] if x is not None], float) * sc
            return f"{v.min():.3g}-{v.max():.3g}" if v.size else "-"

        def kk(s, sc):
            if all(x is not None for x in r[s]["K"]):
                return rng(s, "K", sc)
            return "<= " + f"{np.max(r[s]['K_bound']) * sc:.3g}"

        sheet = DATASHEETS.get(r.get("datasheet") or "", {})
        sh = "-" if not sheet else (f"{_fmt(sheet.get('acc_N'), ug)} ug, {_fmt(sheet.get('gyr_N'), dps)} deg/s" if sheet.get("acc_N") else "see note")
        lo = min(np.min(np.asarray(r[s]["N_lo"]) / np.asarray(r[s]["N"])) for s in ("acc", "gyr")) - 1.0
        hi = max(np.max(np.asarray(r[s]["N_hi"]) / np.asarray(r[s]["N"])) for s in ("acc", "gyr")) - 1.0
        L.append(f"| {r['name']} | {r['duration_s']:.0f} s from {r['t_start_s']:.0f} s | {rng('acc', 'N', ug)} | {rng('acc', 'B', ug)} | "
                 f"{kk('acc', ug)} | {rng('gyr', 'N', dps)} | {rng('gyr', 'B', dph)} | {kk('gyr', dphh)} | {100 * lo:+.0f} % / {100 * hi:+.0f} % | "
                 f"{'; '.join(', '.join(sorted(set(r[s]['model']))) for s in ('acc', 'gyr'))} | {sh} |")
    L += ["", "Datasheets:"]
    for k, v in DATASHEETS.items():
        L.append(f"- {k}: {v['source']}.")
    L += ["- x-io Fusion example: the repository does not name the device; BROAD: myon aktos-t, no noise density found; "
          "TUM-VI: Bosch BMI160, no static stretch in room1 (hand-held from the first second).", "",
          _short_stretches(res["real"]), ""]
    L += ["## (d) How much a filter should inflate the static numbers", ""]
    if res["inflation"]:
        L += ["`jaxcal diagnose` fits, per axis, a noise model to the residual of the IMU against the optical reference (a local-level "
              "random walk plus AR(p), `jaxcal.diagnose.whiten`): its innovation sd is the white part a filter has to absorb. The "
              "static rest of the same recording is processed the same way (the same Gaussian kernel and decimation as diagnose, "
              "then the same REML random-walk choice and AR fit), so the ratio compares like with like:", "",
              "| trial | sensor | kernel sigma | static Allan N | static innovation sd | dynamic innovation sd | factor (innovation) | "
              "factor (residual rms / static rms) |", "|---|---|---|---|---|---|---|---|"]
        for r in res["inflation"]:
            for s, v in r["sensors"].items():
                u = "g" if s == "acc" else "rad/s"
                L.append(f"| {r['name']} ({r['static_s']:.0f} s rest) | {s} | {1e3 * v['kernel_sigma_s']:.0f} ms | "
                         f"{', '.join(_fmt(x) for x in v['static_allan_N'])} SI | {', '.join(_fmt(x) for x in v['static_innovation_sd'])} {u} | "
                         f"{', '.join(_fmt(x) for x in v['dynamic_innovation_sd'])} {u} | "
                         f"{', '.join(f'{x:.1f}' for x in v['factor_innovation'])} | {v['factor_rms']:.1f} |")
        fr = {s: [r["sensors"][s]["factor_rms"] for r in res["inflation"]] for s in ("acc", "gyr")}
        L += ["", f"Measured factor (residual rms / static rms, the same band): accelerometer {min(fr['acc']):.0f}-{max(fr['acc']):.0f}x, "
              f"gyroscope {min(fr['gyr']):.0f}-{max(fr['gyr']):.0f}x on the white noise density. This is the number to use: both sides "
              "pass through the same Gaussian kernel, so the ratio of in-band rms is the ratio of in-band noise densities (check: the "
              "smoothed static rms is "
              f"{min(min(a / b for a, b in zip(v['static_smoothed_rms'], v['static_smoothed_rms_expected_from_N'])) for r in res['inflation'] for v in r['sensors'].values()):.2f}-"
              f"{max(max(a / b for a, b in zip(v['static_smoothed_rms'], v['static_smoothed_rms_expected_from_N'])) for r in res['inflation'] for v in r['sensors'].values()):.2f}"
              " x the Allan N / sqrt(2 sqrt(pi) sigma) that white noise through the kernel predicts). The "
              "innovation ratio is shown but not used: smoothed white noise is partly predictable from its own past (the kernel spans "
              "3-5 samples at the decimated rate), so the static innovation sd depends on the kernel width and the AR order "
              f"({_innovation_spread(res['inflation'])}).", "",
              "What the factor holds: everything the sensor model leaves unexplained during motion, not only the IMU: the "
              "reference's own noise (angular rate and specific force derived from optical mocap poses by Gaussian derivatives), "
              "vibration, unmodelled dynamics, in two fast-rotation trials of one IMU. diagnose fits the whole trial, the rest "
              "included, so motion alone would give a somewhat larger factor. It is therefore an upper bound on what the IMU itself "
              "adds and the right order of magnitude for a filter whose measurement model is this crude; it is measured on one IMU "
              "(myon aktos-t) and two trials, not a universal number. The folklore is 10-20x; measured here: accelerometer "
              f"{min(fr['acc']):.0f}-{max(fr['acc']):.0f}x, and for the gyroscope in fast rotation against mocap "
              f"{min(fr['gyr']):.0f}-{max(fr['gyr']):.0f}x."]
    else:
        L.append("Not run in the quick form (diagnose takes 1-3 minutes per trial): see `results/noise.md`.")
    return "\n".join(L) + "\n"


def main(quick: bool) -> None:
    """Write ``results/noise[_quick].{md,json}`` and ``results/noise[_quick]_*.png``."""
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    RESULTS.mkdir(exist_ok=True)
    cov = _coverage(quick, 10 if quick else 100)
    at = _allantools(quick)
    real = _real()
    infl = [] if quick else _inflation(quick)  # diagnose takes 1-3 min per trial: full form only
    prefix = "noise_quick" if quick else "noise"
    res = {"quick": quick, "coverage": cov, "allantools": at, "real": real, "inflation": infl}
    res["figures"] = _figures(prefix, cov, real)
    res["seconds"] = time.perf_counter() - t0
    res["load_start"], res["load_end"] = round(load0, 2), round(os.getloadavg()[0], 2)
    (RESULTS / f"{prefix}.json").write_text(json.dumps(res, indent=1, default=float) + "\n")
    (RESULTS / f"{prefix}.md").write_text(_markdown(res))
    print(f"wrote results/{prefix}.md, .json in {res['seconds']:.0f} s", flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="10 logs per case, a shorter allantools log, no diagnose runs (part d)")
    main(ap.parse_args().quick)
