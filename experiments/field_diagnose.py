"""``jaxcal diagnose`` without a reference on real recordings (issue 26 part 1, "Proof").

``python -m experiments.field_diagnose [--quick]`` writes ``results/field_diagnose.{md,json}``
(quick: ``results/field_diagnose_quick.*``, git-ignored). Three parts, library calls only:

1. **Every real recording in ``data/``** (its first 200 s; 60 s quick) through the reference-free mode
   (:func:`jaxcal.diagnose.diagnose_recording` with ``reference="none"``): what it names, its
   warnings, and whether the report keeps the promise
   (:func:`jaxcal.diagnose.report.promise_violations`). Quick: the first 60 s of each.
2. **BROAD beside its own mocap**: the accelerometer's time offset relative to the gyroscope on
   trials 07 and 21 against the reference mode's 2.81 - 4.16 = -1.35 ms; agreement means within
   3 standard errors or 0.5 ms.
3. **Concealed into real recordings** (:mod:`jaxcal.diagnose.stress`): the accelerometer moved
   3-10 cm on the same rigid body (from the recording's own calibrated gyroscope), the
   accelerometer stream delayed 2-20 ms, a g-sensitivity of 0.05-0.3 (deg/s)/g from the calibrated
   accelerometer. Each case is compared with the same stretch unmodified: the estimate minus the
   unmodified estimate (0 where the unmodified report does not name it) must lie within the
   simultaneous 95 % interval of the case's standard errors (Bonferroni over the components), with
   nothing else newly named. Then the detection rate against size in multiples of the unmodified
   report's minimum detectable size (:func:`jaxcal.diagnose.conceal.effect_at_mds`).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy import stats

from jaxcal.diagnose import conceal as CO
from jaxcal.diagnose import diagnose_recording
from jaxcal.diagnose import noref as N
from jaxcal.diagnose.report import promise_violations
from jaxcal.recording import load_recording, take_rows

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "results"

RECORDINGS = (
    ("Xsens multipos (imu_tk)", "data/imu_tk_xsens_multipos/xsens.npz"),
    ("MPU-6050 calibration", "data/tomisuarez_mpu6050/calibration.npz"),
    ("imucal Ferraris session", "data/imucal_ferraris_example/session.npz"),
    ("x-io Fusion sensor data", "data/xio_fusion_sensor_data/sensor_data.npz"),
    ("TUM-VI room1", "data/tumvi_room1_512_16/room1.npz"),
    ("BROAD 07", "data/broad_07_undisturbed_fast_rotation_B/07_undisturbed_fast_rotation_B.npz"),
    ("BROAD 21", "data/broad_21_undisturbed_fast_combined/21_undisturbed_fast_combined.npz"),
)
MAX_S = 200.0  # full run: the first 200 s of each recording (all of every one but Xsens's 512 s)
BROAD_REF_MS = 2.81 - 4.16  # reference mode on BROAD: acc and gyro behind the mocap (ms)

# (name, sensor, param, range of sizes, unit for the table): the concealed effects of the issue
CONCEAL = (("lever_arm", "acc", "r", (0.03, 0.10), "m"),
           ("time_offset", "acc", "tau", (0.002, 0.020), "s"),
           ("g_sensitivity", "gyr", "G", (np.radians(0.05), np.radians(0.3)), "(rad/s)/g"))


def _crop(rec, t0: float, dur: float | None):
    """The stretch ``[t0, t0 + dur)`` s of ``rec`` without its reference (None: all of it)."""
    rec = rec.replace(acc_ref=None, gyr_ref=None, pos_ref=None, quat_ref=None)
    if dur is None and t0 == 0.0:
        return rec
    t = rec.t - rec.t[0]
    return take_rows(rec, (t >= t0) & (t < t0 + (np.inf if dur is None else dur)))


def _summary(rep: dict) -> dict:
    return {"effects": [{k: e.get(k) for k in ("name", "sensor", "params", "stderr", "heldout_rms_before", "heldout_rms_after")}
                        for e in rep["effects"]],
            "baseline": rep["baseline"], "final": rep["final"], "warnings": rep["warnings"], "notes": rep["notes"],
            "self_reference": rep.get("self_reference"), "promise_violations": promise_violations(rep),
            "runtime_s": rep.get("runtime_s")}


def run_recordings(quick: bool) -> dict:
    """Part 1: every recording of :data:`RECORDINGS` (quick: its first 60 s; full: :data:`MAX_S`)."""
    out = {}
    for label, path in RECORDINGS:
        rec = _crop(load_recording(ROOT / path), 0.0, 60.0 if quick else MAX_S)
        t0 = time.perf_counter()
        try:
            rep = diagnose_recording(rec, reference="none")
        except ValueError as err:
            out[label] = {"path": path, "error": str(err), "runtime_s": time.perf_counter() - t0}
            continue
        out[label] = {"path": path, "seconds": float(rec.t[-1] - rec.t[0]), "n": int(len(rec.t)), "report": _summary(rep),
                      "report_full": rep if label.startswith("BROAD") else None, "runtime_s": time.perf_counter() - t0}
        print(f"[field_diagnose] {label}: {[(e['sensor'], e['name']) for e in rep['effects']]} "
              f"promise {'kept' if not promise_violations(rep) else 'BROKEN'} ({time.perf_counter() - t0:.0f} s)", flush=True)
    return out


def broad_offsets(recs: dict, quick: bool) -> dict:
    """Part 2: the accelerometer's time offset relative to the gyroscope on both BROAD trials,
    estimated on request (forced) so that its interval is reported whether or not the tests name
    it, beside part 1's unforced report (named or not) and its per-band estimates."""
    out = {}
    for label, path in RECORDINGS[5:]:
        rec = _crop(load_recording(ROOT / path), 0.0, 60.0 if quick else MAX_S)
        t0 = time.perf_counter()
        rep = diagnose_recording(rec, reference="none", force={"acc": ("time_offset",)})
        e = _find(rep, "acc", "time_offset")
        named = any((x["sensor"], x["name"]) == ("acc", "time_offset") for x in recs.get(label, {}).get("report", {}).get("effects", []))
        tau, se = 1e3 * float(e["params"]["tau"]), 1e3 * float(e["stderr"]["tau"])
        bc = e.get("band_check") or {}
        out[label] = {"named_unforced": named, "tau_ms": tau, "stderr_ms": se, "reference_ms": BROAD_REF_MS, "diff_ms": tau - BROAD_REF_MS,
                      "agrees": abs(tau - BROAD_REF_MS) <= max(3 * se, 0.5),
                      "stderr_refit_ms": 1e3 * float(np.ravel(bc.get("se_refit", [np.nan]))[0]),
                      "between_band_sd_ms": 1e3 * float(np.sqrt(np.ravel(bc.get("tau2", [np.nan]))[0])),
                      "bands_hz": bc.get("bands_hz"), "band_tau_ms": (1e3 * np.ravel(bc["est"])).tolist() if bc else None,
                      "runtime_s": time.perf_counter() - t0}
        print(f"[field_diagnose] {label} forced acc time_offset {tau:+.2f} +- {se:.2f} ms", flush=True)
    return out


