"""Sweep target ``"online-thesis"``: the thesis's online algorithm (chapter 4,
:mod:`jaxcal.online_thesis`) on simulated Dataset 2.

Seed ``s`` draws its dataset from ``PRNGKey(s)`` and its initial weights from :func:`weights_key`
``(s)``. ``init_every`` and the ``dataset.<field>`` settings are static (shapes); every other
hyperparameter of :class:`~jaxcal.online_thesis.OnlineThesisHParams` is traced (vmapped).
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp

from jaxcal import online_thesis as ot
from jaxcal.simulate.dataset2 import Dataset2Config, dataset2
from jaxcal.sweep.base import Prepared, SweepSpec, Target, dataset_config, dataset_settings, full_config, static_key

__all__ = ["TARGET", "weights_key"]

_TRACED = tuple(f for f in ot.OnlineThesisHParams._fields if f != "key")
_INTS = ("init_epochs", "gyr_steps", "acc_steps", "init_every")


def weights_key(seed: int) -> jax.Array:
    """The PRNG key of the initial weights of online-thesis seed ``seed`` (its dataset uses ``PRNGKey(seed)``).

    Args:
        seed: the configuration's seed.
    """
    return jax.random.fold_in(jax.random.PRNGKey(seed), 1)


def _metrics(data, r: ot.OnlineThesisResult) -> dict[str, jax.Array]:
    """The online-thesis row metrics of one run (inside jit/vmap), mg and mrad/s.

    ``test_acc_mg`` / ``test_gyr_mrads``: test errors (mean Euclidean error, eq. 3.8) after the
    whole algorithm; ``init_test_*``: the same after the initial training; ``val_e_*_final``: the
    validation errors of eq. 4.14 after the last sequence, ``val_e_*_last50``: averaged over the
    last 50 sequences; ``init_loss_*``: the initial-training losses.
    """
    ea, eg = ot.test_set_errors((r.acc_params, r.gyr_params), data)
    ea0, eg0 = ot.test_set_errors((r.acc_params0, r.gyr_params0), data)
    last = min(50, r.e_g.shape[0] - 1)
    return {
        "test_acc_mg": 1e3 * ea.mean(),
        "test_gyr_mrads": 1e3 * eg.mean(),
        "init_test_acc_mg": 1e3 * ea0.mean(),
        "init_test_gyr_mrads": 1e3 * eg0.mean(),
        "val_e_a_final_mg": 1e3 * r.e_a[-1],
        "val_e_g_final_mrads": 1e3 * r.e_g[-1],
        "val_e_a_last50_mg": 1e3 * r.e_a[-last:].mean(),
        "val_e_g_last50_mrads": 1e3 * r.e_g[-last:].mean(),
        "init_loss_acc": r.init_loss_acc,
        "init_loss_gyr": r.init_loss_gyr,
    }


def _hparams(full: dict[str, Any], seed: int) -> ot.OnlineThesisHParams:
    return ot.default_hparams(weights_key(seed), **{k: int(full[k]) if k in _INTS else float(full[k]) for k in _TRACED})


def run_one(spec: SweepSpec, config: dict[str, Any]) -> dict[str, float]:
    """One configuration through :func:`jaxcal.online_thesis.run_online_thesis` (no vmap)."""
    full = full_config(spec, TARGET, config)
    key = static_key(spec, TARGET, config)
    data = dataset2(jax.random.PRNGKey(config["seed"]), dataset_config(spec, TARGET, key))
    r = ot.run_online_thesis(data, _hparams(full, config["seed"]), init_every=int(full["init_every"]))
    return {k: float(v) for k, v in _metrics(data, r).items()}


@partial(jax.jit, static_argnames=("dt", "init_every"))
def _group_fn(shared, per_config, *, dt: float, init_every: int):
    """The batch: each distinct initial training once, one after another (``lax.map``: a job's
    numbers do not depend on the batch), then the adaptive loop + metrics vmapped over the
    configurations, each from its job's initial training (datas indexed by seed)."""
    datas, job_seed, job_hps = shared

    def data(i):
        return jax.tree.map(lambda x: x[i], datas)._replace(dt=dt)

    inits = jax.lax.map(lambda job: ot.initial_training(data(job[0]), job[1], init_every), (job_seed, job_hps))

    def one(i, j, hp):
        d = data(i)
        return _metrics(d, ot.run_from_initial(d, hp, jax.tree.map(lambda x: x[j], inits)))

    return jax.vmap(one)(*per_config)


