"""Scores on a recording with ``seq`` ids (the thesis's Dataset 2 setting): each sequence by its
first and last samples (rests in Dataset 2): ``| |f| - 1 g |`` there and the gravity carried from
the first to the last (:func:`jaxcal.eval.scores.score_cal`); held out, a time split of the
sequences (fitted on the first 80 %, scored on the last 20 %). The caller brings the fit (an
``online`` filter, or any method refitted and scored through its applied output).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from jaxcal import multipos as mp
from jaxcal.eval.scores import QualityRow, quality_row, score_cal
from jaxcal.recording import Recording
from jaxcal.sensor import LinearCal
from jaxcal.sequences import sequence_bounds

__all__ = ["HELD_OUT_SHARE", "Bounds", "Errors", "applied_errors", "ends_data", "interval_errors", "seq_bounds", "time_split_rows"]

HELD_OUT_SHARE = 0.2  # the last fifth of the sequences is the held-out time split

Bounds = Sequence[tuple[int, int]]
Errors = tuple[np.ndarray, np.ndarray]


def ends_data(rec: Recording, bounds: Bounds) -> mp.MultiposData:
    """Each sequence's first and last samples as two poses with the sequence between them
    (:func:`jaxcal.multipos.prepare`); transitions ``2k`` are the sequences, the others join two
    sequences and are not scored.

    Args:
        rec: the recording (raw ``acc`` and ``gyr``).
        bounds: the sequences' sample ranges ``[(a, b), ...)``.
    """
    iv = np.array([p for a, b in bounds for p in ((a, a + 1), (b - 1, b))], int)
    return mp.prepare(np.asarray(rec.t, np.float64), rec.acc, rec.gyr, iv,
                      gyr_limit=mp.DetectOptions.for_recording(rec).gyr_limit)


def applied_errors(acc_cal: np.ndarray, gyr_cal: np.ndarray, rec: Recording, bounds: Bounds) -> Errors:
    """:func:`~jaxcal.eval.scores.score_cal` of a model's applied output (g, rad/s) at the
    sequences' ends (the identity calibration on it); a sequence whose raw gyro saturates is not
    scored.

    Args:
        acc_cal, gyr_cal: (N, 3) the model's output on ``rec``.
        rec: the raw recording (its gyro saturation decides which sequences are scored).
        bounds: the sequences' sample ranges.
    """
    iv = np.array([p for a, b in bounds for p in ((a, a + 1), (b - 1, b))], int)
    return interval_errors(acc_cal, gyr_cal, rec, iv, mp.DetectOptions.for_recording(rec).gyr_limit)


def interval_errors(acc_cal: np.ndarray, gyr_cal: np.ndarray, rec: Recording, iv: np.ndarray,
                    gyr_limit: float | None) -> Errors:
    """:func:`~jaxcal.eval.scores.score_cal` of a model's applied output (g, rad/s) with the sample
    ranges ``iv`` as poses (the identity calibration on it): per-pose ``| |f| - 1 |`` (g) and
    per-transition carried-gravity angles (rad); a transition whose raw gyro reaches ``gyr_limit``
    is not scored (NaN).

    Args:
        acc_cal, gyr_cal: (N, 3) the model's output on ``rec``.
        rec: the raw recording (its gyro saturation decides which transitions are scored).
        iv: (P, 2) the poses' sample ranges ``[a, b)``.
        gyr_limit: the raw gyro's saturation limit, or ``None``.
    """
    t = np.asarray(rec.t, np.float64)
    d = mp.prepare(t, np.asarray(acc_cal, np.float64), np.asarray(gyr_cal, np.float64), iv)
    raw = mp.prepare(t, rec.acc, rec.gyr, iv, gyr_limit=gyr_limit)
    d = d._replace(seg_ok=np.asarray(d.seg_ok) & np.asarray(raw.seg_ok))
    ident = LinearCal(np.eye(3), np.zeros(3))
    return score_cal(ident, ident, d)


def seq_bounds(rec: Recording) -> list[tuple[int, int]]:
    """The sample ranges of ``rec``'s sequences with at least two samples, in order."""
    starts, ends = sequence_bounds(rec.seq)
    return [(int(a), int(b)) for a, b in zip(starts, ends) if b - a >= 2]


def time_split_rows(rec: Recording, held_out: bool, score: Callable[[Bounds], Errors],
                    fit_score: Callable[[Bounds, Bounds], Errors], verb: str,
                    initial: tuple[LinearCal, LinearCal] | None = None) -> tuple[QualityRow, QualityRow | None]:
    """In-sample and time-split rows on a recording with ``seq`` ids.

    Args:
        rec: the recording (``seq`` ids).
        held_out: also compute the held-out row.
        score: ``score(bounds)`` scores the sequences with sample ranges ``bounds``.
        fit_score: ``fit_score(train, test)`` fits on the ``train`` sequences (the first 80 %) and
            scores the ``test`` ones (the last 20 %); a ``ValueError`` becomes the row's ``error``.
        verb: how the held-out fit was made (``"fitted"``, ``"refitted"``), for the row's ``how``.
        initial: the starting point of the fit (the datasheet values), scored on the same test
            sequences as ``initial_guess``; ``None``: no such row.

    Returns:
        ``(in_sample, held_out)`` (``held_out`` ``None`` when not asked for).
    """
    bounds = seq_bounds(rec)
    M = len(bounds)
    ea, eg = score(bounds)
    ins = quality_row(ea, eg[::2], f"first and last samples of all {M} sequences")
    if not held_out:
        return ins, None
    k = max(1, int(round(HELD_OUT_SHARE * M)))
    if M - k < 2:
        return ins, {"error": f"{M} sequences: too few for a held-out time split"}
    try:
        ea, eg = fit_score(bounds[: M - k], bounds[M - k:])
    except ValueError as e:
        return ins, {"error": f"time split: {e}"}
    row = quality_row(ea, eg[::2], f"time split: {verb} on the first {M - k} sequences, scored on the last {k} "
                      "(their first and last samples)")
    if initial is not None:
        ea0, eg0 = score_cal(*initial, ends_data(rec, bounds[M - k:]))
        row["initial_guess"] = quality_row(ea0, eg0[::2], "the same sequences: the datasheet values alone")
    return ins, row
