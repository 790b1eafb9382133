"""A recording scored against its motion capture (pose reference) with ``jaxcal diagnose``.

:func:`mocap_summary` puts the RMS of the recording as it is (its maker's calibration, nothing
fitted) beside the held-out RMS of jaxcal's baseline re-calibration and of the baseline plus the
effects ``diagnose`` names, per sensor. :func:`calibrated_rms` scores any calibrated output of a
recording (e.g. a model fitted on another recording) against that recording's own mocap reference,
in a given band, the way :func:`as_recorded_rms` scores the recording as it is; :func:`half` cuts a
recording in two halves in time, so that a model fitted on one is scored on the other's mocap.
"""

from __future__ import annotations

import numpy as np

from jaxcal.diagnose import effects as E
from jaxcal.diagnose import prepare as diag_prepare
from jaxcal.diagnose.select import linearize_baseline
from jaxcal.recording import PER_SAMPLE_FIELDS, Recording, with_calibrated

__all__ = ["as_recorded_rms", "calibrated_rms", "half", "mocap_summary"]


def as_recorded_rms(rec, baseline: str = "affine") -> dict[str, float]:
    """Per sensor, the RMS of the sensor output minus the mocap-derived reference with the identity
    calibration (the recording as its maker calibrated it), over the rows ``diagnose`` uses.

    Args:
        rec: a recording with a pose reference (see ``docs/CONVENTIONS.md``).
        baseline: the baseline whose identity parameters are evaluated.
    """
    prep = diag_prepare(rec)
    out = {}
    for s, sd in prep.sensors.items():
        _, z = linearize_baseline(baseline, sd, E.identity_beta(baseline), np.zeros(E.N_THETA[s]))
        out[s] = float(np.sqrt(np.mean(z[sd.valid] ** 2)))
    return out


def calibrated_rms(rec, outputs: dict, sigma_by_sensor: dict[str, float]) -> dict[str, dict]:
    """Per sensor, the RMS of calibrated outputs minus the reference ``diagnose`` derives from the
    recording's pose, inside each sensor's trusted band (pure).

    The calibrated outputs (g, rad/s, on the recording's samples; e.g. ``model.apply(rec)``) replace
    the recording's ``acc``/``gyr``; the result is prepared as :func:`jaxcal.diagnose.diagnose_banded`
    prepares each sensor (:func:`jaxcal.diagnose.prepare` with that sensor's Gaussian width: the
    reference specific force / body rate from the pose, the outputs smoothed by the same kernel and
    decimated alike, reference gaps and the kernel around them dropped) and scored with the identity
    calibration over the valid rows, as :func:`as_recorded_rms` scores the recording as it is.
    Input-referred (calibrated minus reference): on the recording it was fitted on, a baseline-only
    ``diag`` model's residual is the diagnosis's in-sample baseline residual (output-referred)
    divided by the fitted scale, row for row.

    Args:
        rec: a recording with a pose reference (``pos_ref`` + ``quat_ref``).
        outputs: ``{"acc_cal": (N, 3) g, "gyr_cal": (N, 3) rad/s}`` (either may be absent).
        sigma_by_sensor: each sensor's Gaussian width (s), e.g. ``prepare(rec, pose_sigma=None).sigma_by_sensor``.

    Returns:
        ``{sensor: {"rms", "rms_axes" (3,), "n_rows", "sigma_s"}}`` (g or rad/s) for the sensors in
        both ``outputs`` and ``sigma_by_sensor``.
    """
    sens = [s for s in ("acc", "gyr") if f"{s}_cal" in outputs and s in sigma_by_sensor]
    cal = with_calibrated(rec, {f"{s}_cal": outputs[f"{s}_cal"] for s in sens})
    out = {}
    for s in sens:
        sd = diag_prepare(cal, pose_sigma=float(sigma_by_sensor[s])).sensors[s]
        _, z = linearize_baseline("diag", sd, E.identity_beta("diag"), np.zeros(E.N_THETA[s]))
        zv = z[sd.valid]
        out[s] = {"rms": float(np.sqrt(np.mean(zv**2))), "rms_axes": np.sqrt(np.mean(zv**2, axis=0)).tolist(),
                  "n_rows": int(sd.valid.sum()), "sigma_s": float(sigma_by_sensor[s])}
    return out


def mocap_summary(rec, report: dict, baseline: str = "affine") -> dict:
    """Per sensor: unit, as-recorded RMS, the report's held-out RMS (GLS and OLS) of the baseline and of
    the final model, and the effects named.

    Args:
        rec: the recording ``report`` was computed from.
        report: :func:`jaxcal.diagnose.diagnose_recording`'s report with the same ``baseline``.
        baseline: the baseline of ``report``.
    """
    out = {}
    for s, rms in as_recorded_rms(rec, baseline).items():
        b, f = report["baseline"][s], report["final"][s]
        out[s] = {
            "unit": b["unit"],
            "as_recorded_rms": rms,
            "affine_heldout_rms": b["heldout_rms"],
            "final_heldout_rms": f["heldout_rms"],
            "affine_heldout_rms_ols": b["heldout_rms_ols"],
            "final_heldout_rms_ols": f["heldout_rms_ols"],
            "effects": [f"{e['name']}" for e in report["effects"] if e["sensor"] == s],
        }
    return out


def half(rec: Recording, k: int) -> Recording:
    """The first (``k = 0``) or second (``k = 1``) half of a recording in time (pure): per-sample
    fields cut at the middle time, the original pose track (``gt_*``) kept over the half's span
    (plus 50 ms) so that ``diagnose`` still marks interpolation across missing pose samples.

    Args:
        rec: the recording.
        k: 0 or 1.
    """
    t = np.asarray(rec.t)
    mid = 0.5 * (t[0] + t[-1])
    m = (t < mid) if k == 0 else (t >= mid)
    ch = {f: np.asarray(getattr(rec, f))[m] for f in PER_SAMPLE_FIELDS if getattr(rec, f) is not None}
    if rec.gt_t is not None:
        g = (rec.gt_t >= ch["t"][0] - 0.05) & (rec.gt_t <= ch["t"][-1] + 0.05)
        ch.update(gt_t=np.asarray(rec.gt_t)[g], gt_pos=None if rec.gt_pos is None else np.asarray(rec.gt_pos)[g],
                  gt_quat=None if rec.gt_quat is None else np.asarray(rec.gt_quat)[g])
    return rec.replace(**ch)
