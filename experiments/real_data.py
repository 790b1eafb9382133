"""Public recordings side by side: datasheet, factory/published, imucal, imu_tk-style, jaxcal multipos.

    python -m experiments.real_data [--quick]

Reads only ``data/`` (the repository's compact copies). Writes ``results/real.md``,
``results/real.json`` and ``results/figures/real_*.png`` (quick form: ``real_quick.*``).

Scores are held out (leave-poses-out): the accelerometer's mean ``| |f| - 1 g |`` over static
poses that the fit did not use (mg), and the angle between the gyro-carried gravity direction of
one pose and the next pose's (deg), over transitions the gyro fit did not use. Fixed calibrations
(datasheet, factory, published) use nothing from the recording and are scored on every pose.
``--quick`` uses 5 interleaved folds; the full run leaves one pose out at a time.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

from experiments._real_report import FIELD_ROW, PARTIAL, TURNS_ONLY, UNCHECKED, fig_errors, markdown
from jaxcal import multipos as mp
from jaxcal.eval import checks, peers
from jaxcal.eval.heldout import fair_data, fair_field, fair_multipos, fixed_errors, online_fit, online_heldout
from jaxcal.eval.mocap import mocap_summary
from jaxcal.eval.scores import fair_row, paired_with_peer, public, score_fixed, score_heldout, score_insample
from jaxcal.methods.online import OnlineOptions, field_hp
from jaxcal.recording import load_recording
from jaxcal.sensor import Diag, LinearCal
from jaxcal.static import detect_static

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "data"
RESULTS = ROOT / "results"
FIG = RESULTS / "figures"


# ----------------------------------------------------------------------------- rows


CONFIGS = {
    "imu_tk-style 9-param (bias from initial rest, zero-order-hold rates)": mp.MultiposConfig(acc_model="9", gyro_bias="init", midpoint=False),
    "jaxcal multipos 12-param": mp.MultiposConfig(acc_model="12"),
    "jaxcal multipos 9-param": mp.MultiposConfig(acc_model="9"),
    "jaxcal multipos 9-param + gyro g-sensitivity": mp.MultiposConfig(acc_model="9", g_sensitivity=True),
}


def _fitted_rows(data: mp.MultiposData, n_folds: int | None, rows: dict, insample: bool = False) -> None:
    for name, cfg in CONFIGS.items():
        t0 = time.time()
        rows[name] = score_heldout(data, cfg, n_folds)
        rows[name]["seconds"] = round(time.time() - t0, 1)
    if insample:  # for comparison with peers whose numbers are in-sample
        rows["jaxcal multipos 9-param, in-sample"] = score_insample(data, mp.MultiposConfig())



FACES, TURNS = mp.FERRARIS_FACES, mp.FERRARIS_TURNS




def imucal_fair(quick: bool) -> tuple[dict, dict]:
    """imucal's continuous session, both methods held out on the same time split (see
    :func:`jaxcal.multipos.time_split`), plus clearly labelled in-sample rows."""
    rec = load_recording(DATA / "imucal_ferraris_example" / "session.npz")
    sec = json.loads((DATA / "imucal_ferraris_example" / "example_ferraris_session_list.json").read_text())
    bounds = {n: (v["start"], v["end"]) for n, v in sec.items()}
    rows: dict = {}
    info: dict = {"fs_hz": 102.4, "split": "each static section (the six faces; the rests next to each turn) cut in two "
                  "halves in time; fold 0 calibrates on the first halves and scores the second, fold 1 the reverse (both "
                  "folds pooled)"}
    parts = {k: [] for k in ("nominal", "imucal", "mp_vertical", "mp_known", "mp", "mp_turns_only", "online", "field")}
    field_hp_ = field_hp(OnlineOptions(), None)  # online's defaults between rests; the noise is measured per fold
    sig = float(np.mean([rec.acc[bounds[n][0]:bounds[n][1]].std(0).mean() for n in FACES]))  # static noise (g)
    try:
        import imucal

        have_imucal = True
        info["imucal"] = f"imucal {imucal.__version__} ran"
    except ImportError as e:
        have_imucal = False
        info["imucal"] = f"not installed ({e}); pip install -e '.[compare]'"
    cfg = mp.MultiposConfig()
    for fold in (0, 1):
        plan = mp.time_split(bounds, fold)
        fit_d, score_d, known, turns = fair_data(rec.t, rec.acc, rec.gyr, plan)
        bg = np.asarray(fit_d.pose_gyr).mean(0)
        parts["nominal"].append(fixed_errors(LinearCal(np.eye(3), np.zeros(3)), LinearCal(np.eye(3), bg), score_d, known, plan))
        if have_imucal:
            ia, ig = peers.imucal_ferraris(rec.acc, rec.gyr, mp.peer_sections(plan, bounds), 102.4)
            parts["imucal"].append(fixed_errors(ia, ig, score_d, known, plan))
        parts["mp_vertical"].append(fair_multipos(fit_d, score_d, known, turns, plan, cfg, "vertical"))
        parts["mp_known"].append(fair_multipos(fit_d, score_d, known, turns, plan, cfg, "closed"))
        parts["mp"].append(fair_multipos(fit_d, score_d, known, turns, plan, cfg, "none"))
        parts["mp_turns_only"].append(fair_multipos(fit_d, score_d, known, turns, plan, cfg, "vertical", motions=False))
        # online: sequences = calibration half of a face + the motion to the next face (or the motion +
        # the next face's calibration half), face-to-face motions in two interleaved folds
        F = [j for j in range(len(plan.spans)) if plan.is_face[j] and plan.is_face[j + 1]]
        eo_a, eo_g = [], np.full(len(plan.spans), np.nan)
        for tf in (0, 1):
            train = [j for j in F if j % 2 != tf]
            segs = []
            for j in train:
                a, b = plan.spans[j]
                segs.append((plan.fit_iv[j][0], b + 1) if fold == 1 else (a, plan.fit_iv[j + 1][1]))
            ca, cg = online_fit(rec.acc, rec.gyr, segs, 1 / 102.4, Diag(np.ones(3), np.zeros(3)), Diag(np.ones(3), bg), sig)
            ea, eg, ek = fixed_errors(ca, cg, score_d, known, plan)
            eo_a.append(ea)  # faces: every half scored is outside both folds' sequences
            out = [j for j in range(len(plan.spans)) if ((j % 2 == tf) if j in F else tf == 0)]
            eo_g[out] = eg[out]  # face-to-face motions from the fold that left them out, the others from the first
        parts["online"].append((eo_a[0], eo_g, ek))  # acc from the first transition fold, turns from the second
        parts["field"].append(fair_field(rec.acc, rec.gyr, fit_d, score_d, known, plan, 1 / 102.4, field_hp_))
    sc = "held out: acc on the other halves of the faces, gyro on the motions between poses"
    rows["nominal conversion (as exported: m/s^2 / 9.80665, deg/s; gyro bias from the calibration halves)"] = fair_row(parts["nominal"], "nothing fitted but the gyro bias; turns: held out")
    if have_imucal:
        rows["imucal Ferraris (calibration halves of the faces + all three turns, expected_angle -360; K_ga left out)"] = fair_row(
            parts["imucal"], sc + " (never used by imucal); turns: IN-SAMPLE (imucal needs all three)")
    rows["jaxcal multipos 9-param + turns about the measured vertical (no labels)"] = fair_row(
        parts["mp_vertical"], sc + " (leave-one-motion-out); turns: leave-one-turn-out")
    rows["jaxcal multipos 9-param + known 360 deg turns (closure only)"] = fair_row(
        parts["mp_known"], sc + " (leave-one-motion-out); turns: leave-one-turn-out")
    rows["jaxcal multipos 9-param (turns not used)"] = fair_row(parts["mp"], sc + " (leave-one-motion-out); turns: never used")
    rows[TURNS_ONLY] = fair_row(parts["mp_turns_only"], sc + " (never used by the fit); turns: IN-SAMPLE (as imucal)")
    rows["jaxcal online (affine, nominal units as prior centre; no labels)"] = fair_row(
        parts["online"], sc + " (face-to-face motions in 2 interleaved folds); turns: never used")
    rows[FIELD_ROW] = fair_row(parts["field"], sc + " (the calibration halves are its rests, the motions between them its "
                               "sequences); turns: never used")
    # in-sample rows, kept separate: fitted on the whole static sections (and turns), scored on them
    full = {n: bounds[n] for n in FACES + TURNS}
    plan = mp.whole_sections(mp.time_split(bounds, 0))
    all_d, _, known, turns = fair_data(rec.t, rec.acc, rec.gyr, plan)
    if have_imucal:
        rows["IN-SAMPLE imucal Ferraris (all of every section)"] = fair_row([fixed_errors(*peers.imucal_ferraris(rec.acc, rec.gyr, full, 102.4), all_d, known, plan)],
                                                                           "IN-SAMPLE (whole faces, motions, turns)")
    with jax.enable_x64(True):
        d, kn, tv = (jax.tree_util.tree_map(jnp.asarray, x) for x in (all_d, known, turns))
        f = jax.tree_util.tree_map(np.asarray, mp.fit_prepared_jit(
            d, cfg, acc_w=jnp.asarray(plan.is_face.astype(float)), gyr_w=jnp.asarray((~plan.across_turn).astype(float)), turns=tv))
    rows["IN-SAMPLE jaxcal multipos 9-param + turns about the measured vertical (all of every section)"] = fair_row(
        [fixed_errors(f.acc, f.gyr, all_d, known, plan)], "IN-SAMPLE (whole static sections, motions, turns)")
    faces = [n for n, face in zip(plan.statics, plan.is_face) if face]
    segs = [(max(bounds[faces[j]][0], bounds[faces[j]][1] - 100), min(bounds[faces[j + 1]][1], bounds[faces[j + 1]][0] + 100))
            for j in range(len(faces) - 1)]
    ca, cg = online_fit(rec.acc, rec.gyr, segs, 1 / 102.4, Diag(np.ones(3), np.zeros(3)),
                         Diag(np.ones(3), np.asarray(all_d.pose_gyr).mean(0)), sig)
    rows["IN-SAMPLE jaxcal online (all five face-to-face sequences)"] = fair_row(
        [fixed_errors(ca, cg, all_d, known, plan)], "IN-SAMPLE (its five sequences include the faces' ends and all face-to-face motions)")
    info["sigma_acc_g"] = sig
    if have_imucal:
        info["paired_peer"] = next(n for n in rows if n.startswith("imucal"))
        info["paired"] = paired_with_peer(rows, info["paired_peer"], lambda e: np.degrees(np.nanmean(np.reshape(e, (2, -1)), 0)),
                                          also=(FIELD_ROW,))
    motions = [j for j in range(len(plan.spans)) if not plan.across_turn[j]]
    info["motions"] = [f"{plan.statics[j]} -> {plan.statics[j + 1]}" for j in motions]
    info["motion_peak_rate_dps"] = [float(np.degrees(np.linalg.norm(rec.gyr[a:b + 1], axis=1).max())) for a, b in plan.spans[motions]]
    return rows, info


# ----------------------------------------------------------------------------- recordings


def xsens(n_folds: int | None) -> tuple[dict, dict]:
    rec = load_recording(DATA / "imu_tk_xsens_multipos" / "xsens.npz")
    det = detect_static(rec.t, rec.acc, k=5, init_duration=45.0, window=1.0, min_duration=1.0)
    data = mp.prepare(rec.t, rec.acc, rec.gyr, det.intervals, gyr_limit=65535)
    g_local = 9.81744  # README: imu_tk's gravity
    off_a = np.array([33123.0, 33276.0, 32360.0])
    ka, kg = np.diag([415.0, 413.0, 415.0]), np.diag([4778.0, 4758.0, 4766.0])
    ma = np.array([[1.0, 0.0, -0.01], [0.01, 1.0, 0.01], [0.02, 0.01, 1.0]])
    mg = np.array([[1.0, -0.01, -0.02], [0.0, 1.0, 0.04], [-0.01, 0.01, 1.0]])
    off_g = np.asarray(data.pose_gyr[0])  # README: use the initial rest mean as the gyro bias
    rows: dict = {}
    # accelerometer units: f in m/s^2 / g_local -> "1 g" = local gravity, as the fits normalise it
    rows["datasheet scales (diag K, factory offsets)"] = score_fixed(
        peers.imu_tk_factory(ka, None, off_a, g_local), peers.imu_tk_factory(kg, None, off_g), data)
    rows["factory calibration, f = M^-1 K^-1 (raw - offset)"] = score_fixed(
        peers.imu_tk_factory(ka, ma, off_a, g_local), peers.imu_tk_factory(kg, mg, off_g), data)
    _fitted_rows(data, n_folds, rows)
    # online: a spec is its prior centre; the datasheet/README values (unsigned offsets, diag K)
    aspec = Diag(np.diag(ka) * g_local, off_a)
    gspec = Diag(np.diag(kg).copy(), off_g)
    sig = float(np.mean([rec.acc[a:b].std(0).mean() for a, b in det.intervals]) / (415.0 * g_local))
    t0 = time.time()
    name = "jaxcal online (affine, datasheet scales and offsets as prior centre)"
    rows[name] = online_heldout(rec.t, rec.acc, rec.gyr, det.intervals, data, aspec, gspec, sig, n_folds or 10)  # <= 10 folds: one compile each
    rows[name]["seconds"] = round(time.time() - t0, 1)
    info = {"n_static_intervals": int(len(det.intervals)), "threshold_k": det.k, "fs_hz": 100.0,
            "gravity_m_s2": g_local, "_det": det, "_rec": rec,
            "paired_peer": "factory calibration, f = M^-1 K^-1 (raw - offset)"}
    info["paired"] = paired_with_peer(rows, info["paired_peer"])
    return rows, info


def mpu6050(n_folds: int | None) -> tuple[dict, dict]:
    rec = load_recording(DATA / "tomisuarez_mpu6050" / "calibration.npz")
    fit, iv, k = mp.detect_and_fit(rec.t, rec.acc, rec.gyr, detect=mp.DetectOptions(init_duration=36.0, gyr_limit=32767))
    data = mp.prepare(rec.t, rec.acc, rec.gyr, iv, gyr_limit=32767)
    rows: dict = {}
    bg_rest = np.asarray(data.pose_gyr[0])
    rows["datasheet (16384 LSB/g, 131 LSB/(deg/s), zero acc bias, gyro bias from rest)"] = score_fixed(
        peers.datasheet(16384.0), peers.datasheet(131.0 * 180 / math.pi, bg_rest), data)
    pa = np.loadtxt(DATA / "tomisuarez_mpu6050" / "optimization_result_data" / "params_acc.csv")
    pg = np.loadtxt(DATA / "tomisuarez_mpu6050" / "optimization_result_data" / "params_gyro.csv")
    pub_acc, pub_gyr = peers.tedaldi_published(pa, pg)
    rows["published (tomisuarez2/ImuCalibration, Tedaldi method; fitted upstream on this same session)"] = score_fixed(pub_acc, pub_gyr, data)
    rows["published (tomisuarez2/ImuCalibration, Tedaldi method; fitted upstream on this same session)"]["scored"] = "all poses (in-sample upstream)"
    _fitted_rows(data, n_folds, rows, insample=True)
    prior_cfg = mp.MultiposConfig(prior=mp.MPU6050_PRIOR)
    pname = "jaxcal multipos 9-param + MPU-6050 datasheet prior (MAP: sensitivity +-3 %, cross-axis +-2 %)"
    t0 = time.time()
    rows[pname] = score_heldout(data, prior_cfg, n_folds)
    rows[pname]["seconds"] = round(time.time() - t0, 1)
    rows[pname.replace("prior (MAP", "prior, in-sample (MAP")] = score_insample(data, prior_cfg)
    fit_prior = mp.fit_multipos(rec.t, rec.acc, rec.gyr, iv, prior_cfg, gyr_limit=32767)
    aspec = Diag(np.full(3, 16384.0), np.zeros(3))
    gspec = Diag(np.full(3, 131.0 * 180 / math.pi), bg_rest)
    sig = float(np.mean([rec.acc[a:b].std(0).mean() for a, b in iv]) / 16384.0)
    t0 = time.time()
    rows["jaxcal online (affine, datasheet values as prior centre)"] = online_heldout(rec.t, rec.acc, rec.gyr, iv, data, aspec, gspec, sig, n_folds)
    rows["jaxcal online (affine, datasheet values as prior centre)"]["seconds"] = round(time.time() - t0, 1)
    ok = np.asarray(data.seg_ok)
    segs = [(max(iv[j, 0], iv[j, 1] - 100), min(iv[j + 1, 1], iv[j + 1, 0] + 100)) for j in range(len(iv) - 1) if ok[j]]
    on_acc, on_gyr = online_fit(rec.acc, rec.gyr, segs, 0.01, aspec, gspec, sig)
    # independent recordings: a static test and a ~90 deg rotation about x
    extra = {}
    cals = {
        "datasheet": (peers.datasheet(16384.0), peers.datasheet(131.0 * 180 / math.pi, bg_rest)),
        "published": (pub_acc, pub_gyr),
        "jaxcal multipos 9-param (all poses)": (fit.acc, fit.gyr),
        "jaxcal multipos 9-param + MPU-6050 datasheet prior (all poses)": (fit_prior.acc, fit_prior.gyr),
        "jaxcal online (all unsaturated sequences)": (on_acc, on_gyr),
    }
    st = load_recording(DATA / "tomisuarez_mpu6050" / "static_test.npz")
    r9 = load_recording(DATA / "tomisuarez_mpu6050" / "rot90x.npz")
    for name, (ca, cg) in cals.items():
        # rot90x: rest bias from its own first 3 s, gravity from first/last second
        rc = checks.rotation_check(ca, cg, r9.t, r9.acc, r9.gyr)
        extra[name] = {
            "static_test_norm_err_mg": checks.static_norm_error_mg(ca, st.acc),
            "rot90x_gyro_rotation_deg": rc["rotation_deg"],
            "rot90x_carried_gravity_err_deg": rc["carried_gravity_err_deg"],
            "rot90x_angle_deg": rc["angle_deg"],
            "rot90x_off_axis_deg": rc["off_axis_deg"],
        }
    info = {"n_static_intervals": int(len(iv)), "threshold_k": k, "fs_hz": 100.0,
            "saturated_transitions_excluded": int((~np.asarray(data.seg_ok)).sum()), "independent_recordings": extra}
    info["paired_peer"] = next(n for n in rows if n.startswith("published"))
    info["paired"] = paired_with_peer(rows, info["paired_peer"])
    return rows, info


def imucal_snapshot() -> dict:
    """imucal's stored example_cal.json applied to its own annotated session (raw counts)."""
    rec = load_recording(DATA / "imucal_ferraris_example" / "annotated.npz")
    cal = json.loads((DATA / "imucal_ferraris_example" / "example_cal.json").read_text())
    ka, ra, ba = (np.asarray(cal[k]) for k in ("K_a", "R_a", "b_a"))
    names = list(rec.section_names)
    out = {}
    errs = []
    for face in ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a"):
        m = rec.section == names.index(face)
        f = (rec.acc[m].mean(0) - ba) @ np.linalg.inv(ka @ ra).T / 9.81
        errs.append(abs(np.linalg.norm(f) - 1.0))
    out["example_cal.json on its six faces (in-sample), mean | |f| - 1 g | mg"] = float(1e3 * np.mean(errs))
    # multipos cannot run here: the parts were cut out, no motion between different poses
    out["multipos"] = "not applicable: the file holds the six faces and three turns about the vertical, but not the motions between faces"
    return out


