"""A recording scored against its motion capture (pose reference) with ``jaxcal diagnose``.

:func:`mocap_summary` puts the RMS of the recording as it is (its maker's calibration, nothing
fitted) beside the held-out RMS of jaxcal's baseline re-calibration and of the baseline plus the
effects ``diagnose`` names, per sensor.
"""

from __future__ import annotations

import numpy as np

from jaxcal.diagnose import effects as E
from jaxcal.diagnose import prepare as diag_prepare
from jaxcal.diagnose.select import linearize_baseline

__all__ = ["as_recorded_rms", "mocap_summary"]


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