def _vec(e: dict | None, param: str, size: int) -> tuple[np.ndarray, np.ndarray]:
    if e is None:
        return np.zeros(size), np.full(size, np.nan)
    return np.ravel(np.asarray(e["params"][param], float)), np.ravel(np.asarray(e["stderr"][param], float))


def _find(rep: dict, sensor: str, name: str) -> dict | None:
    return next((e for e in rep["effects"] if (e["sensor"], e["name"]) == (sensor, name)), None)


def _apply(rec, name: str, v: np.ndarray, ref: N.SelfReference):
    if name == "lever_arm":
        return CO.conceal_lever_arm_gyro(rec, v, ref.gyr_cal, ref.acc_cal)
    if name == "time_offset":
        return CO.conceal_shift(rec, float(v[0]), ("acc",))
    return CO.conceal_gsens_cal(rec, v, ref.acc_cal, ref.gyr_cal)


def _case(base, base_forced: dict, ref: N.SelfReference, name: str, sensor: str, param: str, v: np.ndarray) -> dict:
    """Diagnose ``base`` with ``v`` concealed, the effect estimated on request (forced), and compare
    with the unmodified recording's forced estimate: coverage of the difference by the interval, and
    what else is newly named."""
    try:
        rep = diagnose_recording(_apply(base, name, v, ref), reference="none", force={sensor: (name,)})
    except (ValueError, AssertionError) as err:  # a refusal, or a broken promise under the test suite's checker
        return {"name": name, "truth": v.tolist(), "estimate_minus_unmodified": [], "stderr": [], "z": None,
                "covered": False, "newly_named_else": [], "promise": False, "error": str(err)}
    est, se = _vec(_find(rep, sensor, name), param, v.size)
    est0, _ = _vec(_find(base_forced, sensor, name), param, v.size)
    diff = est - est0
    z = float(stats.norm.isf(0.025 / v.size))  # simultaneous 95 % over the components (Bonferroni)
    named0 = {(x["sensor"], x["name"]) for x in base_forced["effects"]}
    extra = sorted(f"{x['sensor']} {x['name']}" for x in rep["effects"] if (x["sensor"], x["name"]) not in named0 | {(sensor, name)})
    return {"name": name, "truth": v.tolist(), "estimate_minus_unmodified": diff.tolist(), "stderr": se.tolist(), "z": z,
            "covered": bool(np.all(np.abs(diff - v) <= z * se)), "newly_named_else": extra, "promise": promise_violations(rep) == []}


