"""The types a sweep target is built from, and how one configuration's fields are resolved.

A target module (``jaxcal/sweep/targets/``) imports only this module (and the library): it builds
a :class:`Target` whose ``prepare`` returns a :class:`Prepared` batch, and resolves a
configuration with :func:`full_config`, :func:`static_key` and :func:`dataset_config`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import numpy as np

__all__ = [
    "DATASET_PREFIX",
    "Prepared",
    "SweepSpec",
    "Target",
    "dataset_config",
    "dataset_settings",
    "full_config",
    "scalar",
    "static_key",
]

#: ``dataset.<field>`` in a spec's ``grid`` / ``fixed`` names a field of the target's dataset settings.
DATASET_PREFIX = "dataset."


class Prepared(NamedTuple):
    """One batch made ready by a target (:attr:`Target.prepare`) for the shared, sharded call.

    Attributes:
        fn: ``fn(shared, per_config) -> {metric: (n,) array}``, jitted (its static settings bound).
        shared: pytree replicated on every device (the data, one copy per seed).
        per_config: pytree whose leaves have the configuration axis first (sharded).
    """

    fn: Callable[[Any, Any], dict[str, jax.Array]]
    shared: Any
    per_config: Any


class Target(NamedTuple):
    """What a sweep can tune, how one configuration's fields are split, and how a batch runs.

    Attributes:
        name: the target's name in a spec (``"online-thesis"``, ``"offline-nn"``).
        traced: hyperparameters stacked along the configuration axis (vmapped).
        static: hyperparameters that set shapes or control flow (a group key: a change recompiles);
            ``dataset.<field>`` of the target's dataset settings are static too.
        ints: the names whose values are integers (random samples are rounded).
        bools: the names whose values are ``true`` / ``false``.
        ranges: name -> ``(lo, hi, lo_open)``: the values allowed (``lo_open``: ``lo`` itself is not).
        defaults: every hyperparameter's default value.
        dataset: the default dataset settings (a config NamedTuple of scalar fields), or ``None``
            for a fixed dataset without settings.
        metrics: ``(row key, table heading)`` of the markdown table's metric columns.
        heatmap_metrics: the two row keys of the heatmap's panes.
        best: ``(row key, phrase, unit)``: the report names the configuration lowest in each.
        best_context: ``(row key, phrase, unit)`` also quoted for each best configuration.
        describe: ``describe(spec) -> str``, the report's words on the data.
        prepare: ``prepare(spec, group key, configs) -> Prepared``: one batch's inputs.
        run_one: ``run_one(spec, config) -> {metric: value}``: one configuration without vmap or
            sharding (the reference :func:`jaxcal.sweep.run_sweep` matches).
    """

    name: str
    traced: tuple[str, ...]
    static: tuple[str, ...]
    ints: tuple[str, ...]
    bools: tuple[str, ...]
    ranges: dict[str, tuple[float, float, bool]]
    defaults: dict[str, Any]
    dataset: Any
    metrics: tuple[tuple[str, str], ...]
    heatmap_metrics: tuple[str, str]
    best: tuple[tuple[str, str, str], ...]
    best_context: tuple[tuple[str, str, str], ...]
    describe: Callable[[Any], str]
    prepare: Callable[[Any, tuple, list[dict[str, Any]]], Prepared]
    run_one: Callable[[Any, dict[str, Any]], dict[str, Any]]


class SweepSpec(NamedTuple):
    """A sweep (plain Python values; the whole spec is static: it decides the groups).

    Attributes:
        target: a key of :data:`jaxcal.sweep.TARGETS` (``"online-thesis"`` or ``"offline-nn"``).
        grid: name -> list of values; the configurations are the Cartesian product.
        random: name -> ``(lo, hi, "log" | "lin")``; ``n_random`` samples, each joined with every
            grid point.
        n_random: number of random samples (0: no random search).
        random_seed: seed of the random search (numpy ``default_rng``).
        fixed: name -> value overriding a default for every configuration.
        seeds: per-configuration seeds (data and initial weights; see each target's module).
        dataset: the dataset settings (online-thesis: a :class:`~jaxcal.simulate.Dataset2Config`;
            ``dataset.<field>`` in ``grid`` overrides them per group); ``None``: the target's
            default (offline-nn has no dataset settings: ``None`` only).
        heatmap: the two swept names of the heatmap (``()``: the first two swept names).
        batch_size: at most this many configurations per call (0: a whole group per call); smaller
            batches checkpoint more often.
    """

    target: str = "online-thesis"
    grid: dict[str, list] = {}  # noqa: RUF012 - a NamedTuple default, never mutated
    random: dict[str, tuple] = {}  # noqa: RUF012
    n_random: int = 0
    random_seed: int = 0
    fixed: dict[str, Any] = {}  # noqa: RUF012
    seeds: tuple[int, ...] = (0,)
    dataset: Any = None
    heatmap: tuple[str, ...] = ()
    batch_size: int = 0


def dataset_settings(spec: SweepSpec, target: Target) -> Any:
    """The spec's dataset settings (the target's default when ``spec.dataset`` is ``None``)."""
    return target.dataset if spec.dataset is None else spec.dataset


def full_config(spec: SweepSpec, target: Target, config: dict[str, Any]) -> dict[str, Any]:
    """Every hyperparameter of a configuration (defaults < fixed < swept)."""
    return {**target.defaults, **{k: v for k, v in spec.fixed.items() if not k.startswith(DATASET_PREFIX)},
            **{k: v for k, v in config.items() if k != "seed" and not k.startswith(DATASET_PREFIX)}}


def static_key(spec: SweepSpec, target: Target, config: dict[str, Any]) -> tuple:
    """The group key of a configuration: ``((static name, value), ...)`` then the dataset overrides."""
    full = full_config(spec, target, config)
    ds = {**{k: v for k, v in spec.fixed.items() if k.startswith(DATASET_PREFIX)},
          **{k: v for k, v in config.items() if k.startswith(DATASET_PREFIX)}}
    return tuple((k, full[k]) for k in target.static) + tuple(sorted(ds.items()))


def dataset_config(spec: SweepSpec, target: Target, key: tuple) -> Any:
    """The dataset settings of a group: the spec's, with the group key's ``dataset.<field>`` values."""
    ds = {k[len(DATASET_PREFIX):]: v for k, v in key if k.startswith(DATASET_PREFIX)}
    return dataset_settings(spec, target)._replace(**ds)


def scalar(v: np.ndarray | np.generic) -> bool | int | float:
    """A row value as plain Python: ``bool``, ``int`` or ``float`` after the array's dtype."""
    if v.dtype == np.bool_:
        return bool(v)
    return int(v) if np.issubdtype(v.dtype, np.integer) else float(v)