def _multipos_verdict(rec) -> str:
    """What ``jaxcal calibrate --method multipos`` says of a recording: the refusal, or that it ran."""
    try:
        mp.fit_multipos_recording(rec)
    except ValueError as e:
        return f"refused: {e}"
    return "calibrated"


def other_recordings() -> dict:
    out = {}
    tv = load_recording(DATA / "tumvi_room1_512_16" / "room1.npz")
    det = detect_static(tv.t, tv.acc, k=5, init_duration=1.0, window=0.5, min_duration=0.5)
    out["tumvi_room1_512_16"] = {
        "samples": int(len(tv.t)), "static_intervals_found": int(len(det.intervals)),
        "jaxcal calibrate --method multipos": _multipos_verdict(tv),
        "note": "hand-held, already intrinsically calibrated by TUM: calibrated against its motion capture instead (below)",
    }
    return out



def fusion(n_folds: int | None) -> tuple[dict, dict]:
    """x-io's Fusion recording: hand-held, still only flat or tilted < 90 deg, in g and deg/s (the
    maker's units). multipos refuses a full calibration; ``--partial`` fits what the poses
    determine. Rows: as recorded, ``--partial`` (held out), the unchecked full fit (held out);
    info: the refusal, the tilts, the return-to-start closure, the magnetometer check."""
    fu = load_recording(DATA / "xio_fusion_sensor_data" / "sensor_data.npz")
    _, poses, k = mp.detect_and_fit(fu.t, fu.acc, fu.gyr, detect=mp.DetectOptions(gyr_gate=True), check=False)  # the poses calibrate uses
    data = mp.prepare(fu.t, fu.acc, fu.gyr, poses)
    ident = LinearCal(np.eye(3), np.zeros(3))
    rows = {"as recorded (the file's units; nothing fitted)": score_fixed(ident, ident, data)}
    rows[PARTIAL] = score_heldout(data, mp.MultiposConfig(acc_fit="determined", gyr_fit="none"), n_folds)
    rows[PARTIAL]["scored"] += "; gyro as recorded, gravity directions from the held-out accelerometer fit"
    rows[UNCHECKED] = score_heldout(data, mp.MultiposConfig(), n_folds)
    pa = np.asarray(data.pose_acc)
    tilt = np.degrees(np.arccos(np.clip(pa @ pa[0] / np.linalg.norm(pa, axis=1) / np.linalg.norm(pa[0]), -1, 1)))
    flat = tilt < 5.0
    info = {"n_static_intervals": int(len(poses)), "threshold_k": float(k), "tilt_deg": tilt.round(1).tolist(),
            "tilted_acc_mg": {n: (1e3 * r["_acc_err"][~flat]).round(3).tolist() for n, r in rows.items()},
            "paired_peer": "as recorded (the file's units; nothing fitted)"}
    info["paired"] = paired_with_peer(rows, info["paired_peer"])
    info["calibrate"] = _multipos_verdict(fu)
    try:
        *_, q = mp.fit_multipos_recording(fu, partial=True, summary=True)
        info["calibrate --partial"] = "; ".join(f"{s_}: {v}" for s_, v in q["partial"].items())
    except ValueError as e:
        info["calibrate --partial"] = f"refused: {e}"
    # loop closure: the device ends where it started; gyro bias from the first second / from every rest
    rests = detect_static(fu.t, fu.acc, k=3, init_duration=1.0, window=0.3, min_duration=0.3, gyr=fu.gyr).intervals
    rest_bias = np.average(np.stack([fu.gyr[a:b].mean(0) for a, b in rests]), axis=0, weights=rests[:, 1] - rests[:, 0])
    closure = {}
    for name, bias in (("as recorded", np.zeros(3)), ("bias from first second", fu.gyr[:100].mean(0)),
                       (f"bias from its {len(rests)} rests", rest_bias)):
        closure[name] = checks.loop_closure_deg(fu.t, fu.acc, fu.gyr, bias)
    info["loop_closure_deg"] = closure
    mag = np.array([np.linalg.norm(fu.mag[a:b].mean(0)) for a, b in poses])
    worst = int(np.argmax(np.abs(mag / np.median(mag) - 1)))
    bias_worse = min(v for n, v in closure.items() if "bias" in n) > closure["as recorded"]
    info["note"] = (f"{int(flat.sum())} of the {len(poses)} still periods multipos finds lie flat like the first (within 5 deg), "
                    f"the other {int((~flat).sum())} are tilted by {', '.join(f'{x:.0f}' for x in tilt[~flat])} deg"
                    f"{' and none is past 90 deg, so opposite directions never pair up to separate scale from bias' if tilt.max() < 90 else ''}"
                    f"{'; every gyro bias read from rests makes the return to the start pose worse than as recorded (the bias is not constant)' if bias_worse else ''}"
                    ". The magnetometer is no reference either: its field magnitude at the still period from "
                    f"{fu.t[poses[worst][0]]:.1f} s is {100 * (mag[worst] / np.median(mag) - 1):+.0f} % off the median of the others "
                    "(a local disturbance)")
    return rows, info


