"""Sweep target ``"offline-nn"``: the thesis's chapter-3 NN (one hidden layer,
:func:`jaxcal.nn.fit_nn`) and, as the reference, the 12-parameter linear model
(:func:`jaxcal.linear.fit_affine`), each trained on exactly ``l`` rows of the fixed Dataset 1
surrogate ``dataset1(PRNGKey(0))`` (1000 train / 184 val / 184 test; no dataset settings).

Seed ``s`` draws the NN's initial weights and which ``l`` training rows are used from
:func:`offline_seed_keys` ``(s)``, the keys of ``experiments/offline.py`` for ``s < 5``.
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal.constants import ACC_RANGE_G
from jaxcal.linear import fit_affine, fit_affine_jit
from jaxcal.metrics import euclidean_error
from jaxcal.nn import MLP, THESIS_LEAKY_SLOPE, THESIS_OFFLINE_WIDTHS, fit_nn, nn_calibrate
from jaxcal.normalise import bounds_from_spec
from jaxcal.offline import NNTrainSpec, nn_calibrate_rows_jit
from jaxcal.sensor import affine_inverse
from jaxcal.simulate.dataset1 import Dataset1Config, dataset1, nested_subset_weights
from jaxcal.sweep.base import Prepared, SweepSpec, Target, full_config, scalar
from jaxcal.train import TrainConfig

__all__ = ["OFFLINE_DATASET_KEY", "TARGET", "offline_data", "offline_rows", "offline_seed_keys"]

#: Dataset 1 surrogate of the offline-nn target: ``dataset1(PRNGKey(OFFLINE_DATASET_KEY))``, as
#: ``experiments/offline.py``.
OFFLINE_DATASET_KEY = 0
_SEED_KEY = 1  # experiments/offline.py's SEED_KEY
_SPLIT_SEEDS = 5  # experiments/offline.py's full run: split(PRNGKey(1), 5)
_STATIC = ("l", "width", "warm_start", "row_chunk", "max_epochs", "slope")
_TRAIN = NNTrainSpec()  # the chapter-3 recipe: the target's defaults


def offline_seed_keys(seed: int) -> tuple[jax.Array, jax.Array]:
    """``(init_key, perm_key)`` of offline-nn seed ``seed``: the NN's initial weights, the row subset.

    ``base = split(PRNGKey(1), 5)[seed]`` for ``seed < 5`` (the seeds of ``experiments/offline.py``,
    whose full run splits five; its quick run's two are the same keys, threefry being partitionable)
    and ``base = fold_in(PRNGKey(1), seed)`` otherwise; then ``init_key, perm_key = split(base)``.
    The ``l`` training rows are the first ``l`` of ``permutation(perm_key, 1000)`` (as
    :func:`jaxcal.simulate.dataset1.nested_subset_weights`), kept in their dataset order.

    Args:
        seed: the configuration's seed.
    """
    root = jax.random.PRNGKey(_SEED_KEY)
    base = jax.random.split(root, _SPLIT_SEEDS)[seed] if seed < _SPLIT_SEEDS else jax.random.fold_in(root, seed)
    init_key, perm_key = jax.random.split(base)
    return init_key, perm_key


class _Static(NamedTuple):
    """The offline-nn group settings (static: hashable, a change recompiles)."""

    l: int
    width: int
    warm_start: bool
    row_chunk: int  # 0: all rows at once
    max_epochs: int
    slope: float

    @property
    def mlp(self) -> MLP:
        return MLP(widths=(self.width,), out_dim=3, slope=self.slope)


def _static(full: dict[str, Any]) -> _Static:
    return _Static(int(full["l"]), int(full["width"]), bool(full["warm_start"]), int(full["row_chunk"]),
                   int(full["max_epochs"]), float(full["slope"]))


def offline_data():
    """``(data, bounds)``: the fixed Dataset 1 surrogate and its normalisation bounds."""
    data = dataset1(jax.random.PRNGKey(OFFLINE_DATASET_KEY), Dataset1Config())
    return data, bounds_from_spec(data.spec, ACC_RANGE_G)


def offline_rows(data, seed: int, l: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(init_key, counts (l, 3), labels (l, 3))`` of a seed: its first ``l`` permuted training rows."""
    init_key, perm_key = offline_seed_keys(seed)
    n = data.train.acc.shape[0]
    sel = np.flatnonzero(np.asarray(nested_subset_weights(perm_key, n, (l,)))[0] > 0)
    return init_key, data.train.acc[sel], data.train.acc_ref[sel]


def _metrics(out_va, out_te, lin, data, epochs, best_epoch, max_epochs: int) -> dict[str, jax.Array]:
    """The offline-nn row metrics (mg; inside jit/vmap or not).

    ``test_mg`` / ``val_mg``: mean Euclidean error (eq. 3.8) of the NN (best-validation weights)
    on the 184 test / validation orientations against their labels; ``linear_mg``: the same test
    error of the 12-parameter linear model fitted on the same ``l`` rows; ``epochs``: Adam epochs
    run; ``best_epoch``: the 0-based index of the epoch whose weights are returned (they follow
    ``best_epoch + 1`` Adam steps), -1 if none beat the initial ones; ``hit_cap``: training ran
    to ``max_epochs`` (patience did not stop it).
    """
    return {
        "test_mg": 1e3 * euclidean_error(data.test.acc_ref, out_te).mean(),
        "linear_mg": 1e3 * euclidean_error(data.test.acc_ref, affine_inverse(lin, data.test.acc)).mean(),
        "val_mg": 1e3 * euclidean_error(data.val.acc_ref, out_va).mean(),
        "epochs": epochs,
        "best_epoch": best_epoch,
        "hit_cap": epochs >= max_epochs,
    }


class _Shared(NamedTuple):
    """The replicated data of an offline-nn batch (seeds stacked on the first axis)."""

    init_keys: jax.Array
    y: jax.Array
    x: jax.Array
    data: Any
    bounds: Any


@partial(jax.jit, static_argnames=("st",))
def _group_fn(shared: _Shared, per_config, *, st: _Static):
    """vmap of NN and linear fits + metrics over the configuration axis (rows indexed by seed)."""
    mlp = st.mlp

    def one(i, cfg):
        y, x = shared.y[i], shared.x[i]
        w = jnp.ones(y.shape[0], y.dtype)
        val = (shared.data.val.acc, shared.data.val.acc_ref)
        cal, res = fit_nn(shared.init_keys[i], mlp, shared.bounds, (y, x, w), val, cfg, st.max_epochs, st.warm_start,
                          st.row_chunk or None)
        out_va, out_te = nn_calibrate(mlp, cal, shared.data.val.acc), nn_calibrate(mlp, cal, shared.data.test.acc)
        lin = fit_affine(x, y, w)
        return _metrics(out_va, out_te, lin, shared.data, res.epochs, res.best_epoch, st.max_epochs)

    return jax.vmap(one)(*per_config)


def _call(shared, per_config, *, st: _Static) -> dict[str, jax.Array]:
    # Full float32 matmuls, as experiments/offline.py: GPUs may default to TF32 (~1e-3 relative).
    with jax.default_matmul_precision("highest"):
        return _group_fn(shared, per_config, st=st)


def prepare(spec: SweepSpec, key: tuple, configs: list[dict[str, Any]]) -> Prepared:
    """One batch: the seeds' rows stacked (shared), the configurations' training settings stacked."""
    st = _static(full_config(spec, TARGET, configs[0]))
    data, bounds = offline_data()
    seeds = sorted({c["seed"] for c in configs})
    keys, ys, xs = zip(*(offline_rows(data, s, st.l) for s in seeds), strict=True)
    shared = _Shared(jnp.stack(keys), jnp.stack(ys), jnp.stack(xs), data, bounds)
    fulls = [full_config(spec, TARGET, c) for c in configs]
    cfg = TrainConfig(
        learning_rate=jnp.asarray([float(f["lr"]) for f in fulls], jnp.float32),
        patience=jnp.asarray([int(f["patience"]) for f in fulls], jnp.int32),
        min_delta=jnp.zeros(len(fulls), jnp.float32),
        min_rel_delta=jnp.asarray([float(f["min_rel_delta"]) for f in fulls], jnp.float32),
    )
    seed_idx = jnp.asarray([seeds.index(c["seed"]) for c in configs], dtype=jnp.int32)
    return Prepared(partial(_call, st=st), shared, (seed_idx, cfg))


def run_one(spec: SweepSpec, config: dict[str, Any]) -> dict[str, Any]:
    """One configuration through ``experiments/offline.py``'s own path (:func:`jaxcal.offline.nn_calibrate_rows`).

    The learning rate there is a (constant) optax schedule and every setting is static: a second
    route to the numbers the vmapped :func:`_group_fn` gives.
    """
    full = full_config(spec, TARGET, config)
    st = _static(full)
    data, bounds = offline_data()
    init_key, y, x = offline_rows(data, config["seed"], st.l)
    lr = float(full["lr"])
    train = NNTrainSpec(lr_init=lr, lr_final=lr, patience=int(full["patience"]), max_epochs=st.max_epochs,
                        min_rel_delta=float(full["min_rel_delta"]), warm_start=st.warm_start,
                        row_chunk=st.row_chunk or None)
    y_eval = jnp.concatenate([data.val.acc, data.test.acc])
    val = (data.val.acc, data.val.acc_ref)
    with jax.default_matmul_precision("highest"):
        out, epochs, best = nn_calibrate_rows_jit(init_key, st.mlp, bounds, (y, x), val, y_eval, train)
        lin = fit_affine_jit(x, y, jnp.ones(y.shape[0], y.dtype))
    n_va = data.val.acc.shape[0]
    m = _metrics(out[:n_va], out[n_va:], lin, data, epochs, best, st.max_epochs)
    return {k: scalar(np.asarray(v)) for k, v in m.items()}


def describe(spec: SweepSpec) -> str:
    """The report's words on the data and the settings not swept."""
    swept = {*spec.grid, *spec.random}
    rest = {k: v for k, v in full_config(spec, TARGET, {}).items() if k not in swept}
    return (f"the fixed Dataset 1 surrogate, dataset1(PRNGKey({OFFLINE_DATASET_KEY})), 1000 train / 184 val / 184 test; "
            f"NN 3-width-3 trained by Adam on l rows drawn per seed, early stopping on the validation loss; linear: the "
            f"12-parameter model on the same rows; settings not swept: {', '.join(f'{k} = {v}' for k, v in rest.items())}")


TARGET = Target(
    name="offline-nn",
    traced=("lr", "patience", "min_rel_delta"),
    static=_STATIC,
    ints=("patience", "l", "width", "row_chunk", "max_epochs"),
    bools=("warm_start",),
    ranges={"lr": (0.0, math.inf, True), "patience": (1, math.inf, False), "min_rel_delta": (0.0, 1.0, False),
            "l": (4, Dataset1Config().n_train, False), "width": (1, math.inf, False),
            "row_chunk": (0, math.inf, False), "max_epochs": (1, math.inf, False), "slope": (0.0, 1.0, False)},
    defaults={"lr": _TRAIN.lr_init, "patience": _TRAIN.patience,
              "min_rel_delta": _TRAIN.min_rel_delta, "l": Dataset1Config().n_train,
              "width": THESIS_OFFLINE_WIDTHS[0], "warm_start": _TRAIN.warm_start,
              "row_chunk": _TRAIN.row_chunk or 0, "max_epochs": _TRAIN.max_epochs,
              "slope": THESIS_LEAKY_SLOPE},
    dataset=None,
    metrics=(("test_mg", "NN test [mg]"), ("linear_mg", "linear test [mg]"), ("val_mg", "NN val [mg]"),
             ("epochs", "epochs"), ("best_epoch", "best epoch"), ("hit_cap", "share at max_epochs")),
    heatmap_metrics=("test_mg", "epochs"),
    best=(("test_mg", "NN test error", "mg"),),
    best_context=(("linear_mg", "linear model on the same rows", "mg"), ("epochs", "epochs", "")),
    describe=describe,
    prepare=prepare,
    run_one=run_one,
)
