"""Rotation sequences: splitting a recording into its sequences, and the labelled sequence sets.

A recording of rotation sequences (thesis section 4.2; CONVENTIONS.md) carries one integer
``seq`` id per sample, the samples of one sequence contiguous. This module turns such flat
``(L, 3)`` arrays into per-sequence arrays, in the two layouts the algorithms use:

* :func:`split_equal`: ``(M, N, 3)`` when every sequence has the same length ``N`` (the thesis's
  algorithm, :mod:`jaxcal.online_thesis`);
* :func:`pad_with_mask`: ``(M, N_max, ...)`` padded with a ``(M, N_max)`` validity mask when the
  lengths differ (the streaming filter, :mod:`jaxcal.online`).

It also defines the data types of labelled sequence sets (:class:`Sequences`, :class:`Samples`,
:class:`Dataset2`): the simulators (:mod:`jaxcal.simulate`) produce them and the algorithms
consume them, so neither imports the other.

Pure numpy, no I/O, and no JAX at import (:mod:`jaxcal.recording` re-exports
:func:`sequence_bounds`); the data types hold JAX or numpy arrays and name their array types for
type checkers only. Dimension letters: ``L`` samples of a recording, ``M`` sequences, ``N``
samples per sequence.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:  # annotations only: importing jaxtyping or jaxcal.sensor would import JAX
    from jaxtyping import Array, Float

    from jaxcal.sensor import Diag

__all__ = [
    "Dataset2",
    "Samples",
    "Sequences",
    "first_repeated_run",
    "pad_with_mask",
    "sequence_bounds",
    "split_equal",
]


# ----------------------------------------------------------------------------- splitting


def sequence_bounds(seq: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``(starts, ends)`` of the runs of equal consecutive ids in ``seq`` (ends exclusive)."""
    seq = np.asarray(seq)
    starts = np.flatnonzero(np.r_[True, seq[1:] != seq[:-1]])
    return starts, np.r_[starts[1:], seq.shape[0]]


def first_repeated_run(seq: npt.ArrayLike) -> int | None:
    """First sample of the first run whose id already appeared in an earlier run (the first place
    where a sequence is not contiguous), or ``None`` if every id forms one run."""
    seq = np.asarray(seq)
    starts, _ = sequence_bounds(seq)
    _, first = np.unique(seq[starts], return_index=True)
    if first.size == starts.size:
        return None
    return int(starts[np.setdiff1d(np.arange(starts.size), first)[0]])


def split_equal(x: npt.ArrayLike, seq: npt.ArrayLike) -> np.ndarray:
    """Split a recording into its sequences of equal length: ``x`` ``(L, 3)`` -> ``(M, N, 3)``.

    ``seq`` holds one id per sample; samples of one sequence must be contiguous and every sequence
    must have the same length ``N >= 2``. Raises ``ValueError`` naming the offending sequence
    otherwise (non-contiguous id, unequal lengths).

    Args:
        x: (L, 3) samples.
        seq: (L,) sequence id per sample.
    """
    x = np.asarray(x)
    seq = np.asarray(seq)
    if seq.ndim != 1 or x.ndim != 2 or x.shape[0] != seq.shape[0] or x.shape[1] != 3:
        raise ValueError(f"expected samples (L, 3) and seq (L,), got {x.shape} and {seq.shape}")
    repeat = first_repeated_run(seq)
    if repeat is not None:
        raise ValueError(f"seq id {seq[repeat]} is not contiguous: samples of one sequence must be adjacent")
    starts, ends = sequence_bounds(seq)
    ids = seq[starts]
    lengths = ends - starts
    if np.any(lengths != lengths[0]):
        bad = int(np.flatnonzero(lengths != lengths[0])[0])
        raise ValueError(
            f"sequences must have equal length: seq id {ids[0]} has {lengths[0]} samples, "
            f"seq id {ids[bad]} has {lengths[bad]}"
        )
    if lengths[0] < 2:
        raise ValueError("every sequence needs at least 2 samples")
    return x.reshape(len(ids), int(lengths[0]), 3)


def pad_with_mask(x: npt.ArrayLike, seq: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Split contiguous runs of equal ``seq`` (``(L,)`` ids) in ``x`` (``(L, ...)``) into a padded
    float64 ``(M, N_max, ...)`` array and its ``(M, N_max)`` validity mask (1 on samples, 0 on
    padding).

    Padding repeats the last sample of the sequence (a valid value; masked anyway).

    Args:
        x: (L, ...) samples.
        seq: (L,) sequence id per sample (contiguous runs).
    """
    x = np.asarray(x)
    starts, ends = sequence_bounds(seq)
    lmax = int(np.max(ends - starts))
    padded = np.zeros((len(starts), lmax) + x.shape[1:])
    mask = np.zeros((len(starts), lmax))
    for i, (s, e) in enumerate(zip(starts, ends)):
        padded[i, : e - s] = x[s:e]
        mask[i, : e - s] = 1.0
        padded[i, e - s :] = x[e - 1]
    return padded, mask


# ----------------------------------------------------------------------------- labelled sets


class Sequences(NamedTuple):
    """A set of ``M`` sequences of ``N`` samples: raw outputs (LSB) and the truth they were made from.

    Args:
        acc, gyr: raw accelerometer / gyroscope outputs (LSB).
        acc_true, gyr_true: true specific force (g) / body rate (rad/s).
    """

    acc: Float[Array, "M N 3"]
    gyr: Float[Array, "M N 3"]
    acc_true: Float[Array, "M N 3"]
    gyr_true: Float[Array, "M N 3"]


class Samples(NamedTuple):
    """A test set: raw outputs (LSB) and truth (g or rad/s).

    Args:
        raw: sensor outputs (LSB).
        true: the values they measure (g or rad/s).
    """

    raw: Float[Array, "L 3"]
    true: Float[Array, "L 3"]


class Dataset2(NamedTuple):
    """Everything thesis section 4.2 defines (Dataset 2), plus the hidden truth for scoring.

    Made by :func:`jaxcal.simulate.dataset2`; used by :func:`jaxcal.online_thesis.run_online_thesis`.

    Args:
        train, val: training and validation sequences.
        test_acc, test_gyr: the accelerometer and gyroscope test sets.
        acc_true_model, gyr_true_model: the true sensor models (hidden from the algorithms).
        acc_spec, gyr_spec: the datasheet ("spec") models.
        dt: sample period (s).
    """

    train: Sequences
    val: Sequences
    test_acc: Samples
    test_gyr: Samples
    acc_true_model: Diag
    gyr_true_model: Diag
    acc_spec: Diag
    gyr_spec: Diag
    dt: float