def _detect(base, base_rep: dict, ref: N.SelfReference, name: str, sensor: str, v: np.ndarray) -> dict:
    """Diagnose ``base`` with ``v`` concealed, nothing forced: is the effect named, and what else?"""
    rep = diagnose_recording(_apply(base, name, v, ref), reference="none")
    named0 = {(x["sensor"], x["name"]) for x in base_rep["effects"]}
    extra = sorted(f"{x['sensor']} {x['name']}" for x in rep["effects"] if (x["sensor"], x["name"]) not in named0 | {(sensor, name)})
    return {"name": name, "truth": v.tolist(), "named": _find(rep, sensor, name) is not None, "newly_named_else": extra,
            "promise": promise_violations(rep) == []}


def _stretches(quick: bool) -> list[tuple[str, str, float, float]]:
    """(label, path, start s, duration s) of the real stretches the effects are concealed into."""
    if quick:
        return [("imucal session 0-60 s", RECORDINGS[2][1], 0.0, 60.0)]
    # BROAD 07 starts with a 24-s rest: a stretch with motion. (Xsens would need about 130 s for the 9 rests of its multi-position calibration: too slow for 2 shared cores)
    return [("imucal session (all 101 s)", RECORDINGS[2][1], 0.0, 200.0), ("BROAD 07 20-50 s", RECORDINGS[5][1], 20.0, 30.0)]


def run_concealment(quick: bool, seed: int = 0) -> dict:
    """Part 3: coverage cases (sizes drawn from the issue's ranges; the effect estimated on request
    in the concealed and the unmodified stretch) and the detection rate at multiples of the minimum
    detectable size (nothing forced), on each stretch of :func:`_stretches`."""
    rng = np.random.default_rng(seed)
    n_cov = 1 if quick else 3
    multiples = (1.0, 2.0, 4.0)
    out = {}
    for label, path, t0, dur in _stretches(quick):
        base = _crop(load_recording(ROOT / path), t0, dur)
        ref = N.self_reference(base)
        base_rep = diagnose_recording(base, reference="none")
        cases, det = [], []
        for name, sensor, param, (lo, hi), _ in CONCEAL:
            if sensor == "gyr" and "gyr" not in base_rep["baseline"]:
                continue  # fewer than 2 rests: the gyroscope is not diagnosed here
            base_forced = diagnose_recording(base, reference="none", force={sensor: (name,)})
            size = 3 if name == "lever_arm" else 1 if name == "time_offset" else 9
            for _ in range(n_cov):
                u = rng.standard_normal(size)
                mag = rng.uniform(lo, hi)
                v = mag * u / np.linalg.norm(u)  # a random direction (one component: a random sign) of size mag
                c = _case(base, base_forced, ref, name, sensor, param, np.atleast_1d(v))
                c["size"] = float(mag)
                cases.append(c)
                print(f"[field_diagnose] {label} {name} {mag:.4g}: covered {c['covered']} else {c['newly_named_else']}", flush=True)
            mds = base_rep["sensors"][sensor]["mds"].get(name)
            if mds is None:
                continue
            for m in multiples:
                _, _, flat = CO.effect_at_mds(rng, base_rep, sensor, name, m, np.zeros((1, 3)))
                c = _detect(base, base_rep, ref, name, sensor, np.asarray(flat, float))
                c["mds_multiple"] = m
                c["size"] = float(np.linalg.norm(flat))
                det.append(c)
                print(f"[field_diagnose] {label} {name} {m:g} x MDS: named {c['named']}", flush=True)
        out[label] = {"base_effects": [(e["sensor"], e["name"]) for e in base_rep["effects"]], "coverage_cases": cases,
                      "detection": det, "base_promise": promise_violations(base_rep) == []}
    return out


