"""The neural-network sensor model (thesis sections 3.3 and 4.3), flax linen with params pytrees.

An :class:`MLP` maps normalised raw counts (eq. 3.7) to calibrated physical units. The thesis
uses one hidden layer of 7500 leaky-ReLU(0.1) units offline (Fig. 3.2) and 3-5-10-5-3 online
(Fig. 4.5); widths and slope are configurable. Parameters are plain pytrees, so training runs
under ``jax.jit`` / ``lax.scan`` / ``vmap`` with no framework state.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.metrics import mse
from jaxcal.normalise import Bounds, normalise
from jaxcal.train import TrainConfig, TrainResult, fit_full_batch

Params = Any

THESIS_OFFLINE_WIDTHS = (7500,)
THESIS_ONLINE_WIDTHS = (5, 10, 5)
THESIS_LEAKY_SLOPE = 0.1


class MLP(nn.Module):
    """Fully connected network ``3 -> widths... -> out_dim`` with leaky-ReLU hidden layers.

    Static: a flax module definition is hashable and closed over by the fitters; changing a field
    compiles anew.

    Attributes:
        widths: hidden layer widths, e.g. ``(7500,)`` or ``(5, 10, 5)``.
        out_dim: output size (3 for a tri-axis sensor).
        slope: leaky-ReLU negative slope (thesis: 0.1).
    """

    widths: Sequence[int] = THESIS_OFFLINE_WIDTHS
    out_dim: int = 3
    slope: float = THESIS_LEAKY_SLOPE

    @nn.compact
    def __call__(self, x: Float[Array, "... 3"]) -> Float[Array, "... out"]:
        for w in self.widths:
            x = nn.leaky_relu(nn.Dense(w)(x), negative_slope=self.slope)
        return nn.Dense(self.out_dim)(x)


def init_mlp(key: jax.Array, mlp: MLP, in_dim: int = 3) -> Params:
    """Initial parameters (flax defaults: LeCun-normal kernels, zero biases).

    Args:
        key: PRNG key of the initial weights.
        mlp: the network definition (static).
        in_dim: input size (3 for a tri-axis sensor).
    """
    return mlp.init(key, jnp.zeros((1, in_dim)))["params"]


class NNCalibration(NamedTuple):
    """A trained NN calibration: counts -> eq. 3.7 normalisation -> MLP -> physical units."""

    params: Params
    bounds: Bounds


def nn_calibrate(mlp: MLP, cal: NNCalibration, y: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Apply a trained NN calibration to raw counts ``y`` (Fig. 3.3).

    Args:
        mlp: the network definition the calibration was trained with (static).
        cal: trained parameters and their eq. 3.6 bounds.
        y: (..., 3) raw counts (LSB).
    """
    return mlp.apply({"params": cal.params}, normalise(y, cal.bounds))


def weighted_mse(pred: Float[Array, "L 3"], target: Float[Array, "L 3"], w: Float[Array, " L"]) -> Float[Array, ""]:
    """Eq. 2.7 with per-sample weights (0 drops a sample); equals :func:`mse` for ``w = 1``.

    Args:
        pred: (L, 3) model outputs.
        target: (L, 3) labels.
        w: (L,) non-negative per-sample weights.
    """
    return jnp.sum(w[:, None] * (pred - target) ** 2) / (3.0 * jnp.maximum(jnp.sum(w), 1e-12))


def fit_nn(
    key: jax.Array,
    mlp: MLP,
    bounds: Bounds,
    train: tuple[Array, Array, Array],
    val: tuple[Array, Array],
    config: TrainConfig,
    max_epochs: int,
) -> tuple[NNCalibration, TrainResult]:
    """Fit the offline NN sensor model (section 3.3) with full-batch Adam and early stopping.

    Args:
        key: PRNG key for the initial weights.
        mlp: the network definition (static).
        bounds: eq. 3.6 normalisation bounds.
        train: ``(y_counts (L, 3), x_true (L, 3), weights (L,))``; weights select a subset of a
            padded training set so that different subset sizes ``l`` vmap together.
        val: ``(y_counts, x_true)`` for early stopping.
        config: Adam learning rate, patience, min_delta (may be traced).
        max_epochs: static cap on epochs.

    Returns:
        The calibration (best-validation parameters) and the training record.
    """
    y_tr, x_tr, w_tr = train
    y_va, x_va = val
    u_tr, u_va = normalise(y_tr, bounds), normalise(y_va, bounds)

    def loss_fn(params, data):
        u, x, w = data
        return weighted_mse(mlp.apply({"params": params}, u), x, w)

    params0 = init_mlp(key, mlp)
    result = fit_full_batch(
        loss_fn, params0, (u_tr, x_tr, w_tr), (u_va, x_va, jnp.ones(u_va.shape[0])), config, max_epochs
    )
    return NNCalibration(result.params, bounds), result


__all__ = [
    "MLP",
    "NNCalibration",
    "THESIS_LEAKY_SLOPE",
    "THESIS_OFFLINE_WIDTHS",
    "THESIS_ONLINE_WIDTHS",
    "fit_nn",
    "init_mlp",
    "mse",
    "nn_calibrate",
    "weighted_mse",
]
