"""Held-out multipos scores: leave-poses-out folds, all fitted inside one compiled ``lax.map``."""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal.multipos.acc import acc_norm_errors
from jaxcal.multipos.data import MultiposData
from jaxcal.multipos.fit import MultiposConfig, fit_prepared
from jaxcal.multipos.gyro import gyro_angle_errors
from jaxcal.precision import float64

__all__ = ["HeldOut", "fold_batch", "fold_ids", "fold_scores", "jackknife_sd", "leave_poses_out"]


class HeldOut(NamedTuple):
    """Leave-poses-out scores: ``acc_err`` (P,) ``| |f| - 1 |`` in g of each pose from the fold
    that left it out, ``gyr_err`` (J,) the carried-gravity angle (rad) of each transition from
    the fold that left it out (NaN for unusable transitions), and the fold of each; ``acc_bias``,
    ``gyr_bias`` (F, 3) each fold's fitted biases (input units) and ``acc_A``, ``gyr_A`` (F, 3, 3)
    its ``A`` of ``x = A (y - b)``, for :func:`jackknife_sd`."""

    acc_err: np.ndarray
    gyr_err: np.ndarray
    pose_fold: np.ndarray
    trans_fold: np.ndarray
    acc_bias: np.ndarray | None = None
    gyr_bias: np.ndarray | None = None
    acc_A: np.ndarray | None = None
    gyr_A: np.ndarray | None = None


def fold_ids(n: int, n_folds: int) -> np.ndarray:
    """Interleaved folds: item ``i`` goes to fold ``i mod n_folds``.

    Args:
        n: number of items.
        n_folds: number of folds.
    """
    return np.arange(n) % n_folds


@partial(jax.jit, static_argnames=("config", "batch"))
def fold_scores(
    d: MultiposData, config: MultiposConfig, aw: jax.Array, gw: jax.Array, batch: int
) -> tuple[jax.Array, ...]:
    """Every fold's fit (weights ``aw`` (F, P), ``gw`` (F, J)) and its scores on all poses (F, P)
    and transitions (F, J), its accelerometer and gyroscope biases (F, 3) each and their ``A``
    (F, 3, 3) each, ``batch`` folds
    at a time in one ``vmap`` (``lax.map``; 1: one after another). The data is an argument, not a
    closure constant: one compilation per shape, config and batch (the persistent cache keeps it),
    not one per call."""

    def one(weights: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, ...]:
        f = fit_prepared(d, config, acc_w=weights[0], gyr_w=weights[1])
        return (acc_norm_errors(f.acc, d.pose_acc), gyro_angle_errors(f.gyr, f.gsens, f.acc, d), f.acc.b, f.gyr.b,
                f.acc.A, f.gyr.A)

    return jax.lax.map(one, (aw, gw), batch_size=batch if batch > 1 else None)


def fold_batch(n_folds: int) -> int:
    """How many folds :func:`leave_poses_out` fits in one ``vmap`` by default: all on an
    accelerator; one at a time on a CPU, where a vmapped Levenberg-Marquardt loop runs every fold
    until the slowest has converged and holds every fold's intermediates at once (the Xsens
    session's 40 folds: 9.6 s in one vmap, 3.75 s one after another; compiling 5.1 s against 3.1 s:
    ``python -m benchmarks.multipos_folds``)."""
    return 1 if jax.default_backend() == "cpu" else n_folds


@float64
def leave_poses_out(
    data: MultiposData, config: MultiposConfig = MultiposConfig(), n_folds: int | None = None,
    batch: int | None = None,
) -> HeldOut:
    """Held-out scores with interleaved folds over poses (and transitions), every fold a
    :func:`fit_prepared` inside one compiled ``lax.map``. ``n_folds=None`` leaves one pose (and one
    transition) out at a time. Fold ``k`` leaves out poses ``i = k mod n_folds`` from the
    accelerometer fit and transitions ``j = k mod n_folds`` from the gyroscope fit, then scores
    exactly those.

    Args:
        data: prepared poses and transitions (numpy or JAX arrays).
        config: :class:`~jaxcal.multipos.fit.MultiposConfig` (static).
        n_folds: number of interleaved folds; ``None``: one per pose.
        batch: folds fitted together in one ``vmap`` (static); ``None``: :func:`fold_batch`.
    """
    P = data.pose_acc.shape[0]
    F = P if n_folds is None else n_folds
    pf, tf = fold_ids(P, F), fold_ids(P - 1, F)
    d = jax.tree_util.tree_map(jnp.asarray, data)
    aw = jnp.asarray((pf[None, :] != np.arange(F)[:, None]).astype(np.float64))
    gw = jnp.asarray((tf[None, :] != np.arange(F)[:, None]).astype(np.float64))

    ea, eg, ba, bg, Aa, Ag = (np.asarray(x) for x in fold_scores(d, config, aw, gw, fold_batch(F) if batch is None else int(batch)))
    acc_err = ea[pf, np.arange(P)]
    gyr_err = np.where(np.asarray(data.seg_ok), eg[tf, np.arange(P - 1)], np.nan)
    return HeldOut(acc_err, gyr_err, pf, tf, ba, bg, Aa, Ag)


def jackknife_sd(values: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
    """The grouped (delete-a-group) jackknife standard error of an estimate from its fold values:
    ``sqrt((G - 1) / G sum_g (v_g - mean)^2)`` over the ``G`` folds kept (the delete-a-group
    jackknife; Efron & Tibshirani, An Introduction to the Bootstrap, ch. 11). From :func:`leave_poses_out`'s ``acc_bias`` /
    ``gyr_bias`` it is the standard error of the session's bias estimate, poses resampled: the
    between-pose spread (bias instability, an unmodelled g-sensitivity) counts, the part's turn-on
    repeatability does not.

    Args:
        values: (G, ...) each fold's estimate.
        keep: (G,) bool, folds used (default all); fewer than 2 give NaN.
    """
    v = np.asarray(values, np.float64)
    v = v if keep is None else v[np.asarray(keep, bool)]
    g = v.shape[0]
    if g < 2:
        return np.full(v.shape[1:], np.nan)
    return np.sqrt((g - 1) / g * np.sum((v - v.mean(0)) ** 2, 0))
