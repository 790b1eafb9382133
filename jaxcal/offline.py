"""Offline accelerometer calibration sweep (thesis chapter 3): linear vs NN over subset sizes.

Everything here is a pure function of arrays and static configs, so that a whole Table 3.1 sweep
(subset sizes ``l`` x seeds) is one ``jit`` of nested ``vmap`` s: subsets are 0/1 weight rows over
the padded 1000-sample training set (:func:`jaxcal.simulate.dataset1.nested_subset_weights`), and
seeds vary the NN initialisation and the subset permutation.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
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
    (equal values: constant). Training stops after ``patience`` epochs without a validation
    improvement and returns the best-validation weights. Defaults: the full-form setting of
    ``experiments/offline.py`` (constant 2e-2; why, and how it was chosen: ``results/offline.md``).

    Static: callers close over the spec (:func:`nn_calibrate_subsets` under ``jit``/``vmap``), so a
    new value compiles anew; to vmap over learning rates, pass a traced
    :class:`~jaxcal.train.TrainConfig` to :func:`jaxcal.nn.fit_nn` instead.

    Attributes:
        lr_init: Adam step size at the first epoch.
        lr_final: step size at ``max_epochs`` (exponential decay in between).
        patience: epochs without a validation improvement before stopping.
        max_epochs: hard cap on epochs (it also sizes the loss histories).
    """

    lr_init: float = 2e-2
    lr_final: float = 2e-2
    patience: int = 6000
    max_epochs: int = 30000

    def train_config(self) -> TrainConfig:
        """The :class:`~jaxcal.train.TrainConfig` with the decaying step size as an optax schedule."""
        sched = optax.exponential_decay(
            init_value=self.lr_init,
            transition_steps=self.max_epochs,
            decay_rate=self.lr_final / self.lr_init,
        )
        return TrainConfig(learning_rate=sched, patience=self.patience, min_delta=0.0)


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
    cfg = spec.train_config()

    def one(w):
        cal, res = fit_nn(key, mlp, bounds, (y_tr, x_tr, w), val, cfg, spec.max_epochs)
        return nn_calibrate(mlp, cal, y_te), res.epochs, res.best_epoch

    return jax.vmap(one)(weights)


__all__ = ["NNTrainSpec", "THESIS_SIZES", "linear_calibrate_subsets", "nn_calibrate_subsets"]