def _sci(v) -> str:
    return "[" + ", ".join(f"{float(x):.2g}" for x in np.ravel(np.asarray(v, float))) + "]"


def _fmt_ms(v: float) -> str:
    return f"{v:+.2f}"


def markdown(res: dict) -> str:
    L = ["# `diagnose` without a reference on real recordings (issue 26 part 1)", "",
         f"`python -m experiments.field_diagnose{' --quick' if res['quick'] else ''} [--part recordings|concealment]`: "
         + ", ".join(f"{k} {v:.0f} s" for k, v in res["runtime_s_by_part"].items())
         + " on this machine (2 CPU cores shared with other jobs). Every figure below comes from that run.", "",
         "## 1. Every real recording through the reference-free mode", "",
         "| recording | seconds | calibration from | rests | named effects | warnings | promise | s |", "|---|---|---|---|---|---|---|---|"]
    for label, r in res["recordings"].items():
        if "error" in r:
            L.append(f"| {label} | - | - | - | refused: {r['error']} | - | (no report) | {r['runtime_s']:.0f} |")
            continue
        rep = r["report"]
        sr = rep["self_reference"] or {}
        named = ", ".join(f"{e['sensor']} {e['name']}" for e in rep["effects"]) or "none"
        trans = "translational acceleration; " if any("translational acceleration" in w for w in rep["warnings"]) else ""
        L.append(f"| {label} | {r['seconds']:.0f} | {sr.get('calibration_from')} | {sr.get('n_rests')} | {named} | "
                 f"{trans}{len(rep['warnings'])} | {'kept' if not rep['promise_violations'] else 'BROKEN: ' + '; '.join(rep['promise_violations'])} | "
                 f"{r['runtime_s']:.0f} |")
    L += ["", "Held-out rms, baseline -> final (acc in mg, gyr in mrad/s):", ""]
    for label, r in res["recordings"].items():
        if "error" in r:
            continue
        rep = r["report"]
        parts = [f"{s} {1e3 * rep['baseline'][s]['heldout_rms']:.3f} -> {1e3 * rep['final'][s]['heldout_rms']:.3f}" for s in rep["baseline"]]
        L.append(f"- {label}: " + "; ".join(parts))
    L += ["", "## 2. BROAD: accelerometer time offset relative to the gyroscope", "",
          f"Reference mode (mocap): acc 2.81 ms and gyro 4.16 ms behind the mocap, so {BROAD_REF_MS:+.2f} ms relative. "
          "Agreement: within 3 standard errors or 0.5 ms. The offset is estimated on request (forced), so its interval is "
          "reported whether or not the tests name it; its standard error includes the disagreement of the motion's "
          "frequency bands (`jaxcal.diagnose.band_pool`). 'Named' is part 1's unforced report.", "",
          "| trial | named | tau (ms) | stderr (ms) | of which refit / between bands (ms) | minus -1.35 ms | agrees | per band (ms) |",
          "|---|---|---|---|---|---|---|---|"]
    for label, b in res["broad"].items():
        bands = ", ".join(f"{lo:g}-{hi:g} Hz {v:+.1f}" for (lo, hi), v in zip(b.get("bands_hz") or [], b.get("band_tau_ms") or []))
        L.append(f"| {label} | {'yes' if b['named_unforced'] else 'no'} | {_fmt_ms(b['tau_ms'])} | {b['stderr_ms']:.2f} | "
                 f"{b['stderr_refit_ms']:.2f} / {b['between_band_sd_ms']:.2f} | {_fmt_ms(b['diff_ms'])} | {'yes' if b['agrees'] else 'no'} | {bands} |")
    allc = [x for c in res["concealment"].values() for x in c["coverage_cases"]]
    L += ["", "## 3. Concealed into real stretches", "",
          f"All stretches: {sum(x['covered'] for x in allc)} of {len(allc)} coverage cases covered "
          f"({100 * sum(x['covered'] for x in allc) / max(len(allc), 1):.0f} %; goal 90 %), "
          f"{sum(not x['newly_named_else'] for x in allc)} of {len(allc)} named nothing else new.", ""]
    for label, c in res["concealment"].items():
        cases = c["coverage_cases"]
        n_cov = sum(x["covered"] for x in cases)
        n_clean = sum(not x["newly_named_else"] for x in cases)
        L += [f"### {label}", "", f"Unmodified: {', '.join(' '.join(e) for e in c['base_effects']) or 'nothing'} named.", "",
              f"Coverage: in {n_cov} of {len(cases)} cases the estimate minus the unmodified estimate (both estimated on request) "
              f"lies inside the simultaneous 95 % interval; {n_clean} of {len(cases)} named nothing else new.", "",
              "| effect | size | estimate - unmodified | truth | stderr | covered | else newly named |", "|---|---|---|---|---|---|---|"]
        for x in cases:
            L.append(f"| {x['name']} | {x['size']:.4g} | {np.array2string(np.asarray(x['estimate_minus_unmodified']), precision=4)} | "
                     f"{np.array2string(np.asarray(x['truth']), precision=4)} | {_sci(x['stderr'])} | "
                     f"{x['covered']} | {', '.join(x['newly_named_else']) or '-'} |")
        L += ["", "Detection against size (multiples of the unmodified report's minimum detectable size; nothing forced):", "",
              "| effect | x MDS | size | named | else newly named |", "|---|---|---|---|---|"]
        for x in c["detection"]:
            L.append(f"| {x['name']} | {x['mds_multiple']:g} | {x['size']:.3g} | {x['named']} | {', '.join(x['newly_named_else']) or '-'} |")
        L.append("")
    return "\n".join(L) + "\n"


