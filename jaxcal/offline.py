"""Offline accelerometer calibration sweep (thesis chapter 3): linear vs NN over subset sizes.

Everything here is a pure function of arrays and static configs, so that a whole Table 3.1 sweep
(subset sizes ``l`` x seeds) is one ``jit`` of nested ``vmap`` s: subsets are 0/1 weight rows over
the padded 1000-sample training set (:func:`jaxcal.simulate.dataset1.nested_subset_weights`), and
seeds vary the NN initialisation and the subset permutation.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax
from jaxtyping import Float, Int

from jaxcal.arrays import Array
from jaxcal.linear import fit_affine
from jaxcal.nn import MLP, fit_nn, nn_calibrate
from jaxcal.normalise import Bounds
from jaxcal.sensor import affine_inverse
from jaxcal.train import TrainConfig

THESIS_SIZES = (18, 50, 100, 200, 400, 600, 800, 1000)


class NNTrainSpec(NamedTuple):
    """How the offline NN is trained (full-batch Adam, MSE, early stopping on validation loss).

    The step size decays exponentially from ``lr_init`` to ``lr_final`` over ``max_epochs``
    (equal values: constant). Training stops when the validation loss has not fallen by a share
    ``min_rel_delta`` for ``patience`` epochs and returns the best-validation weights. With
    ``warm_start`` Adam starts from the output layer fitted by ridge least squares on the random
    hidden features (:func:`jaxcal.nn.ridge_output_layer`); ``row_chunk`` computes each epoch's
    gradient over cache-sized blocks of rows (:func:`jaxcal.nn.row_chunked_value_and_grad`).

    Defaults: the recipe of ``experiments/offline.py`` (warm start, then Adam 3e-5 until the
    validation loss stops falling by 0.1 % within 200 epochs). :data:`ADAM_FROM_RANDOM` is the
    previous recipe (Adam 2e-2 from the random initialisation, ~18000 epochs). How both were
    chosen: ``results/sweep_offline_nn/sweep.md``.

    Static: callers close over the spec (:func:`nn_calibrate_subsets` under ``jit``/``vmap``), so a
    new value compiles anew; to vmap over learning rates, pass a traced
    :class:`~jaxcal.train.TrainConfig` to :func:`jaxcal.nn.fit_nn` instead.

    Attributes:
        lr_init: Adam step size at the first epoch.
        lr_final: step size at ``max_epochs`` (exponential decay in between).
        patience: epochs without a validation improvement before stopping.
        max_epochs: hard cap on epochs (it also sizes the loss histories).
        min_rel_delta: relative fall of the validation loss that counts as an improvement.
        warm_start: start from the ridge least-squares output layer.
        row_chunk: rows per gradient block (``None``: all rows at once).
    """

    lr_init: float = 3e-5
    lr_final: float = 3e-5
    patience: int = 200
    max_epochs: int = 5000
    min_rel_delta: float = 1e-3
    warm_start: bool = True
    row_chunk: int | None = 200

    def train_config(self) -> TrainConfig:
        """The :class:`~jaxcal.train.TrainConfig` with the decaying step size as an optax schedule."""
        sched = optax.exponential_decay(
            init_value=self.lr_init,
            transition_steps=self.max_epochs,
            decay_rate=self.lr_final / self.lr_init,
        )
        return TrainConfig(learning_rate=sched, patience=self.patience, min_delta=0.0,
                           min_rel_delta=self.min_rel_delta)


# The previous recipe: Adam 2e-2 from the random initialisation until 6000 epochs without a
# validation improvement (about 18000 epochs at l = 1000: 367 s on a 2-core CPU).
ADAM_FROM_RANDOM = NNTrainSpec(lr_init=2e-2, lr_final=2e-2, patience=6000, max_epochs=30000, min_rel_delta=0.0,
                               warm_start=False, row_chunk=None)


def linear_calibrate_subsets(
    y_tr: Float[Array, "L 3"],
    x_tr: Float[Array, "L 3"],
    weights: Float[Array, "K L"],
    y_te: Float[Array, "T 3"],
) -> Float[Array, "K T 3"]:
    """Calibrated test outputs (eq. 3.5, g) of the 12-parameter linear model fitted on each subset.

    Args:
        y_tr, x_tr: padded training counts (LSB) and labels (g).
        weights: ``(K, L)`` 0/1 subset rows.
        y_te: test counts (LSB).
    """

    def one(w):
        return affine_inverse(fit_affine(x_tr, y_tr, w), y_te)

    return jax.vmap(one)(weights)


def _fit_and_calibrate(key, mlp, bounds, train, val, y_te, spec: NNTrainSpec):
    """:func:`jaxcal.nn.fit_nn` with the spec's recipe on ``(y, x, w)``; the calibrated ``y_te``, the
    epochs run and the best epoch."""
    cal, res = fit_nn(key, mlp, bounds, train, val, spec.train_config(), spec.max_epochs, spec.warm_start,
                      spec.row_chunk)
    return nn_calibrate(mlp, cal, y_te), res.epochs, res.best_epoch


def nn_calibrate_subsets(
    key: jax.Array,
    mlp: MLP,
    bounds: Bounds,
    train: tuple[Float[Array, "L 3"], Float[Array, "L 3"]],
    weights: Float[Array, "K L"],
    val: tuple[Float[Array, "V 3"], Float[Array, "V 3"]],
    y_te: Float[Array, "T 3"],
    spec: NNTrainSpec,
) -> tuple[Float[Array, "K T 3"], Int[Array, " K"], Int[Array, " K"]]:
    """Fit the NN on every subset row of ``weights`` (one init key) and calibrate ``y_te``.

    Args:
        key: initialisation key (shared by all subsets: the sizes differ only in data).
        mlp: network definition (thesis: ``MLP((7500,), 3, 0.1)``).
        bounds: eq. 3.6 bounds of the input normalisation.
        train: ``(y_counts, x_labels)`` of the padded training set.
        weights: ``(K, L)`` 0/1 subset rows.
        val: ``(y_counts, x_labels)`` for early stopping.
        y_te: test counts (LSB).
        spec: training hyperparameters.

    Returns:
        Calibrated test outputs ``(K, T, 3)`` in g, and the epochs run and best epoch per subset.
    """
    y_tr, x_tr = train

    def one(w):
        return _fit_and_calibrate(key, mlp, bounds, (y_tr, x_tr, w), val, y_te, spec)

    return jax.vmap(one)(weights)


def nn_calibrate_rows(
    key: jax.Array,
    mlp: MLP,
    bounds: Bounds,
    train: tuple[Float[Array, "L 3"], Float[Array, "L 3"]],
    val: tuple[Float[Array, "V 3"], Float[Array, "V 3"]],
    y_te: Float[Array, "T 3"],
    spec: NNTrainSpec,
) -> tuple[Float[Array, "T 3"], Int[Array, ""], Int[Array, ""]]:
    """Fit the NN on exactly the rows of ``train`` and calibrate ``y_te``.

    Unlike :func:`nn_calibrate_subsets` (0/1 weight rows over a padded set, so that sizes vmap
    together), every epoch costs in proportion to the rows given: the l = 18 fit costs 18 rows.

    Args:
        key: initialisation key.
        mlp: network definition.
        bounds: eq. 3.6 bounds of the input normalisation.
        train: ``(y_counts, x_labels)``.
        val: ``(y_counts, x_labels)`` for early stopping.
        y_te: test counts (LSB).
        spec: training hyperparameters.

    Returns:
        Calibrated test outputs (g), epochs run and best epoch.
    """
    y_tr, x_tr = train
    return _fit_and_calibrate(key, mlp, bounds, (y_tr, x_tr, jnp.ones(y_tr.shape[0], y_tr.dtype)), val, y_te, spec)


#: :func:`nn_calibrate_rows` compiled, ``mlp`` and ``spec`` static.
nn_calibrate_rows_jit = jax.jit(nn_calibrate_rows, static_argnames=("mlp", "spec"))


def residual_nn_calibrate_rows(
    key: jax.Array,
    mlp: MLP,
    bounds: Bounds,
    train: tuple[Float[Array, "L 3"], Float[Array, "L 3"]],
    val: tuple[Float[Array, "V 3"], Float[Array, "V 3"]],
    y_te: Float[Array, "T 3"],
    spec: NNTrainSpec,
) -> tuple[Float[Array, "T 3"], Int[Array, ""], Int[Array, ""]]:
    """Affine backbone plus an NN residual: the 12-parameter model, then an NN fitted to what it misses.

    ``x = A (y - b) + f_NN(y)``: the linear model (eq. 3.1, :func:`jaxcal.linear.fit_affine`) is
    fitted first; the network is trained (as :func:`nn_calibrate_rows`) on the labels minus the
    linear model's output, on the training and the validation rows. With few rows the warm start's
    ridge and early stopping keep the residual near zero, so the model falls back to the linear one.

    Args:
        key: initialisation key of the residual network.
        mlp: residual network definition (small, e.g. ``MLP((256,))``).
        bounds: eq. 3.6 bounds of the input normalisation.
        train: ``(y_counts, x_labels)``.
        val: ``(y_counts, x_labels)`` for early stopping.
        y_te: test counts (LSB).
        spec: training hyperparameters of the residual network.

    Returns:
        Calibrated test outputs (g), epochs run and best epoch of the residual network.
    """
    y_tr, x_tr = train
    y_va, x_va = val
    lin = fit_affine(x_tr, y_tr, jnp.ones(y_tr.shape[0], y_tr.dtype))
    r_tr = x_tr - affine_inverse(lin, y_tr)
    r_va = x_va - affine_inverse(lin, y_va)
    res_te, epochs, best = nn_calibrate_rows(key, mlp, bounds, (y_tr, r_tr), (y_va, r_va), y_te, spec)
    return affine_inverse(lin, y_te) + res_te, epochs, best


__all__ = [
    "ADAM_FROM_RANDOM",
    "NNTrainSpec",
    "THESIS_SIZES",
    "linear_calibrate_subsets",
    "nn_calibrate_rows",
    "nn_calibrate_rows_jit",
    "nn_calibrate_subsets",
    "residual_nn_calibrate_rows",
]