def tumvi_mocap() -> dict:
    """TUM-VI room1: calibrated against its motion capture instead of static poses (it has too few
    of them): ``jaxcal diagnose`` with the affine baseline (scale, misalignment, bias; thesis eq.
    2.3) and the effects it names. Held-out figures are its leave-one-time-block-out RMS (8 blocks);
    'as recorded' is the RMS of the recording as TUM calibrated it (nothing fitted)."""
    from jaxcal.diagnose import diagnose_recording

    rec = load_recording(DATA / "tumvi_room1_512_16" / "room1.npz")
    t0 = time.time()
    rep = diagnose_recording(rec, baseline="affine")
    sensors = mocap_summary(rec, rep)
    return {"seconds": round(time.time() - t0, 1), "sensors": sensors}


# ----------------------------------------------------------------------------- figures


def fig_static(info: dict, path: Path) -> None:
    rec, det = info["_rec"], info["_det"]
    t = rec.t
    fig, ax = plt.subplots(2, 1, figsize=(11, 5.5), sharex=True)
    norm = np.linalg.norm(rec.acc - np.array([33123.0, 33276.0, 32360.0]), axis=1) / 415.0 / 9.81744
    ax[0].plot(t, norm, lw=0.5, label="|f| (factory offsets, 415 LSB per m/s^2)")
    ax[1].semilogy(t, det.var_mag, lw=0.5, label="variance magnitude of acc (1 s window)")
    ax[1].axhline(det.threshold, color="r", ls="--", label=f"threshold = {det.k:g} x initial-rest variance")
    for a, b in det.intervals:
        for x in ax:
            x.axvspan(t[a], t[b - 1], color="g", alpha=0.15, lw=0)
    ax[0].set_ylabel("|f| (g)")
    ax[1].set_ylabel("variance (LSB^2)")
    ax[1].set_xlabel("time (s)")
    ax[0].set_title(f"Xsens multi-position recording: {len(det.intervals)} static intervals (green)")
    ax[0].legend(loc="upper right")
    ax[1].legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(quick: bool) -> None:
    t_start = time.time()
    FIG.mkdir(parents=True, exist_ok=True)
    n_folds = 5 if quick else None
    res: dict = {"mode": "quick (5 interleaved folds)" if quick else "full (leave one pose out)"}
    pre = "real_quick" if quick else "real"  # make run's quick form never overwrites the full results
    xs_rows, xs_info = xsens(n_folds)
    fig_static(xs_info, FIG / f"{pre}_static_xsens.png")
    fig_errors(xs_rows, "Xsens", FIG / f"{pre}_xsens_errors.png")
    mpu_rows, mpu_info = mpu6050(n_folds)
    fig_errors(mpu_rows, "MPU-6050", FIG / f"{pre}_mpu6050_errors.png")
    im_rows, im_info = imucal_fair(quick)
    fig_errors(im_rows, "imucal session (time split)", FIG / f"{pre}_imucal_errors.png")
    fu_rows, fu_info = fusion(n_folds)
    fig_errors(fu_rows, "x-io Fusion", FIG / f"{pre}_fusion_errors.png")
    snap = imucal_snapshot()
    other = other_recordings()
    tum = tumvi_mocap()
    res["recordings"] = {
        "imu_tk_xsens_multipos": {"rows": xs_rows, "info": xs_info},
        "tomisuarez_mpu6050": {"rows": mpu_rows, "info": mpu_info},
        "imucal_ferraris_example (continuous session, fair time split)": {"rows": im_rows, "info": im_info},
        "xio_fusion_sensor_data": {"rows": fu_rows, "info": fu_info},
    }
    res["imucal_snapshot"] = snap
    res["other"] = other
    res["tumvi_mocap"] = tum
    res["seconds"] = round(time.time() - t_start, 1)
    pub = public(res)
    (RESULTS / f"{pre}.json").write_text(json.dumps(pub, indent=2))

    md = markdown(res, pub, quick, pre)
    (RESULTS / f"{pre}.md").write_text(md)
    print(md)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    main(ap.parse_args().quick)
