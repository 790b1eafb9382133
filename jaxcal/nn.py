"""The neural-network sensor model (thesis sections 3.3 and 4.3), flax linen with params pytrees.

An :class:`MLP` maps normalised raw counts (eq. 3.7) to calibrated physical units. The thesis
uses one hidden layer of 7500 leaky-ReLU(0.1) units offline (Fig. 3.2) and 3-5-10-5-3 online
(Fig. 4.5); widths and slope are configurable. Parameters are plain pytrees, so training runs
under ``jax.jit`` / ``lax.scan`` / ``vmap`` with no framework state.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.metrics import mse
from jaxcal.normalise import Bounds, normalise
from jaxcal.train import TrainConfig, TrainResult, ValueAndGradFn, fit_full_batch

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


#: :func:`nn_calibrate` compiled, ``mlp`` static.
nn_calibrate_jit = jax.jit(nn_calibrate, static_argnames=("mlp",))


def weighted_mse(pred: Float[Array, "L 3"], target: Float[Array, "L 3"], w: Float[Array, " L"]) -> Float[Array, ""]:
    """Eq. 2.7 with per-sample weights (0 drops a sample); equals :func:`mse` for ``w = 1``.

    Args:
        pred: (L, 3) model outputs.
        target: (L, 3) labels.
        w: (L,) non-negative per-sample weights.
    """
    return jnp.sum(w[:, None] * (pred - target) ** 2) / (3.0 * jnp.maximum(jnp.sum(w), 1e-12))


def hidden_features(mlp: MLP, params: Params, u: Float[Array, "N 3"]) -> Float[Array, "N H"]:
    """Activations of the last hidden layer (the features the output layer combines linearly).

    Args:
        mlp: the network definition (static; flax names its layers ``Dense_0``, ``Dense_1``, ...).
        params: its parameters.
        u: (N, 3) normalised inputs.
    """
    h = u
    for i in range(len(mlp.widths)):
        layer = params[f"Dense_{i}"]
        h = jax.nn.leaky_relu(h @ layer["kernel"] + layer["bias"], negative_slope=mlp.slope)
    return h


# Ridge strengths of the warm start, relative to the mean diagonal of the feature Gram matrix.
RIDGE_GRID = tuple(10.0 ** (k / 2) for k in range(-18, 2))


def ridge_output_layer(
    mlp: MLP,
    params: Params,
    train: tuple[Float[Array, "L 3"], Float[Array, "L 3"], Float[Array, " L"]],
    val: tuple[Float[Array, "V 3"], Float[Array, "V 3"]],
    rel_lambdas: tuple[float, ...] = RIDGE_GRID,
    max_rows: int = 2048,
) -> tuple[Params, Float[Array, ""]]:
    """Warm start: the output layer set to the ridge least-squares fit on the initial hidden features.

    With the hidden layers at their random initialisation, the output layer (kernel and bias) is
    the weighted ridge regression of the labels on the last hidden layer's activations, with the
    ridge strength picked from ``rel_lambdas`` (times the mean squared feature norm) by the
    validation MSE. It is solved in the dual, ``theta = H^T (H H^T + lam I)^-1 x``, from one
    ``L x L`` eigendecomposition, so every strength costs only matrix products. Above
    ``max_rows`` training rows an evenly strided subset of them is used (it is a starting point;
    Adam then trains on every row).

    Args:
        mlp: the network definition (static).
        params: initial parameters (the hidden layers are kept).
        train: ``(u, x, w)``: normalised inputs, labels, 0/1 (or non-negative) row weights.
        val: ``(u, x)`` of the validation set that picks the strength.
        rel_lambdas: candidate ridge strengths, relative (static).
        max_rows: most training rows in the solve (static).

    Returns:
        The parameters with the new output layer, and the chosen relative strength.
    """
    u, x, w = train
    u_va, x_va = val
    stride = -(-u.shape[0] // max_rows)
    u, x, w = u[::stride], x[::stride], w[::stride]

    def design(v):
        h = hidden_features(mlp, params, v)
        return jnp.concatenate([h, jnp.ones((h.shape[0], 1), h.dtype)], axis=1)

    sw = jnp.sqrt(w)[:, None]
    h_tr, h_va = sw * design(u), design(u_va)  # rows of weight 0 drop out of every product below
    xw = sw * x
    scale = jnp.maximum(jnp.sum(h_tr * h_tr) / jnp.maximum(jnp.sum(w), 1.0), 1e-30)
    lams = scale * jnp.asarray(rel_lambdas, h_tr.dtype)
    ev, q = jnp.linalg.eigh(h_tr @ h_tr.T)
    qx = q.T @ xw
    k_va = h_va @ h_tr.T

    def dual(lam):
        return q @ (qx / (ev + lam)[:, None])

    val_mse = jax.vmap(lambda lam: jnp.mean((k_va @ dual(lam) - x_va) ** 2))(lams)
    best = jnp.argmin(jnp.where(jnp.isfinite(val_mse), val_mse, jnp.inf))
    th = h_tr.T @ dual(lams[best])
    out = dict(params)
    out[f"Dense_{len(mlp.widths)}"] = {"kernel": th[:-1], "bias": th[-1]}
    return out, jnp.asarray(rel_lambdas)[best]


def row_chunked_value_and_grad(mlp: MLP, chunk: int) -> ValueAndGradFn:
    """``(params, (u, x, w)) -> (weighted_mse, grads)`` computed over blocks of ``chunk`` rows.

    The same numbers as ``jax.value_and_grad`` of :func:`weighted_mse` (up to float summation
    order), but each block's hidden activations (``chunk x width`` floats) stay in cache instead of
    streaming ``L x width`` arrays through memory several times per epoch: with the thesis's 7500
    units and 1000 rows, 2-3x less time per epoch on a 2-core CPU (``benchmarks/run.py``). Rows are
    padded with weight 0 to a multiple of ``chunk``.

    Args:
        mlp: the network definition (static).
        chunk: rows per block (static).
    """

    def sse(params, u, x, w):
        return jnp.sum(w[:, None] * (mlp.apply({"params": params}, u) - x) ** 2)

    block_vg = jax.value_and_grad(sse)

    def value_and_grad(params, data):
        u, x, w = data
        n = u.shape[0]
        pad = (-n) % chunk
        blocks = (
            jnp.pad(u, ((0, pad), (0, 0))).reshape(-1, chunk, u.shape[1]),
            jnp.pad(x, ((0, pad), (0, 0))).reshape(-1, chunk, x.shape[1]),
            jnp.pad(w, (0, pad)).reshape(-1, chunk),
        )

        def body(acc, b):
            v, g = block_vg(params, *b)
            return jax.tree.map(jnp.add, acc, (v, g)), None

        zero = (jnp.zeros((), u.dtype), jax.tree.map(jnp.zeros_like, params))
        (total, grads), _ = jax.lax.scan(body, zero, blocks)
        norm = 3.0 * jnp.maximum(jnp.sum(w), 1e-12)
        return total / norm, jax.tree.map(lambda g: g / norm, grads)

    return value_and_grad


def fit_nn(
    key: jax.Array,
    mlp: MLP,
    bounds: Bounds,
    train: tuple[Array, Array, Array],
    val: tuple[Array, Array],
    config: TrainConfig,
    max_epochs: int,
    warm_start: bool = False,
    row_chunk: int | None = None,
    progress: Callable[[Any, Any, Any, Any], None] | None = None,
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
        warm_start: start Adam from :func:`ridge_output_layer` (output layer fitted by ridge least
            squares on the random hidden features) instead of the plain random initialisation
            (static).
        row_chunk: compute each epoch's gradient over blocks of this many rows
            (:func:`row_chunked_value_and_grad`; static); ``None``: all rows at once.
        progress: optional host callback ``(epoch, train_loss, val_loss, best_val)`` every 100
            epochs (:func:`jaxcal.train.fit_full_batch`; static, a side effect only).

    Returns:
        The calibration (best-validation parameters) and the training record.
    """
    y_tr, x_tr, w_tr = train
    y_va, x_va = val
    u_tr, u_va = normalise(y_tr, bounds), normalise(y_va, bounds)

    def loss_fn(params, data):
        u, x, w = data
        return weighted_mse(mlp.apply({"params": params}, u), x, w)

    params0 = jax.tree.map(lambda a: a.astype(u_tr.dtype), init_mlp(key, mlp))  # float64 data: float64 weights
    if warm_start:
        params0, _ = ridge_output_layer(mlp, params0, (u_tr, x_tr, w_tr), (u_va, x_va))
    vg = None if row_chunk is None or row_chunk >= u_tr.shape[0] else row_chunked_value_and_grad(mlp, row_chunk)
    result = fit_full_batch(
        loss_fn, params0, (u_tr, x_tr, w_tr), (u_va, x_va, jnp.ones(u_va.shape[0])), config, max_epochs, vg,
        progress=progress,
    )
    return NNCalibration(result.params, bounds), result


__all__ = [
    "MLP",
    "NNCalibration",
    "RIDGE_GRID",
    "THESIS_LEAKY_SLOPE",
    "THESIS_OFFLINE_WIDTHS",
    "THESIS_ONLINE_WIDTHS",
    "fit_nn",
    "hidden_features",
    "init_mlp",
    "mse",
    "nn_calibrate",
    "nn_calibrate_jit",
    "ridge_output_layer",
    "row_chunked_value_and_grad",
    "weighted_mse",
]
