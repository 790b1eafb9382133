"""Losses and error metrics of the thesis (eq. 2.7, 3.8, 4.14)."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Float

from jaxcal.arrays import Array

__all__ = [
    "ErrorStats",
    "error_stats",
    "euclidean_error",
    "mse",
    "sequence_acc_error",
    "sequence_gyro_error",
]


def mse(target: Float[Array, "... K"], pred: Float[Array, "... K"]) -> Float[Array, ""]:
    """Mean squared error over samples and outputs, eq. 2.7.

    Args:
        target: (..., K) reference values.
        pred: (..., K) predictions, same shape and unit.
    """
    return jnp.mean((target - pred) ** 2)


def euclidean_error(truth: Float[Array, "... 3"], cal: Float[Array, "... 3"]) -> Float[Array, "..."]:
    """Per-sample Euclidean error ``e_l = |a_gt,l - a_c,l|``, eq. 3.8.

    Args:
        truth: (..., 3) ground truth (e.g. labels in g).
        cal: (..., 3) calibrated values in the same unit.
    """
    return jnp.sqrt(jnp.sum((truth - cal) ** 2, axis=-1))


class ErrorStats(NamedTuple):
    """Mean and standard deviation of per-sample Euclidean errors (Tables 3.1, 4.1, 4.2)."""

    mean: Float[Array, ""]
    std: Float[Array, ""]


def error_stats(truth: Float[Array, "L 3"], cal: Float[Array, "L 3"]) -> ErrorStats:
    """Mean and (population) standard deviation of eq. 3.8 over a test set.

    Args:
        truth: (L, 3) ground truth of the test set.
        cal: (L, 3) calibrated outputs in the same unit.
    """
    e = euclidean_error(truth, cal)
    return ErrorStats(mean=jnp.mean(e), std=jnp.std(e))


def sequence_gyro_error(gyr_true: Float[Array, "M N 3"], gyr_cal: Float[Array, "M N 3"]) -> Float[Array, ""]:
    """``e_g``, eq. 4.14: Euclidean gyroscope error averaged over all samples of all sequences.

    Args:
        gyr_true: (M, N, 3) true rates of ``M`` sequences of ``N`` samples (rad/s).
        gyr_cal: (M, N, 3) calibrated rates.
    """
    return jnp.mean(euclidean_error(gyr_true, gyr_cal))


def sequence_acc_error(acc_true_last: Float[Array, "M 3"], acc_cal_last: Float[Array, "M 3"]) -> Float[Array, ""]:
    """``e_a``, eq. 4.14: Euclidean accelerometer error at the last (static) sample of each sequence.

    Args:
        acc_true_last: (M, 3) true specific force at each sequence's last sample (g).
        acc_cal_last: (M, 3) calibrated accelerometer output there.
    """
    return jnp.mean(euclidean_error(acc_true_last, acc_cal_last))
