"""Row operations on a :class:`~jaxcal.recording.Recording`: the per-sample fields, a row subset
(:func:`take_rows`), a stretch of time (:func:`crop`) and the sample ranges of its sequences
(:func:`sequence_slices`)."""

from __future__ import annotations

import numpy as np

from jaxcal.recording.types import Recording
from jaxcal.sequences import sequence_bounds

PER_SAMPLE_FIELDS = ("t", "acc", "gyr", "temp", "seq", "static", "acc_ref", "gyr_ref", "pos_ref", "quat_ref", "mag",
                     "ref_valid", "section")
"""The fields with one row per sample (``t``'s length), which :func:`take_rows` cuts."""


def take_rows(rec: Recording, mask: np.ndarray) -> Recording:
    """The recording restricted to the rows where ``mask`` is true (per-sample fields only; extras
    and reference tracks dropped).

    Args:
        rec: the recording.
        mask: (N,) bool.
    """
    changes = {f: np.asarray(getattr(rec, f))[mask] for f in PER_SAMPLE_FIELDS if getattr(rec, f) is not None}
    return rec.replace(**changes, extra={}, gt_t=None, gt_pos=None, gt_quat=None)


def crop(rec: Recording, start: float, end: float | None = None) -> Recording:
    """The stretch ``[start, end)`` seconds after the recording's first sample.

    Per-sample fields are cut (:func:`take_rows`); the original reference track (``gt_*``) keeps its
    samples inside the stretch; extras whose first axis is the sample axis are cut, others kept.

    Args:
        rec: the recording.
        start: seconds after ``rec.t[0]`` (>= 0).
        end: seconds after ``rec.t[0]`` (None: to the end).

    Raises:
        ValueError: ``start`` < 0, ``end`` <= ``start``, or fewer than 2 samples in the stretch.
    """
    t = np.asarray(rec.t, np.float64)
    rel = t - t[0]
    stop = np.inf if end is None else float(end)
    if not (start >= 0 and stop > start):
        raise ValueError(f"the stretch must have 0 <= start < end, got start {start}, end {end}")
    keep = (rel >= start) & (rel < stop)
    if keep.sum() < 2:
        raise ValueError(f"the stretch {start}-{end} s holds {int(keep.sum())} samples; the recording lasts "
                         f"{rel[-1]:.3f} s")
    out = take_rows(rec, keep)
    extra = {k: (np.asarray(v)[keep] if np.ndim(v) >= 1 and len(v) == len(t) else v) for k, v in rec.extra.items()}
    if rec.gt_t is not None:
        g = (rec.gt_t >= t[0] + start) & (rec.gt_t < t[0] + stop)
        g = g if g.sum() >= 2 else np.zeros_like(g)
        out = out if not g.any() else out.replace(gt_t=rec.gt_t[g], gt_pos=None if rec.gt_pos is None else rec.gt_pos[g],
                          gt_quat=None if rec.gt_quat is None else rec.gt_quat[g])
    return out.replace(extra=extra)


def sequence_slices(rec: Recording) -> list[slice]:
    """Sample ranges of the contiguous sequences (one slice over everything if ``seq`` is absent)."""
    if rec.seq is None:
        return [slice(0, rec.n)]
    return [slice(int(a), int(b)) for a, b in zip(*sequence_bounds(rec.seq))]