def main(quick: bool = False, out: str | Path = RESULTS, part: str = "all") -> None:
    """Run and write ``OUT/field_diagnose.{json,md}`` (quick: ``field_diagnose_quick.*``).

    Args:
        quick: the first 60 s of each recording, one stretch (imucal's session), one case per effect, 1-2 x MDS.
        out: output directory.
        part: ``"recordings"`` (parts 1-2), ``"concealment"`` (part 3) or ``"all"``; a partial run
            keeps the other part of an existing JSON.
    """
    out = Path(out)
    out.mkdir(exist_ok=True)
    stem = "field_diagnose_quick" if quick else "field_diagnose"
    js = out / f"{stem}.json"
    res = json.loads(js.read_text()) if part != "all" and js.exists() else {}
    res["quick"] = quick
    res.setdefault("runtime_s_by_part", {})
    if part in ("all", "recordings"):
        t0 = time.perf_counter()
        recs = run_recordings(quick)
        res["broad"] = broad_offsets(recs, quick)
        for r in recs.values():
            r.pop("report_full", None)
        res["recordings"] = recs
        res["runtime_s_by_part"]["recordings"] = time.perf_counter() - t0
    if part in ("all", "concealment"):
        t0 = time.perf_counter()
        res["concealment"] = run_concealment(quick)
        res["runtime_s_by_part"]["concealment"] = time.perf_counter() - t0
    res["runtime_s"] = sum(res["runtime_s_by_part"].values())
    js.write_text(json.dumps(res, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    if "recordings" in res and "concealment" in res:
        (out / f"{stem}.md").write_text(markdown(res))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="first 60 s of each recording; one stretch; fewer cases")
    ap.add_argument("--out", default=str(RESULTS), help="output directory (default results/)")
    ap.add_argument("--part", choices=("all", "recordings", "concealment"), default="all")
    a = ap.parse_args()
    main(a.quick, a.out, a.part)
