"""A toy sweep target: the whole of what a new target needs (see ``test_sweep.py``).

``toy-gd``: ``steps`` gradient-descent steps of size ``lr`` on ``f(x) = sum_i a_i (x_i - c_i)^2 / 2``
from ``x = 0``, with curvatures ``a = (1, 2, 4)`` and ``c ~ N(0, I)`` drawn from ``PRNGKey(seed)``.
Its closed form, ``x_n - c = -c (1 - lr a)^n`` per axis, is the test's independent truth. ``lr``
is traced (vmapped); ``steps`` is static (a group key). Register it with one line,
``sweep.targets.register(toy_sweep_target.TARGET)``.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import jax
import jax.numpy as jnp

from jaxcal.sweep.base import Prepared, SweepSpec, Target, full_config

__all__ = ["CURVATURE", "TARGET", "centre"]

CURVATURE = (1.0, 2.0, 4.0)


def centre(seed: int) -> jax.Array:
    """The minimum ``c`` of seed ``seed``."""
    return jax.random.normal(jax.random.PRNGKey(seed), (3,))


def _descend(c: jax.Array, lr: jax.Array, steps: int) -> dict[str, jax.Array]:
    a = jnp.asarray(CURVATURE)
    x = jax.lax.fori_loop(0, steps, lambda _, x: x - lr * a * (x - c), jnp.zeros(3))
    return {"error": jnp.linalg.norm(x - c), "loss": 0.5 * jnp.sum(a * (x - c) ** 2)}


@functools.partial(jax.jit, static_argnames=("steps",))
def _group(centres, per_config, *, steps: int):
    return jax.vmap(lambda i, lr: _descend(centres[i], lr, steps))(*per_config)


def prepare(spec: SweepSpec, key: tuple, configs: list[dict[str, Any]]) -> Prepared:
    seeds = sorted({c["seed"] for c in configs})
    lrs = jnp.asarray([float(full_config(spec, TARGET, c)["lr"]) for c in configs])
    idx = jnp.asarray([seeds.index(c["seed"]) for c in configs], jnp.int32)
    steps = int(full_config(spec, TARGET, configs[0])["steps"])
    return Prepared(functools.partial(_group, steps=steps), jnp.stack([centre(s) for s in seeds]), (idx, lrs))


def run_one(spec: SweepSpec, config: dict[str, Any]) -> dict[str, float]:
    full = full_config(spec, TARGET, config)
    out = _descend(centre(config["seed"]), jnp.asarray(float(full["lr"])), int(full["steps"]))
    return {k: float(v) for k, v in out.items()}


TARGET = Target(
    name="toy-gd",
    traced=("lr",),
    static=("steps",),
    ints=("steps",),
    bools=(),
    ranges={"lr": (0.0, 1.0, True), "steps": (1, math.inf, False)},
    defaults={"lr": 0.1, "steps": 10},
    dataset=None,
    metrics=(("error", "distance to the minimum"), ("loss", "loss")),
    heatmap_metrics=("error", "loss"),
    best=(("error", "distance to the minimum", ""),),
    best_context=(("loss", "loss", ""),),
    describe=lambda spec: f"gradient descent on a quadratic with curvatures {CURVATURE}",
    prepare=prepare,
    run_one=run_one,
)
