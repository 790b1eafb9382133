"""``jaxcal align``: the IMU-to-mocap time offset, clock skew, rotation and lever arm, and the mocap
ground truth re-expressed in the IMU frame and on the IMU clock.

The engine is ``diagnose``'s (:func:`jaxcal.diagnose.core.diagnose_prepared`) with the ``affine``
baseline and the rig's unknowns estimated whatever the tests say: the gyroscope's ``time_offset`` (the
rig's clock offset; its coarse value guides the accelerometer's search) and ``clock_skew`` (the rate
of the reference clock against the IMU's, both sensors), and the accelerometer's
``lever_arm`` and own ``time_offset`` (its filter delay may differ by a millisecond or two, which a
lever arm would otherwise absorb at high rates) (``force``); each sensor in its own trusted band
(:func:`jaxcal.diagnose.core.diagnose_banded`); the rotation is
the polar factor of the gyroscope's affine matrix (:mod:`jaxcal.diagnose.frames`). Every other
vocabulary effect is still tested and reported, so a rig with, say, a g-sensitive gyro says so.

Conventions (CONVENTIONS.md "align"): ``tau`` has the sign of ``time_offset`` (tau > 0: the IMU
lags the reference, the IMU sample stamped ``t`` saw the motion of reference time ``t - tau``, at
the epoch ``clock_skew_epoch_s``); ``clock_skew`` (ppm) > 0: the reference clock runs fast, so the IMU
sample stamped ``t`` saw the motion of reference time ``t_ref(t) = t - tau + 1e-6 clock_skew (t - epoch)``;
``R_ref_imu`` rotates IMU-frame vectors into the reference body frame; ``r`` is the IMU position in
the reference body frame (m). The ground truth is then, at IMU time ``t``:
``p_imu = p_ref(t_ref) + R_world_ref(t_ref) r``, ``R_world_imu = R_world_ref(t_ref) R_ref_imu``.
Only :func:`write_alignment` touches the file system.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from jaxcal.diagnose import effects as E
from jaxcal.diagnose import kinematics as K
from jaxcal.diagnose.core import diagnose_banded, require_recording
from jaxcal.diagnose.report import build_report_banded
from jaxcal.diagnose.select import SelectConfig
from jaxcal.recording import Recording

__all__ = ["AlignResult", "align_recording", "groundtruth_table", "write_alignment", "EUROC_GT_COLUMNS", "clock_from_qmt"]

# the accelerometer's own filter delay may differ; the clocks' rate (clock_skew) is estimated for both
FORCE = {"acc": ("lever_arm", "time_offset", "clock_skew"), "gyr": ("time_offset", "clock_skew")}

EUROC_GT_COLUMNS = (
    "#timestamp", "p_RS_R_x [m]", "p_RS_R_y [m]", "p_RS_R_z [m]", "q_RS_w []", "q_RS_x []", "q_RS_y []", "q_RS_z []",
    "v_RS_R_x [m s^-1]", "v_RS_R_y [m s^-1]", "v_RS_R_z [m s^-1]", "b_w_RS_S_x [rad s^-1]", "b_w_RS_S_y [rad s^-1]",
    "b_w_RS_S_z [rad s^-1]", "b_a_RS_S_x [m s^-2]", "b_a_RS_S_y [m s^-2]", "b_a_RS_S_z [m s^-2]",
)


class AlignResult(NamedTuple):
    """``align`` is the ``align.json`` dict; ``report`` the full diagnosis behind it;
    ``groundtruth`` (M, 17) rows in :data:`EUROC_GT_COLUMNS` order (timestamp in ns);
    ``results`` the per-sensor :class:`~jaxcal.diagnose.core.SensorResult` (for figures)."""

    align: dict
    report: dict
    groundtruth: np.ndarray
    results: dict
    t: dict  # per sensor, the (decimated) times its results live on


def _effect(rep: dict, sensor: str, name: str) -> dict | None:
    for e in rep["effects"]:
        if e["sensor"] == sensor and e["name"] == name:
            return e
    return None


def _combine(rep: dict, name: str, param: str) -> tuple[float, float, dict]:
    """The rig's value of a clock effect (``time_offset`` ``tau``, ``clock_skew`` ``s``): the
    gyroscope's estimate (its regressor, the rate's derivative, is the sharper; the accelerometer's
    own, which may carry a different filter delay, is reported beside it); without a gyroscope
    reference, the accelerometer's."""
    per = {}
    for s in ("gyr", "acc"):
        e = _effect(rep, s, name)
        if e is not None:
            per[s] = (float(e["params"][param]), float(e["stderr"][param]))
    if not per:
        raise ValueError(f"no {name.replace('_', ' ')} could be estimated (no sensor with a reference)")
    v, se = per["gyr"] if "gyr" in per else per["acc"]
    return v, se, per


