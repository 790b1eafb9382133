"""Row operations on a :class:`~jaxcal.recording.Recording`: the per-sample fields, a row subset
(:func:`take_rows`) and the sample ranges of its sequences (:func:`sequence_slices`)."""

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


def sequence_slices(rec: Recording) -> list[slice]:
    """Sample ranges of the contiguous sequences (one slice over everything if ``seq`` is absent)."""
    if rec.seq is None:
        return [slice(0, rec.n)]
    return [slice(int(a), int(b)) for a, b in zip(*sequence_bounds(rec.seq))]
