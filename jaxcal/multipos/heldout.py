"""Held-out multipos scores: leave-poses-out folds, all fitted in one ``vmap``."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal.multipos.acc import acc_norm_errors
from jaxcal.multipos.data import MultiposData
from jaxcal.multipos.fit import MultiposConfig, fit_prepared
from jaxcal.multipos.gyro import gyro_angle_errors

__all__ = ["HeldOut", "fold_ids", "leave_poses_out"]


class HeldOut(NamedTuple):
    """Leave-poses-out scores: ``acc_err`` (P,) ``| |f| - 1 |`` in g of each pose from the fold
    that left it out, ``gyr_err`` (J,) the carried-gravity angle (rad) of each transition from
    the fold that left it out (NaN for unusable transitions), and the fold of each."""

    acc_err: np.ndarray
    gyr_err: np.ndarray
    pose_fold: np.ndarray
    trans_fold: np.ndarray


def fold_ids(n: int, n_folds: int) -> np.ndarray:
    """Interleaved folds: item ``i`` goes to fold ``i mod n_folds``.

    Args:
        n: number of items.
        n_folds: number of folds.
    """
    return np.arange(n) % n_folds


def leave_poses_out(
    data: MultiposData, config: MultiposConfig = MultiposConfig(), n_folds: int | None = None
) -> HeldOut:
    """Held-out scores with interleaved folds over poses (and transitions), all folds fitted in
    one ``vmap`` of :func:`fit_prepared`. ``n_folds=None`` leaves one pose (and one transition)
    out at a time. Fold ``k`` leaves out poses ``i = k mod n_folds`` from the accelerometer fit and
    transitions ``j = k mod n_folds`` from the gyroscope fit, then scores exactly those.

    Args:
        data: prepared poses and transitions (numpy or JAX arrays).
        config: :class:`~jaxcal.multipos.fit.MultiposConfig` (static).
        n_folds: number of interleaved folds; ``None``: one per pose.
    """
    P = data.pose_acc.shape[0]
    F = P if n_folds is None else n_folds
    pf, tf = fold_ids(P, F), fold_ids(P - 1, F)
    with jax.enable_x64(True):
        d = jax.tree_util.tree_map(jnp.asarray, data)
        aw = jnp.asarray((pf[None, :] != np.arange(F)[:, None]).astype(np.float64))
        gw = jnp.asarray((tf[None, :] != np.arange(F)[:, None]).astype(np.float64))

        @jax.jit
        def run(aw, gw):
            fits = jax.vmap(lambda a, g: fit_prepared(d, config, acc_w=a, gyr_w=g))(aw, gw)
            ea = jax.vmap(lambda f: acc_norm_errors(f.acc, d.pose_acc))(fits)
            eg = jax.vmap(lambda f: gyro_angle_errors(f.gyr, f.gsens, f.acc, d))(fits)
            return ea, eg

        ea, eg = (np.asarray(x) for x in run(aw, gw))
    acc_err = ea[pf, np.arange(P)]
    gyr_err = np.where(np.asarray(data.seg_ok), eg[tf, np.arange(P - 1)], np.nan)
    return HeldOut(acc_err, gyr_err, pf, tf)
