"""A sweep's configurations (:func:`expand`) and their compile-compatible batches (:func:`plan`).

:func:`expand` lists every configuration (grid x random samples x seeds); :func:`plan` splits them
into **groups** whose configurations share every *static* field (fields that set shapes or Python
control flow: a change recompiles) and cuts a group into batches of at most ``batch_size``.
:func:`configurations` and :func:`batches` do the same for a spec already checked (they take
:func:`~jaxcal.sweep.spec.check_spec`'s :class:`~jaxcal.sweep.base.Target`): a run checks its spec once.
"""

from __future__ import annotations

import itertools
from typing import Any, NamedTuple

import numpy as np

from jaxcal.sweep.base import SweepSpec, Target, static_key
from jaxcal.sweep.spec import CheckedSpec, checked

__all__ = ["Batch", "batches", "configurations", "expand", "plan"]


class Batch(NamedTuple):
    """One vmapped call of :func:`jaxcal.sweep.run_sweep` (static: it fixes the compiled shapes).

    Attributes:
        key: the group key, ``((static name, value), ...)``.
        label: ``name=value,...`` (``#j``: the j-th batch of the group); the checkpoint's key.
        configs: the configurations it runs (entries of :func:`expand`).
    """

    key: tuple
    label: str
    configs: list[dict[str, Any]]


def _random_samples(spec: SweepSpec, target: Target) -> list[dict[str, Any]]:
    if not spec.random:
        return [{}]
    rng = np.random.default_rng(spec.random_seed)
    out = []
    for _ in range(spec.n_random):
        s = {}
        for name, (lo, hi, scale) in spec.random.items():
            u = float(rng.uniform())
            v = lo * (hi / lo) ** u if scale == "log" else lo + (hi - lo) * u
            s[name] = round(v) if name in target.ints else v
        out.append(s)
    return out


def configurations(spec: SweepSpec, target: Target) -> list[dict[str, Any]]:
    """:func:`expand` of a checked spec (``target``: its :func:`~jaxcal.sweep.spec.check_spec`)."""
    names = list(spec.grid)
    points = [dict(zip(names, vals, strict=True)) for vals in itertools.product(*spec.grid.values())]
    samples = _random_samples(spec, target)
    return [{**p, **r, "seed": s} for p in points for r in samples for s in spec.seeds]


def expand(spec: SweepSpec | CheckedSpec) -> list[dict[str, Any]]:
    """Every configuration of a sweep: ``{swept name: value, ..., "seed": s}`` (grid x random x seeds).

    Args:
        spec: the sweep (a plain spec is checked, ``ValueError`` if malformed; a
            :class:`~jaxcal.sweep.spec.CheckedSpec` is not checked again).
    """
    return configurations(*checked(spec))


def _key_label(key: tuple) -> str:
    return ",".join(f"{k}={v}" for k, v in key) or "all"


def batches(spec: SweepSpec, target: Target) -> list[Batch]:
    """:func:`plan` of a checked spec (``target``: its :func:`~jaxcal.sweep.spec.check_spec`)."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for c in configurations(spec, target):
        groups.setdefault(static_key(spec, target, c), []).append(c)
    out = []
    for key, configs in groups.items():
        size = spec.batch_size or len(configs)
        chunks = [configs[i:i + size] for i in range(0, len(configs), size)]
        for j, chunk in enumerate(chunks):
            label = _key_label(key) + (f"#{j}" if len(chunks) > 1 else "")
            out.append(Batch(key, label, chunk))
    return out


def plan(spec: SweepSpec | CheckedSpec) -> list[Batch]:
    """Split the configurations into compile-compatible groups, and groups into batches.

    Groups follow the first appearance of their static key in :func:`expand`'s order; a group
    with more than ``spec.batch_size`` (> 0) configurations is split into batches of that size.

    Args:
        spec: the sweep (a plain spec is checked, ``ValueError`` if malformed; a
            :class:`~jaxcal.sweep.spec.CheckedSpec` is not checked again).
    """
    return batches(*checked(spec))
