"""Full-batch Adam training with early stopping, entirely inside one ``jax.lax.while_loop``.

The loop is a pure function of ``(params0, data, config)``: it jit-compiles once and ``vmap``s
over seeds, datasets or (traced) hyperparameters, the purejaxrl way. Early stopping follows the
thesis ("until the loss stops improving"): training stops when the validation loss has not
improved by more than ``min_delta`` for ``patience`` epochs, and the best-validation parameters
are returned.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jaxtyping import Float, Int

from jaxcal.arrays import Array

__all__ = [
    "PyTree",
    "LossFn",
    "ValueAndGradFn",
    "TrainConfig",
    "TrainResult",
    "fit_full_batch",
]

PyTree = Any
LossFn = Callable[[PyTree, Any], Float[Array, ""]]
ValueAndGradFn = Callable[[PyTree, Any], tuple[Float[Array, ""], PyTree]]


class TrainConfig(NamedTuple):
    """Hyperparameters of :func:`fit_full_batch`; every field may be a traced array.

    Attributes:
        learning_rate: Adam step size.
        patience: epochs without validation improvement before stopping.
        min_delta: improvement (absolute, in loss units) that counts as one.
        min_rel_delta: improvement relative to the best validation loss that counts as one
            (``1e-3``: the loss must fall by 0.1 %); combined with ``min_delta``, a new loss counts
            when ``val < best * (1 - min_rel_delta) - min_delta``.
    """

    learning_rate: float | Float[Array, ""] = 1e-3
    patience: int | Int[Array, ""] = 200
    min_delta: float | Float[Array, ""] = 0.0
    min_rel_delta: float | Float[Array, ""] = 0.0


class TrainResult(NamedTuple):
    """Outcome of :func:`fit_full_batch`.

    ``train_loss``/``val_loss`` have length ``max_epochs``; entries after ``epochs`` are NaN.
    """

    params: PyTree
    best_val: Float[Array, ""]
    best_epoch: Int[Array, ""]
    epochs: Int[Array, ""]
    train_loss: Float[Array, " E"]
    val_loss: Float[Array, " E"]


def fit_full_batch(
    loss_fn: LossFn,
    params0: PyTree,
    train_data: Any,
    val_data: Any,
    config: TrainConfig,
    max_epochs: int,
    value_and_grad: ValueAndGradFn | None = None,
    progress: Callable[[Any, Any, Any, Any], None] | None = None,
    progress_every: int = 100,
) -> TrainResult:
    """Train ``params`` with full-batch Adam until the validation loss stops improving.

    Args:
        loss_fn: ``loss_fn(params, data) -> scalar``, pure.
        params0: initial parameters (any pytree).
        train_data: passed to ``loss_fn`` for the gradient step.
        val_data: passed to ``loss_fn`` for early stopping.
        config: :class:`TrainConfig` (fields may be traced, so trainings vmap over them).
        max_epochs: hard cap on epochs (static: it sizes the loss histories).
        value_and_grad: ``(params, train_data) -> (loss, grads)`` of ``loss_fn`` computed another
            way (e.g. :func:`jaxcal.nn.row_chunked_value_and_grad`, which streams the rows in
            cache-sized blocks); ``None``: ``jax.value_and_grad(loss_fn)``.
        progress: optional host callback ``progress(epoch, train_loss, val_loss, best_val)``,
            called through ``jax.debug.callback`` every ``progress_every`` epochs (static; a side
            effect only: the numbers the loop produces do not change). ``None``: no callback.
        progress_every: epochs between two callbacks (static).

    Returns:
        :class:`TrainResult` with the best-validation parameters.
    """
    opt = optax.adam(config.learning_rate)
    if value_and_grad is None:
        value_and_grad = jax.value_and_grad(loss_fn)
    nan_hist = jnp.full((max_epochs,), jnp.nan, dtype=jnp.float32)

    def cond(carry):
        epoch, since_best = carry[0], carry[6]
        return (epoch < max_epochs) & (since_best < config.patience)

    def body(carry):
        epoch, params, opt_state, best_params, best_val, best_epoch, since_best, th, vh = carry
        loss, grads = value_and_grad(params, train_data)
        updates, opt_state = opt.update(grads, opt_state, params)
        params = optax.apply_updates(params, updates)
        val = loss_fn(params, val_data)
        improved = val < best_val * (1.0 - config.min_rel_delta) - config.min_delta
        best_params = jax.tree.map(lambda n, o: jnp.where(improved, n, o), params, best_params)
        best_val = jnp.where(improved, val, best_val)
        best_epoch = jnp.where(improved, epoch, best_epoch)
        since_best = jnp.where(improved, 0, since_best + 1)
        th = th.at[epoch].set(loss.astype(th.dtype))
        vh = vh.at[epoch].set(val.astype(vh.dtype))
        if progress is not None:
            jax.lax.cond((epoch + 1) % progress_every == 0,
                         lambda: jax.debug.callback(progress, epoch + 1, loss, val, best_val), lambda: None)
        return epoch + 1, params, opt_state, best_params, best_val, best_epoch, since_best, th, vh

    val0 = loss_fn(params0, val_data)
    init = (
        jnp.asarray(0),
        params0,
        opt.init(params0),
        params0,
        val0,
        jnp.asarray(-1),
        jnp.asarray(0),
        nan_hist,
        nan_hist,
    )
    epoch, _, _, best_params, best_val, best_epoch, _, th, vh = jax.lax.while_loop(cond, body, init)
    return TrainResult(best_params, best_val, best_epoch, epoch, th, vh)
