"""A fitted model scored on another recording (``jaxcal score MODEL REC``): the figures a method
reports held out, computed from the model's applied output on a recording it was not fitted on.

:func:`score_outputs` takes the calibrated output (``model.apply(rec)``: ``acc_cal`` in g,
``gyr_cal`` in rad/s) and the recording, and scores it with every truth the recording carries, on
items chosen from the recording alone (so two models are scored on the same items):

- ``labels`` (``acc_ref`` / ``gyr_ref``): RMS of the row-wise error norm against the labels, as the
  labelled methods' quality (:mod:`jaxcal.methods.quality`): ``acc_rms_mg``, ``gyr_rms_degs``;
- ``sequences`` (``seq`` ids, both sensors): each sequence by its first and last samples, as
  :func:`jaxcal.eval.seqsplit.time_split_rows` scores them: ``acc_rms_mg``, ``gyr_median_deg``;
- ``rests`` (no ``seq``, both sensors): the rests detected on the raw recording as ``multipos`` and
  ``online`` detect them (:func:`jaxcal.multipos.detect_rests`, default options) and the motions
  between them: ``| |f| - 1 g |`` RMS (mg) and the median carried-gravity angle (deg);
- ``mocap`` (``pos_ref`` + ``quat_ref``): RMS of the output minus the reference the pose gives,
  in each sensor's trusted band (:func:`jaxcal.eval.mocap.calibrated_rms`, the band chosen on the
  recording itself): ``acc_rms_mg``, ``gyr_rms_degs``.

A truth the recording lacks gives no row; one that cannot be computed gives ``{"error": ...}``.
Pure: no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from jaxcal import multipos as mp
from jaxcal.eval import seqsplit
from jaxcal.eval.scores import QualityRow, quality_row
from jaxcal.recording import Recording

__all__ = ["label_row", "mocap_row", "rest_row", "score_outputs", "sequence_row"]

_TO_ROW = {"acc": ("acc_rms_mg", 1e3), "gyr": ("gyr_rms_degs", 180.0 / math.pi)}


def _rms(e: np.ndarray) -> float:
    """Root mean square of the row norms of ``e``."""
    return float(np.sqrt(np.mean(np.sum(np.asarray(e, np.float64) ** 2, axis=-1))))


def label_row(rec: Recording, outputs: Mapping[str, np.ndarray]) -> QualityRow | None:
    """RMS of the output's error against the labels (rows where the label is finite); ``None``
    without labels for an output sensor.

    Args:
        rec: the recording (``acc_ref`` in g, ``gyr_ref`` in rad/s).
        outputs: ``{"acc_cal", "gyr_cal"}`` on ``rec``'s samples (either may be absent).
    """
    row: dict = {}
    counts = []
    for s in ("acc", "gyr"):
        ref = getattr(rec, f"{s}_ref")
        if f"{s}_cal" not in outputs or ref is None:
            continue
        ref = np.asarray(ref, np.float64)
        ok = np.isfinite(ref).all(axis=1)
        key, k = _TO_ROW[s]
        row[key] = k * _rms(np.asarray(outputs[f"{s}_cal"], np.float64)[ok] - ref[ok])
        counts.append(f"{int(ok.sum())} {s} rows")
    if not row:
        return None
    return row | {"how": f"against the labels ({', '.join(counts)})"}  # type: ignore[return-value]


def sequence_row(rec: Recording, outputs: Mapping[str, np.ndarray]) -> QualityRow | None:
    """Each sequence scored by its first and last samples (:mod:`jaxcal.eval.seqsplit`); ``None``
    without ``seq`` or without both sensors' outputs.

    Args:
        rec: the recording.
        outputs: ``{"acc_cal", "gyr_cal"}`` on ``rec``'s samples.
    """
    if rec.seq is None or "acc_cal" not in outputs or "gyr_cal" not in outputs:
        return None
    bounds = seqsplit.seq_bounds(rec)
    if not bounds:
        return {"error": "no sequence of two or more samples"}
    ea, eg = seqsplit.applied_errors(outputs["acc_cal"], outputs["gyr_cal"], rec, bounds)
    return quality_row(ea, eg[::2], f"first and last samples of all {len(bounds)} sequences")


def rest_row(rec: Recording, outputs: Mapping[str, np.ndarray],
             detect: mp.DetectOptions | None = None) -> QualityRow | None:
    """The output on the rests detected in the raw recording and the motions between them;
    ``None`` with ``seq`` ids or without both sensors' outputs.

    Args:
        rec: the recording (raw ``acc`` and ``gyr``: the rests are found there, model-free).
        outputs: ``{"acc_cal", "gyr_cal"}`` on ``rec``'s samples.
        detect: how rests are found; ``None``: ``multipos``'s defaults
            (:meth:`~jaxcal.multipos.DetectOptions.for_recording`).
    """
    if rec.seq is not None or "acc_cal" not in outputs or "gyr_cal" not in outputs:
        return None
    det = mp.DetectOptions.for_recording(rec) if detect is None else detect
    try:
        iv = mp.detect_rests(rec, det)
    except ValueError as e:
        return {"error": f"rests: {e}"}
    if len(iv) < 2:
        return {"error": f"rests: {len(iv)} rest found; the score needs two or more"}
    ea, eg = seqsplit.interval_errors(outputs["acc_cal"], outputs["gyr_cal"], rec, iv, det.gyr_limit)
    return quality_row(ea, eg, f"all {len(iv)} rests and the {int(np.isfinite(eg).sum())} usable motions between them")


def mocap_row(rec: Recording, outputs: Mapping[str, np.ndarray]) -> QualityRow | None:
    """RMS of the output against the reference motion of the recording's pose track, in each
    sensor's trusted band chosen on the recording (:func:`jaxcal.eval.mocap.calibrated_rms`);
    ``None`` without a pose reference.

    Args:
        rec: the recording (``pos_ref`` and ``quat_ref``).
        outputs: ``{"acc_cal", "gyr_cal"}`` on ``rec``'s samples (either may be absent).
    """
    if rec.pos_ref is None or rec.quat_ref is None:
        return None
    from jaxcal.diagnose import prepare
    from jaxcal.eval.mocap import calibrated_rms

    try:
        sigma = prepare(rec, pose_sigma=None).sigma_by_sensor
        res = calibrated_rms(rec, dict(outputs), sigma)
    except ValueError as e:
        return {"error": f"mocap: {e}"}
    if not res:
        return {"error": "mocap: no sensor of the output has a trusted band"}
    row: dict = {_TO_ROW[s][0]: _TO_ROW[s][1] * r["rms"] for s, r in res.items()}
    bands = ", ".join(f"{s} {r['n_rows']} rows, Gaussian {1e3 * r['sigma_s']:.0f} ms" for s, r in res.items())
    return row | {"how": f"against the pose reference, in its trusted band ({bands})"}  # type: ignore[return-value]


def score_outputs(rec: Recording, outputs: Mapping[str, np.ndarray],
                  detect: mp.DetectOptions | None = None) -> dict[str, QualityRow]:
    """Every score of a calibrated output that ``rec`` can give (module docstring): ``labels``,
    ``sequences`` or ``rests``, ``mocap``; only the rows the recording's truth allows.

    Args:
        rec: the recording the output was computed on (not the one the model was fitted on, for a
            held-out figure).
        outputs: ``{"acc_cal": (N, 3) g, "gyr_cal": (N, 3) rad/s}`` (either may be absent).
        detect: how :func:`rest_row` finds the rests (``None``: ``multipos``'s defaults).
    """
    rows = {"labels": label_row(rec, outputs), "sequences": sequence_row(rec, outputs),
            "rests": rest_row(rec, outputs, detect), "mocap": mocap_row(rec, outputs)}
    return {k: v for k, v in rows.items() if v is not None}