_INIT_FIELDS = ("init_lr", "init_epochs", "acc_init_scale", "gyr_init_scale")  # what the initial training reads


def prepare(spec: SweepSpec, key: tuple, configs: list[dict[str, Any]]) -> Prepared:
    """One batch: the seeds' datasets stacked and the distinct initial trainings (seed and
    :data:`_INIT_FIELDS`) as jobs (shared); per configuration its seed, its job and its hyperparameters."""
    config = dataset_config(spec, TARGET, key)
    seeds = sorted({c["seed"] for c in configs})
    datas = [dataset2(jax.random.PRNGKey(s), config)._replace(dt=None) for s in seeds]
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *datas)
    fulls = [full_config(spec, TARGET, c) for c in configs]
    hps = [_hparams(f, c["seed"]) for f, c in zip(fulls, configs, strict=True)]
    jobs: dict[tuple, int] = {}
    job_idx = [jobs.setdefault((c["seed"], *(f[k] for k in _INIT_FIELDS)), len(jobs)) for f, c in zip(fulls, configs, strict=True)]
    first = {j: job_idx.index(j) for j in range(len(jobs))}
    job_seed = jnp.asarray([seeds.index(configs[first[j]]["seed"]) for j in range(len(jobs))], dtype=jnp.int32)
    job_hps = ot.stack_hparams([hps[first[j]] for j in range(len(jobs))])
    seed_idx = jnp.asarray([seeds.index(c["seed"]) for c in configs], dtype=jnp.int32)
    init_every = int(fulls[0]["init_every"])
    return Prepared(partial(_group_fn, dt=1.0 / config.fs, init_every=init_every), (stacked, job_seed, job_hps),
                    (seed_idx, jnp.asarray(job_idx, dtype=jnp.int32), ot.stack_hparams(hps)))


def describe(spec: SweepSpec) -> str:
    """The report's words on the data."""
    ds = dataset_settings(spec, TARGET)
    return f"Dataset 2 with {ds.n_train} training sequences of {ds.n_samples} samples; fixed {spec.fixed or 'nothing'}"


TARGET = Target(
    name="online-thesis",
    traced=_TRACED,
    static=("init_every",),
    ints=_INTS,
    bools=(),
    ranges={"init_epochs": (0, math.inf, False), "gyr_steps": (0, math.inf, False), "acc_steps": (0, math.inf, False),
            "init_every": (1, math.inf, False), "w": (0.0, 1.0, False), "init_lr": (0.0, math.inf, True),
            "gyr_lr": (0.0, math.inf, True), "acc_lr": (0.0, math.inf, True)},
    defaults={**{f: ot.OnlineThesisHParams._field_defaults[f] for f in _TRACED}, "init_every": ot.INIT_EVERY},
    dataset=Dataset2Config(),
    metrics=(("test_gyr_mrads", "test gyr [mrad/s]"), ("test_acc_mg", "test acc [mg]"),
             ("val_e_g_last50_mrads", "val e_g last 50 [mrad/s]"), ("val_e_a_last50_mg", "val e_a last 50 [mg]"),
             ("init_test_gyr_mrads", "after init gyr [mrad/s]"), ("init_test_acc_mg", "after init acc [mg]")),
    heatmap_metrics=("test_gyr_mrads", "test_acc_mg"),
    best=(("test_gyr_mrads", "gyroscope error", "mrad/s"), ("test_acc_mg", "accelerometer error", "mg")),
    best_context=(),
    describe=describe,
    prepare=prepare,
    run_one=run_one,
)
