"""The diagnosis report: the ``report.json`` dict (CONVENTIONS.md schema plus extra fields), the
``report.md`` text and the figures. Only :func:`write_report` touches the file system."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from jaxcal.diagnose import effects as E
from jaxcal.diagnose.core import Prepared, SensorResult
from jaxcal.diagnose.locate import allan_deviation, breakdown, whiteness

UNIT = {"acc": "g", "gyr": "rad/s"}


def _rms(r: np.ndarray, rows: np.ndarray) -> float:
    return float(np.sqrt(np.mean(r[rows] ** 2))) if rows.any() else float("nan")


def _se_params(sensor: str, name: str, se_theta: np.ndarray) -> dict:
    return E.params_from_theta(sensor, name, se_theta)


def build_report(prep: Prepared, results: dict[str, SensorResult], kind: str, runtime_s: float) -> dict:
    """The ``report.json`` dict of CONVENTIONS.md (RMS in g / rad/s) with extra diagnostic fields."""
    rep: dict = {"baseline": {}, "effects": [], "rejected": [], "warnings": [], "final": {}}
    rep["baseline_kind"] = kind
    rep["n_samples"] = int(len(prep.t))
    rep["dt_s"] = prep.dt
    rep["notes"] = list(prep.notes)
    rep["sensors"] = {}
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
                "note": d["reason"],
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
                                        "heldout_gain": d["heldout_gain"], "reason": d["reason"], "mds": r.mds.get(name)})
        if r.saturation is not None and not r.saturation["selected"]:
            rep["rejected"].append({"name": "saturation", "sensor": s, "stat": r.saturation["stat"], "dof": 1,
                                    "log10_p": r.saturation["log10_p"], "reason": "not significant"})
        rep["warnings"] += r.warnings
        inp = sd.inp
        rep["sensors"][s] = {
            "noise": {"ar_order": r.ar_orders, "ima_theta": r.ar_theta, "innovation_sd": r.ar_sigma, "whitened_s2_final": r.final_all.s2},
            "baseline_params": np.asarray(r.base_all.beta).tolist(),
            "mds": r.mds,
            "mds_units": {n: E.UNITS.get((n, s)) for n in r.mds},
            "locate": breakdown(r.base_all.resid, rows, prep.t, np.asarray(inp.w), np.asarray(inp.wdot), prep.temp, prep.dt),
            "whiteness_before": whiteness(r.base_all.resid, rows, prep.dt),
            "whiteness_after": whiteness(r.final_all.resid, rows, prep.dt),
        }
    rep["effects"].sort(key=lambda e: e["log10_p"])
    rep["runtime_s"] = runtime_s
    return rep


def _fmt(v) -> str:
    a = np.asarray(v, dtype=float)
    if a.ndim == 0:
        return f"{float(a):.4g}"
    return "[" + ", ".join(_fmt(x) for x in a) + "]"


def report_markdown(rep: dict) -> str:
    """``report.md``: a short engineering report of a diagnosis."""
    L = [f"# jaxcal diagnose report", "",
         f"Baseline `{rep['baseline_kind']}`, {rep['n_samples']} samples at {1 / rep['dt_s']:.1f} Hz, run time {rep['runtime_s']:.1f} s.", ""]
    for n in rep["notes"]:
        L.append(f"- note: {n}")
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
    """Matplotlib figures: residual vs time, vs rate and temperature, fitted-effect check, ADEV."""
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
        cen = [np.median(wn[rows & (idx == k)]) for k in range(15)]
        ax[0, 1].plot(cen, [np.sqrt(np.mean(rn_b[rows & (idx == k)] ** 2)) for k in range(15)], "o-", label="baseline")
        ax[0, 1].plot(cen, [np.sqrt(np.mean(rn_f[rows & (idx == k)] ** 2)) for k in range(15)], "s-", label="final")
        ax[0, 1].set(xlabel="|rate| (rad/s)", ylabel=f"residual rms ({u})", title="residual vs motion regime")
        ax[0, 1].legend()
        # fitted-effect check: baseline residual vs what the named effects predict
        contrib = r.base_all.resid - r.final_all.resid
        if r.selected:
            for i, c in enumerate("xyz"):
                xx, yy = contrib[rows, i], r.base_all.resid[rows, i]
                q = np.quantile(xx, np.linspace(0, 1, 21))
                k = np.clip(np.searchsorted(q, xx, side="right") - 1, 0, 19)
                ax[1, 0].plot([xx[k == j].mean() for j in range(20)], [yy[k == j].mean() for j in range(20)], "o", label=f"axis {c} (binned)")
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
    """Write ``report.json``, ``report.md`` and ``<name>.png`` figures into ``out_dir``."""
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