def _combine_tau(rep: dict) -> tuple[float, float, dict]:
    """The rig's time offset (:func:`_combine`)."""
    return _combine(rep, "time_offset", "tau")


def _track(rec: Recording) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference pose track at its own times (the reader's ``gt_*`` when kept), NaN rows dropped."""
    t = rec.gt_t
    if t is not None:
        tt, p, q = np.asarray(t, float), np.asarray(rec.gt_pos, float), np.asarray(rec.gt_quat, float)
    else:
        tt, p, q = np.asarray(rec.t, float), np.asarray(rec.pos_ref, float), np.asarray(rec.quat_ref, float)
        rv = rec.ref_valid
        if rv is not None:
            p = np.where(np.asarray(rv, bool)[:, None], p, np.nan)
    ok = np.isfinite(p).all(1) & np.isfinite(q).all(1)
    return tt[ok], p[ok], q[ok]


def groundtruth_table(t_imu: np.ndarray, track: tuple[np.ndarray, np.ndarray, np.ndarray], tau: float, R_ref_imu: np.ndarray,
                      r: np.ndarray, b_gyr: np.ndarray, b_acc_ms2: np.ndarray, valid: np.ndarray | None = None,
                      t0: float = 0.0, sigma: float = 0.02, skew_ppm: float = 0.0, epoch: float = 0.0) -> np.ndarray:
    """EuRoC ``state_groundtruth_estimate0`` rows of the IMU on its own clock.

    Args:
        t_imu: (N,) IMU sample times (s, recording clock).
        track: reference pose track ``(t (M,), p (M, 3) m world, q (M, 4) [w,x,y,z] body to world)``.
        tau: time offset (s; the IMU at ``t`` saw the reference at ``t - tau + 1e-6 skew_ppm (t - epoch)``).
        R_ref_imu: (3, 3) rotates IMU-frame vectors into the reference body frame.
        r: (3,) IMU position in the reference body frame (m).
        b_gyr, b_acc_ms2: (3,) biases written in every row (rad/s, m/s^2).
        valid: (N,) bool, rows to keep (default: all whose reference time lies in the track and not
            across a gap, :func:`jaxcal.diagnose.kinematics.reference_gap_mask`).
        t0: added to ``t_imu`` for the time stamps (e.g. the recording's Unix start).
        sigma: Gaussian width (s) of the velocity's derivative kernel.
        skew_ppm: clock skew (ppm; positive: the reference clock runs fast).
        epoch: the recording time (s) at which ``tau`` holds.

    Returns:
        (K, 17) float array in :data:`EUROC_GT_COLUMNS` order, time stamps in integer ns (as float64).
    """
    tt, p, q = track
    tq = np.asarray(t_imu, float) - tau + skew_ppm * 1e-6 * (np.asarray(t_imu, float) - epoch)
    ok = K.reference_gap_mask(tq, tt) if valid is None else np.asarray(valid, bool)
    inside = (tq >= tt[0]) & (tq <= tt[-1])
    ok = ok & inside
    tqc = np.clip(tq, tt[0], tt[-1])
    rot = Slerp(tt, Rotation.from_quat(q[:, [1, 2, 3, 0]]))(tqc)
    pr = np.stack([np.interp(tqc, tt, p[:, k]) for k in range(3)], 1)
    R_w_ref = rot.as_matrix()
    p_imu = pr + R_w_ref @ np.asarray(r, float)
    R_w_imu = R_w_ref @ np.asarray(R_ref_imu, float)
    q_imu = Rotation.from_matrix(R_w_imu).as_quat()[:, [3, 0, 1, 2]]
    q_imu *= np.where(q_imu[:, :1] < 0, -1.0, 1.0)
    dt = float(np.median(np.diff(t_imu)))
    v = K.derivative(p_imu, sigma, dt) if sigma > 0 else np.gradient(p_imu, dt, axis=0)
    # the velocity kernel must not reach across a gap
    half = int(np.ceil(4.0 * sigma / dt)) if sigma > 0 else 1
    ok = ok & K._gap_mask(~ok, half)
    ts = np.round((np.asarray(t_imu, float) + t0) * 1e9)
    n = int(ok.sum())
    return np.column_stack([ts[ok], p_imu[ok], q_imu[ok], v[ok], np.tile(b_gyr, (n, 1)), np.tile(b_acc_ms2, (n, 1))])


def clock_from_qmt(sync_info: dict, epoch: float) -> tuple[float, float]:
    """``qmt.syncOptImu``'s result in ``align``'s convention: ``(tau at epoch (s), clock_skew (ppm))``.

    qmt maps mocap sample ``j`` to IMU sample ``i0 + j rate_imu' / rate_opt`` (``sync_info["data"]["imu"]["rate"]``,
    the IMU's rate on the mocap's clock, and the ``["opt", "ind", 0, "imu", "ind", i0]`` entry). Its
    mocap rate at sample ``j`` is ``quatToGyrStrapdown``'s, the rotation from sample ``j - 1`` to ``j``:
    the rate of mocap time ``(j - 1/2) / rate_opt``. So the IMU sample stamped ``t = i / rate_imu`` (its
    nominal rate) saw the mocap time ``t_ref = (t - i0 / rate_imu) rate_imu / rate_imu' - 1 / (2 rate_opt)``;
    then ``1 + 1e-6 clock_skew = rate_imu / rate_imu'`` and ``tau = epoch - t_ref(epoch)``. Both streams'
    first samples are at time 0.

    Args:
        sync_info: the dict ``qmt.syncOptImu`` returns.
        epoch: the time (s) at which ``tau`` is wanted (``align.json``'s ``clock_skew_epoch_s``).
    """
    data = sync_info["data"]
    nominal, rate, opt = float(data["imu_offsetonly"]["rate"]), float(data["imu"]["rate"]), float(data["opt"]["rate"])
    i0 = next(float(e[5]) for e in sync_info["sync"] if e[0] == "opt" and e[3] == "imu" and e[1] == "ind")
    t_ref = (epoch - i0 / nominal) * nominal / rate - 0.5 / opt
    return epoch - t_ref, (nominal / rate - 1.0) * 1e6


def align_recording(rec: Recording, pose_sigma: float | None = None, config: SelectConfig = SelectConfig()) -> AlignResult:
    """Estimate the rig's time offset, rotation and lever arm, and the IMU ground truth.

    Args:
        rec: :class:`~jaxcal.recording.Recording` with ``gyr`` (and ``acc``) and a reference pose
            (``pos_ref``, ``quat_ref``; the original track ``gt_*`` and ``t0`` used when given).
        pose_sigma: Gaussian width (s) of the pose derivatives; None (default) chooses it from the
            coherence of sensor and reference (:mod:`jaxcal.diagnose.band`).
        config: the tests' settings (as in ``diagnose``).

    Raises:
        ValueError: no reference pose, no gyroscope, or no usable reference.
    """
    require_recording(rec)
    if rec.pos_ref is None or rec.quat_ref is None:
        raise ValueError("align needs a reference pose (pos_ref and quat_ref)")
    if rec.gyr is None:
        raise ValueError("align needs the gyroscope (the rotation comes from it)")
    t_start = time.perf_counter()
    preps, results = diagnose_banded(rec, "affine", config, FORCE, pose_sigma)
    rep = build_report_banded(preps, results, "affine", time.perf_counter() - t_start)
    fr = rep["frames"]
    tau, tau_se, per = _combine_tau(rep)
    skew, skew_se, skew_per = _combine(rep, "clock_skew", "s")
    t_skew = preps["gyr" if "gyr" in skew_per else "acc"].t
    R = np.asarray(fr["R_ref_imu"])
    out: dict = {"tau": tau, "tau_stderr": tau_se, "tau_per_sensor": {s: {"tau": v[0], "stderr": v[1]} for s, v in per.items()},
                 "R_ref_imu": R.tolist(), "R_ref_imu_from": fr["R_ref_imu_from"],
                 "rotation_deg": fr["gyr"]["rotation_deg"], "rotation_deg_stderr": fr["gyr"].get("rotation_deg_stderr"),
                 "rotvec_imu_ref_deg": fr["gyr"]["rotvec_imu_ref_deg"], "rotvec_imu_ref_deg_stderr": fr["gyr"].get("rotvec_imu_ref_deg_stderr"),
                 "clock_skew": skew, "clock_skew_epoch_s": 0.5 * float(t_skew[0] + t_skew[-1]),
                 "clock_skew_per_sensor": {s: {"clock_skew": v[0], "stderr": v[1]} for s, v in skew_per.items()},
                 "stderr": {"tau": tau_se, "clock_skew": skew_se}}
    out["stderr"]["R_ref_imu_rotvec_deg"] = fr["gyr"].get("rotvec_imu_ref_deg_stderr")
    b_gyr = np.asarray(results["gyr"].final_all.beta[9:12])
    b_acc = np.zeros(3)
    if "acc" in results:
        la = fr.get("lever_arm")
        e = _effect(rep, "acc", "lever_arm")
        out["r"] = e["params"]["r"]
        out["stderr"]["r"] = e["stderr"]["r"]
        out["r_imu_frame"] = la["r_imu_frame_m"] if la else None
        b_acc = np.asarray(results["acc"].final_all.beta[9:12]) * E.G0
    else:
        out["r"] = None
        out["stderr"]["r"] = None
    out["bias_gyr_rads"] = b_gyr.tolist()
    out["bias_acc_ms2"] = b_acc.tolist()
    out["named_effects"] = [f"{e['sensor']} {e['name']}" for e in rep["effects"] if not e.get("forced")]
    out["warnings"] = rep["warnings"]
    out["notes"] = rep["notes"]
    r = np.zeros(3) if out["r"] is None else np.asarray(out["r"])
    t0 = float(rec.t0 or 0.0)
    # velocity: the position's derivative with a kernel of two track intervals (a wider one would
    # attenuate the velocity itself: 18 % at 1 Hz for 100 ms)
    track = _track(rec)
    v_sigma = 2.0 * max(float(np.median(np.diff(track[0]))), float(np.median(np.diff(np.asarray(rec.t, float)))))
    gt = groundtruth_table(np.asarray(rec.t, float), track, tau, R, r, b_gyr, b_acc, t0=t0, sigma=v_sigma, skew_ppm=skew,
                           epoch=out["clock_skew_epoch_s"])
    out["groundtruth_rows"] = int(len(gt))
    out["runtime_s"] = time.perf_counter() - t_start
    return AlignResult(out, rep, gt, results, {k: p.t for k, p in preps.items()})


def alignment_figure(res: AlignResult):
    """Before/after residuals: each sensor's output against the raw reference (no alignment,
    identity frames, no delay) and against the aligned model, rms in 2 s windows."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    sens = list(res.results)
    fig, ax = plt.subplots(len(sens), 1, figsize=(10, 3.2 * len(sens)), squeeze=False)
    for k, s in enumerate(sens):
        r = res.results[s]
        rows = r.fit_rows
        t = res.t[s]
        w = max(1, int(round(2.0 / float(np.median(np.diff(t))))))
        for lab, resid in (("before (raw reference, identity frames, no delay)", None), ("baseline affine, no delay", r.base_all.resid),
                           ("aligned (affine + time offset + lever arm)", r.final_all.resid)):
            if resid is None:
                continue
            e2 = np.where(rows, np.sum(resid**2, 1), 0.0)
            c = np.convolve(e2, np.ones(w), "same") / np.maximum(np.convolve(rows.astype(float), np.ones(w), "same"), 1)
            ax[k, 0].semilogy(t, np.sqrt(c), label=lab)
        ax[k, 0].set(xlabel="time (s)", ylabel=f"|residual| rms ({'g' if s == 'acc' else 'rad/s'})", title=f"{s}: before / after alignment")
        ax[k, 0].legend(fontsize=8)
    fig.tight_layout()
    return fig


def write_alignment(out_dir: str | os.PathLike, res: AlignResult, figure: bool = True) -> None:
    """Write ``align.json``, ``groundtruth.csv`` (EuRoC columns), ``report.json``/``report.md`` of the
    diagnosis behind it and ``align_residuals.png``.

    Args:
        out_dir: output directory (created if missing).
        res: the result of :func:`align_recording`.
        figure: also write ``align_residuals.png``.
    """
    from jaxcal.diagnose.report import write_report

    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    (d / "align.json").write_text(json.dumps(res.align, indent=1, default=float))
    fmt = ["%d"] + ["%.9f"] * 16
    np.savetxt(d / "groundtruth.csv", res.groundtruth, delimiter=",", fmt=fmt, header=",".join(EUROC_GT_COLUMNS)[1:], comments="#")
    write_report(d, res.report, None)
    if figure:
        import matplotlib.pyplot as plt

        fig = alignment_figure(res)
        fig.savefig(d / "align_residuals.png", dpi=110)
        plt.close(fig)
