"""The diagnosis report: the ``report.json`` dict (CONVENTIONS.md schema plus extra fields), the
``report.md`` text and the figures. Only :func:`write_report` touches the file system."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from jaxcal.diagnose import effects as E
from jaxcal.diagnose import vocabulary as V
from jaxcal.diagnose.band import HALF_POWER
from jaxcal.diagnose.core import FORCED, Prepared, SensorResult
from jaxcal.diagnose.core import UNIT_OF as UNIT
from jaxcal.diagnose.frames import lever_arm_frames, rotation_split
from jaxcal.diagnose.locate import allan_deviation, breakdown, whiteness

__all__ = [
    "named_effects",
    "effect_estimate",
    "build_report",
    "build_report_banded",
    "figures_banded",
    "frames_report",
    "promise_violations",
    "report_markdown",
    "figures",
    "write_report",
]


def named_effects(rep: dict) -> set[tuple[str, str]]:
    """The ``(sensor, effect)`` pairs a report names."""
    return {(e["sensor"], e["name"]) for e in rep["effects"]}


def effect_estimate(rep: dict, sensor: str, name: str):
    """A named effect's flat estimate and standard errors (misalignment: its 6 off-diagonal entries;
    saturation: the limit) and its report entry, or ``(None, None, None)`` if not named.

    Args:
        rep: a ``report.json`` dict.
        sensor: ``"acc"`` or ``"gyr"``.
        name: effect name.
    """
    for e in rep["effects"]:
        if e["sensor"] == sensor and e["name"] == name:
            if name == "saturation":
                return np.array([e["params"]["limit"]]), np.array([e["stderr"]["limit"]]), e
            sl, rec = E.slot(sensor, name), V.get(name)
            return rec.to_flat(e["params"][sl.param]), rec.to_flat(e["stderr"][sl.param]), e
    return None, None, None


def _rms(r: np.ndarray, rows: np.ndarray) -> float:
    return float(np.sqrt(np.mean(r[rows] ** 2))) if rows.any() else float("nan")


def _se_params(sensor: str, name: str, se_theta: np.ndarray) -> dict:
    return E.params_from_theta(sensor, name, se_theta)


def build_report(prep: Prepared, results: dict[str, SensorResult], kind: str, runtime_s: float, finish: bool = True) -> dict:
    """The ``report.json`` dict of CONVENTIONS.md (RMS in g / rad/s) with extra diagnostic fields.

    Args:
        prep: the prepared recording.
        results: ``{sensor: SensorResult}``.
        kind: baseline, ``"diag"`` or ``"affine"``.
        runtime_s: wall time to record (s).
        finish: add the cross-sensor parts (frames, plausible ranges, sort); False when
            :func:`build_report_banded` merges per-sensor reports.
    """
    rep: dict = {"baseline": {}, "effects": [], "rejected": [], "warnings": [], "final": {}}
    rep["baseline_kind"] = kind
    rep["n_samples"] = int(len(prep.t))
    rep["dt_s"] = prep.dt
    rep["notes"] = list(prep.notes)
    rep["sensors"] = {}
    if prep.pose_sigma is not None:
        b = prep.band
        rep["reference_band"] = {"sigma_s": prep.pose_sigma, "band_hz": [0.0, HALF_POWER / prep.pose_sigma],
                                 "sigma_by_sensor_s": prep.sigma_by_sensor,
                                 "band_by_sensor_hz": {k: [0.0, HALF_POWER / v] for k, v in (prep.sigma_by_sensor or {}).items()},
                                 "chosen_by": "coherence" if b is not None else "fixed pose_sigma",
                                 "reason": b.reason if b is not None else "pose_sigma given by the caller",
                                 "coherent_edge_hz": None if b is None else b.edge_hz,
                                 "coherent_edge_per_axis_hz": None if b is None else b.axis_edge_hz}
    T0 = float(np.mean(prep.temp)) if prep.temp is not None else None
    for s, r in results.items():
        sd = prep.sensors[s]
        rows = r.fit_rows
        # held-out rms: leave-one-block-out cross-validation (linearised fit), every block predicted
        # by parameters fitted on the other blocks
        rep["baseline"][s] = {"rms": _rms(r.base_all.resid, rows), "heldout_rms": r.heldout_path[0],
                               "heldout_rms_ols": r.heldout_path_ols[0], "unit": UNIT[s]}
        rep["final"][s] = {"rms": _rms(r.final_all.resid, rows), "heldout_rms": r.heldout_path[-1],
                            "heldout_rms_ols": r.heldout_path_ols[-1], "unit": UNIT[s]}
        for k, name in enumerate(r.selected):
            d = r.decisions[name]
            params = E.params_from_theta(s, name, r.final_all.theta)
            se = _se_params(s, name, r.final_all.se_theta)
            if name.startswith("temperature") and T0 is not None:
                params["T0"] = T0
                se["T0"] = 0.0
            rep["effects"].append({
                "name": name, "sensor": s, "params": params, "stderr": se, "unit": E.UNITS[(name, s)],
                "heldout_rms_before": r.heldout_path[k], "heldout_rms_after": r.heldout_path[k + 1],
                "stat": d["stat"], "dof": d["dof"], "log10_p": d["log10_p"], "mds": r.mds.get(name),
                "note": d["reason"], "plausible_max_abs": E.PLAUSIBLE_RANGE.get((name, s)),
                "forced": d["reason"].startswith(FORCED),
                **({"band_check": r.bands[name]} if r.bands and name in r.bands else {}),
            })
        if r.saturation is not None and r.saturation["selected"]:
            rep["effects"].append({
                "name": "saturation", "sensor": s, "params": {"limit": r.saturation["limit"]}, "stderr": {"limit": 0.5},
                "unit": "LSB", "n_clipped": r.saturation["n_clipped"], "stat": r.saturation["stat"], "dof": 1,
                "log10_p": r.saturation["log10_p"], "heldout_rms_before": None, "heldout_rms_after": None,
                "note": "clipped samples excluded from every fit; stderr is the rounding resolution",
            })
        for name, d in r.decisions.items():
            if not d["selected"]:
                rep["rejected"].append({"name": name, "sensor": s, "stat": d["stat"], "dof": d["dof"], "log10_p": d["log10_p"],
                                        "heldout_gain": d["heldout_gain"], "heldout_rms_change": d.get("heldout_rms_change"),
                                        "reason": d["reason"], "mds": r.mds.get(name)})
        if r.saturation is not None and not r.saturation["selected"]:
            rep["rejected"].append({"name": "saturation", "sensor": s, "stat": r.saturation["stat"], "dof": 1,
                                    "log10_p": r.saturation["log10_p"], "reason": "not significant"})
        rep["warnings"] += r.warnings
        inp = sd.inp
        rep["sensors"][s] = {
            "noise": {"ar_order": r.ar_orders, "ima_theta": r.ar_theta, "innovation_sd": r.ar_sigma, "whitened_s2_final": r.final_all.s2},
            "baseline_params": np.asarray(r.base_all.beta).tolist(),
            "estimator": {"fit": "noise-model (AR + random walk) least squares, Huber-reweighted once (3 robust sd)",
                          "downweighted_rows": int(r.final_all.n_downweighted),
                          "stderr": "larger of model-based and 8-block sandwich"},
            "mds": r.mds,
            "mds_units": {n: E.UNITS.get((n, s)) for n in r.mds},
            "locate": breakdown(r.base_all.resid, rows, prep.t, np.asarray(inp.w), np.asarray(inp.wdot), prep.temp, prep.dt),
            "whiteness_before": whiteness(r.base_all.resid, rows, prep.dt),
            "whiteness_after": whiteness(r.final_all.resid, rows, prep.dt),
        }
    if finish:
        _finish(rep, results, kind)
    rep["runtime_s"] = runtime_s
    return rep


def _finish(rep: dict, results: dict[str, SensorResult], kind: str) -> None:
    """What a report holds about all its sensors together: the frames (affine), the plausible
    ranges, and the effects sorted strongest first (estimates on request last)."""
    if kind == "affine":
        rep["frames"] = frames_report(results)
    rep["plausible_range"] = {f"{s} {n}": {"max_abs": v, "unit": E.UNITS[(n, s)]} for (n, s), v in E.PLAUSIBLE_RANGE.items() if s in results}
    rep["effects"].sort(key=lambda e: (np.inf if e.get("forced") else e["log10_p"]) if np.isfinite(e["log10_p"]) else np.inf)


def build_report_banded(preps: dict[str, Prepared], results: dict[str, SensorResult], kind: str, runtime_s: float) -> dict:
    """:func:`build_report` when each sensor was prepared in its own band
    (:func:`jaxcal.diagnose.core.diagnose_banded`): one report per sensor, merged; the frames
    (rotation, lever arm) from all sensors together. ``n_samples``/``dt_s`` are the gyroscope's
    (each sensor's own under ``sensors``).

    Args:
        preps: ``{sensor: Prepared}``.
        results: ``{sensor: SensorResult}``.
        kind: baseline, ``"diag"`` or ``"affine"``.
        runtime_s: wall time to record (s).
    """
    ids = {id(p) for p in preps.values()}
    if len(ids) == 1:
        return build_report(next(iter(preps.values())), results, kind, runtime_s)
    order = sorted(results, key=lambda k: k != "gyr")
    rep = None
    for s in order:
        r = build_report(preps[s], {s: results[s]}, kind, runtime_s, finish=False)
        r["sensors"][s]["n_samples"], r["sensors"][s]["dt_s"] = r["n_samples"], r["dt_s"]
        if rep is None:
            rep = r
            continue
        for k in ("baseline", "final", "sensors"):
            rep[k].update(r[k])
        for k in ("effects", "rejected", "warnings"):
            rep[k] += r[k]
        rep["notes"] += [n for n in r["notes"] if n not in rep["notes"]]
    _finish(rep, results, kind)
    return rep


def figures_banded(preps: dict[str, Prepared], results: dict[str, SensorResult]) -> dict:
    """:func:`figures` per sensor, each with its own :class:`Prepared`.

    Args:
        preps: ``{sensor: Prepared}``.
        results: ``{sensor: SensorResult}``.
    """
    out = {}
    for s in results:
        out.update(figures(preps[s], {s: results[s]}))
    return out


def frames_report(results: dict[str, SensorResult]) -> dict:
    """Affine baselines split into rotation and remainder per sensor (:func:`rotation_split`);
    ``R_ref_imu`` from the gyroscope when diagnosed (its rotation is the better determined), and
    the lever arm in both frames when the accelerometer has one."""
    out: dict = {}
    for s, r in results.items():
        f = r.frame_fit if r.frame_fit is not None else r.final_all
        cov = None if f.cov is None else f.cov[:9, :9]
        out[s] = rotation_split(np.asarray(f.beta[:9]).reshape(3, 3), cov)
    src = "gyr" if "gyr" in out else "acc"
    out["R_ref_imu"] = out[src]["R_ref_imu"]
    out["R_ref_imu_from"] = src
    if "acc" in results:
        a = results["acc"]
        sl = E.slot("acc", "lever_arm")
        if "lever_arm" in a.selected:
            th, se = a.final_all.theta, a.final_all.se_theta
            out["lever_arm"] = lever_arm_frames(th[sl.start : sl.start + 3], se[sl.start : sl.start + 3], out["R_ref_imu"])
    return out


def promise_violations(rep: dict) -> list[str]:
    """Where a report breaks the promise of ``diagnose`` (empty when it keeps it):

    * every named effect lowered the held-out rms the report prints (``after < before``);
    * each sensor's final held-out rms is at most its baseline's;
    * every named estimate lies inside its plausible range (``plausible_max_abs``).

    Effects estimated on request (``forced``, ``jaxcal align``) are estimates, not names: they are
    exempt, and so is the final-vs-baseline check of a sensor that has one.
    """
    out = []
    forced = set()
    for e in rep.get("effects", []):
        if e.get("forced"):
            forced.add(e["sensor"])
            continue
        b, a = e.get("heldout_rms_before"), e.get("heldout_rms_after")
        if b is not None and a is not None and not a < b:
            out.append(f"{e['sensor']} {e['name']}: held-out rms {b:.6g} -> {a:.6g}")
        lim = e.get("plausible_max_abs")
        if lim is not None:
            v = np.concatenate([np.ravel(np.asarray(p, float)) for k, p in e["params"].items() if k != "T0"])
            if np.max(np.abs(v)) > lim:
                out.append(f"{e['sensor']} {e['name']}: estimate {np.max(np.abs(v)):.3g} beyond the plausible {lim:g}")
    for s, f in rep.get("final", {}).items():
        b = rep["baseline"][s]["heldout_rms"]
        if s not in forced and f["heldout_rms"] > b:
            out.append(f"{s}: final held-out rms {f['heldout_rms']:.6g} above the baseline's {b:.6g}")
    return out


def _fmt(v) -> str:
    a = np.asarray(v, dtype=float)
    if a.ndim == 0:
        return f"{float(a):.4g}"
    return "[" + ", ".join(_fmt(x) for x in a) + "]"


def report_markdown(rep: dict) -> str:
    """``report.md``: a short engineering report of a diagnosis."""
    L = ["# jaxcal diagnose report", "",
         f"Baseline `{rep['baseline_kind']}`, {rep['n_samples']} samples at {1 / rep['dt_s']:.1f} Hz, run time {rep['runtime_s']:.1f} s.", ""]
    for n in rep["notes"]:
        L.append(f"- note: {n}")
    if rep.get("reference_band"):
        b = rep["reference_band"]
        L.append(f"- band used: 0-{b['band_hz'][1]:.1f} Hz (Gaussian sigma {b['sigma_s'] * 1e3:.0f} ms, {b['chosen_by']}): {b['reason']}")
    L += ["", "## Fit before and after (physical units; held-out = time blocks the fit never saw)", "",
          "Held-out rms with the noise model's (GLS) fit; in brackets with a least-squares fit on the physical residual.", "",
          "| sensor | baseline rms | baseline held-out rms | final rms | final held-out rms |", "|---|---|---|---|---|"]
    for s in rep["baseline"]:
        b, f = rep["baseline"][s], rep["final"][s]
        L.append(f"| {s} ({b['unit']}) | {b['rms']:.4g} | {b['heldout_rms']:.4g} ({b['heldout_rms_ols']:.4g}) | {f['rms']:.4g} "
                 f"| {f['heldout_rms']:.4g} ({f['heldout_rms_ols']:.4g}) |")
    L += ["", "## Where the mismatch lives (baseline residual)", ""]
    for s, d in rep["sensors"].items():
        w = d["locate"]["where"]
        L.append(f"- {s}: largest in {w['breakdown']} bin `{w['bin']}` (rms {w['rms_ratio']:.2f}x overall); "
                 f"frequency band {w['band_hz'][0]:g}-{w['band_hz'][1]:g} Hz holds {w['band_excess']:.2f}x its white share; "
                 f"per-axis rms {_fmt(d['locate']['axis'])}.")
    L += ["", "## Named effects (strongest first)", ""]
    if not rep["effects"]:
        L.append("None: no effect of the vocabulary is supported by the data (the baseline explains it).")
    else:
        L += ["| effect | sensor | parameters (unit) | std. error | held-out rms before -> after | chi2 (dof), log10 p |", "|---|---|---|---|---|---|"]
        for e in rep["effects"]:
            ps = "; ".join(f"{k} = {_fmt(v)}" for k, v in e["params"].items())
            se = "; ".join(f"{k}: {_fmt(v)}" for k, v in e["stderr"].items())
            hb = "-" if e["heldout_rms_before"] is None else f"{e['heldout_rms_before']:.4g} -> {e['heldout_rms_after']:.4g}"
            L.append(f"| {e['name']} | {e['sensor']} | {ps} ({e['unit']}) | {se} | {hb} | {e['stat']:.1f} ({e['dof']}), {e['log10_p']:.1f} |")
    fr = rep.get("frames")
    if fr:
        L += ["", "## Frames (affine baseline split into rotation and remainder)", "",
              "| sensor | rotation (deg) | rotation vector, IMU from reference (deg) | scale | non-orthogonality (rad) |", "|---|---|---|---|---|"]
        for s in ("acc", "gyr"):
            if s in fr:
                f = fr[s]
                rot = f"{f['rotation_deg']:.3f}" + (f" +- {1.96 * f['rotation_deg_stderr']:.3f}" if "rotation_deg_stderr" in f else "")
                L.append(f"| {s} | {rot} | {_fmt(f['rotvec_imu_ref_deg'])} | {_fmt(f['scale'])} | {_fmt(f['non_orthogonality_rad'])} |")
        if "lever_arm" in fr:
            la = fr["lever_arm"]
            L += ["", f"Lever arm (IMU relative to the reference point): {_fmt(la['r_ref_frame_m'])} m in the reference frame "
                  f"(s.e. {_fmt(la['r_ref_frame_stderr_m'])}), {_fmt(la['r_imu_frame_m'])} m in the IMU frame; |r| = {la['norm_m']:.4f} m."]
    L += ["", "## Tested and rejected", "", "| effect | sensor | chi2 (dof) | log10 p | reason | min. detectable (per component) |", "|---|---|---|---|---|---|"]
    for e in rep["rejected"]:
        m = e.get("mds") or {}
        md = _fmt(m["components"]) if "components" in m else "-"
        L.append(f"| {e['name']} | {e['sensor']} | {e['stat']:.1f} ({e['dof']}) | {e['log10_p']:.2f} | {e['reason']} | {md} |")
    L += ["", "## Warnings", ""]
    L += [f"- {w}" for w in rep["warnings"]] or ["- none"]
    L += ["", "## Residual whiteness (Ljung-Box Q, 20 lags; about 20 if white)", ""]
    for s, d in rep["sensors"].items():
        L.append(f"- {s}: before {_fmt(d['whiteness_before']['ljung_box_q20'])}, after {_fmt(d['whiteness_after']['ljung_box_q20'])}; "
                 f"AR noise orders {d['noise']['ar_order']}")
    return "\n".join(L) + "\n"


def figures(prep: Prepared, results: dict[str, SensorResult]) -> dict:
    """Matplotlib figures: residual vs time, vs rate and temperature, fitted-effect check, ADEV.

    Args:
        prep: the prepared recording.
        results: ``{sensor: SensorResult}``.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    out = {}
    for s, r in results.items():
        sd = prep.sensors[s]
        rows = r.fit_rows
        u = UNIT[s]
        fig, ax = plt.subplots(2, 2, figsize=(11, 7.5))
        t = prep.t
        for i, c in enumerate("xyz"):
            ax[0, 0].plot(t[rows], r.base_all.resid[rows, i], ",", alpha=0.5, label=f"baseline {c}")
        for i, c in enumerate("xyz"):
            ax[0, 0].plot(t[rows], r.final_all.resid[rows, i], ",", alpha=0.5, color="k" if i == 0 else None, label=f"final {c}" if i == 0 else None)
        ax[0, 0].set(xlabel="time (s)", ylabel=f"residual ({u})", title=f"{s}: residual vs time")
        ax[0, 0].legend(markerscale=20, fontsize=7)
        wn = np.linalg.norm(np.asarray(sd.inp.w), axis=1)
        rn_b = np.linalg.norm(r.base_all.resid, axis=1)
        rn_f = np.linalg.norm(r.final_all.resid, axis=1)
        edges = np.quantile(wn[rows], np.linspace(0, 1, 16))
        idx = np.clip(np.searchsorted(edges, wn, side="right") - 1, 0, 14)
        bins = [rows & (idx == k) for k in range(15) if (rows & (idx == k)).any()]  # tied rates leave empty bins
        cen = [np.median(wn[b]) for b in bins]
        ax[0, 1].plot(cen, [np.sqrt(np.mean(rn_b[b] ** 2)) for b in bins], "o-", label="baseline")
        ax[0, 1].plot(cen, [np.sqrt(np.mean(rn_f[b] ** 2)) for b in bins], "s-", label="final")
        ax[0, 1].set(xlabel="|rate| (rad/s)", ylabel=f"residual rms ({u})", title="residual vs motion regime")
        ax[0, 1].legend()
        # fitted-effect check: baseline residual vs what the named effects predict
        contrib = r.base_all.resid - r.final_all.resid
        if r.selected:
            for i, c in enumerate("xyz"):
                xx, yy = contrib[rows, i], r.base_all.resid[rows, i]
                q = np.quantile(xx, np.linspace(0, 1, 21))
                k = np.clip(np.searchsorted(q, xx, side="right") - 1, 0, 19)
                js = [j for j in range(20) if (k == j).any()]
                ax[1, 0].plot([xx[k == j].mean() for j in js], [yy[k == j].mean() for j in js], "o", label=f"axis {c} (binned)")
            lim = np.abs(contrib[rows]).max()
            ax[1, 0].plot([-lim, lim], [-lim, lim], "k--", label="y = x")
            ax[1, 0].set(title="baseline residual vs named-effect prediction")
        else:
            if prep.temp is not None:
                ax[1, 0].plot(prep.temp[rows], r.base_all.resid[rows], ",")
                ax[1, 0].set(title="baseline residual vs temperature (no effect named)")
            else:
                ax[1, 0].set(title="no effect named")
        ax[1, 0].set(xlabel=f"predicted effect ({u})" if r.selected else "temperature (degC)", ylabel=f"baseline residual ({u})")
        if ax[1, 0].get_legend_handles_labels()[0]:
            ax[1, 0].legend(fontsize=7)
        for res, lab, sty in ((r.base_all.resid, "baseline", "-"), (r.final_all.resid, "final", "--")):
            for i, c in enumerate("xyz"):
                ta, ad = allan_deviation(res[rows, i], prep.dt)
                ax[1, 1].loglog(ta, ad, sty, label=f"{lab} {c}")
        ax[1, 1].set(xlabel="averaging time tau (s)", ylabel=f"Allan deviation ({u})", title="residual Allan deviation")
        ax[1, 1].legend(fontsize=7, ncol=2)
        fig.tight_layout()
        out[f"residuals_{s}"] = fig
    return out


def write_report(out_dir: str | os.PathLike, rep: dict, figs: dict | None = None) -> None:
    """Write ``report.json``, ``report.md`` and ``<name>.png`` figures into ``out_dir``.

    Args:
        out_dir: output directory (created if missing).
        rep: the ``report.json`` dict.
        figs: ``{name: matplotlib figure}``; None: none.
    """
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)

    def default(o):
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        raise TypeError(type(o))

    (d / "report.json").write_text(json.dumps(rep, indent=1, default=default, allow_nan=True))
    (d / "report.md").write_text(report_markdown(rep))
    for name, fig in (figs or {}).items():
        fig.savefig(d / f"{name}.png", dpi=110)
