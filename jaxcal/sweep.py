"""Hyperparameter sweeps as one vmapped, jitted, sharded call per compile-compatible group.

A :class:`SweepSpec` names a target (:data:`TARGETS`), a grid (name -> values) and/or a random
search (name -> ``(lo, hi, "log" | "lin")``, ``n_random`` samples drawn with ``random_seed``),
fixed overrides, the seeds and the dataset settings. :func:`expand` lists every configuration
(grid x random samples x seeds); :func:`plan` splits them into **groups** whose configurations
share every *static* field (fields that set shapes or Python control flow, e.g. ``init_every``,
``dataset.n_train`` or the subset size ``l``: a change recompiles) and stacks the *traced* fields
(learning rates, steps, ``w``, patience, seeds): each group (or each batch of at most
``batch_size`` of its configurations, padded to the same size so they share one compilation) is
ONE ``jax.jit(jax.vmap(...))`` call.

**Targets.**

- ``"online-thesis"``: the thesis's online algorithm (chapter 4, :mod:`jaxcal.online_thesis`) on
  simulated Dataset 2. Seed ``s`` draws its dataset from ``PRNGKey(s)`` and its initial weights
  from :func:`weights_key` ``(s)``.
- ``"offline-nn"``: the thesis's chapter-3 NN (one hidden layer, :func:`jaxcal.nn.fit_nn`) and,
  as the reference, the 12-parameter linear model (:func:`jaxcal.linear.fit_affine`), each trained
  on exactly ``l`` rows of the fixed Dataset 1 surrogate ``dataset1(PRNGKey(0))`` (1000 train /
  184 val / 184 test; no dataset settings). Seed ``s`` draws the NN's initial weights and which
  ``l`` training rows are used from :func:`offline_seed_keys` ``(s)``, the keys of
  ``experiments/offline.py`` for ``s < 5``.

Each target brings its own batch runner (:attr:`Target.prepare`), unvmapped reference
(:attr:`Target.run_one`), metric columns and report wording, so the sweep machinery below
(grouping, sharding, checkpoints, the table and heatmap) is shared.

**Sharding.** The stacked configuration axis is laid on a ``jax.sharding.Mesh`` over the devices
(default: all local devices) with ``NamedSharding(mesh, P("configs"))``; the axis is padded to a
multiple of the device count (repeating the last configuration) and the padding dropped after.
The data (one copy per seed) are replicated. The same call therefore uses every GPU of a node, or
the ``--xla_force_host_platform_device_count=N`` CPU devices of a test. On a multi-host cluster,
call ``jax.distributed.initialize()`` in every process first (same spec everywhere) and pass
``devices=jax.devices()`` (the global devices): every process builds the same inputs, each device
computes its shard, and the results are gathered with
``jax.experimental.multihost_utils.process_allgather``; let one process (``jax.process_index() ==
0``) call :func:`write_sweep`.

**Checkpoint and resume.** With ``out_dir``, :func:`run_sweep` rewrites ``out_dir/checkpoint.json``
(atomically: temporary file + ``os.replace``) after each batch with every finished batch's rows;
``resume=True`` skips the batches already there. Each batch is deterministic and keeps its size, so
a killed run resumed gives exactly the rows of an uninterrupted one.

I/O happens only in :func:`load_sweep_spec`, :func:`write_sweep` and in :func:`run_sweep` when it
is given ``out_dir`` (the checkpoint); progress lines go through the ``log`` callable (default: none).
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import math
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from jaxcal import online_thesis as ot
from jaxcal.constants import ACC_RANGE_G
from jaxcal.linear import fit_affine
from jaxcal.metrics import euclidean_error
from jaxcal.nn import MLP, THESIS_LEAKY_SLOPE, THESIS_OFFLINE_WIDTHS, fit_nn, nn_calibrate
from jaxcal.normalise import bounds_from_spec
from jaxcal.offline import NNTrainSpec, nn_calibrate_rows
from jaxcal.recording import atomic_output
from jaxcal.sensor import affine_inverse
from jaxcal.simulate.dataset1 import Dataset1Config, dataset1, nested_subset_weights
from jaxcal.simulate.dataset2 import Dataset2Config, dataset2
from jaxcal.train import TrainConfig

__all__ = [
    "MAX_RUNS",
    "failed_runs",
    "n_runs",
    "CHECKPOINT",
    "OFFLINE_DATASET_KEY",
    "TARGETS",
    "Batch",
    "Prepared",
    "SweepResult",
    "SweepSpec",
    "Target",
    "check_spec",
    "expand",
    "load_sweep_spec",
    "offline_seed_keys",
    "plan",
    "run_one",
    "run_sweep",
    "spec_from_dict",
    "spec_to_dict",
    "weights_key",
    "write_sweep",
]

CHECKPOINT = "checkpoint.json"
_DATASET_PREFIX = "dataset."


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
            sharding (the reference :func:`run_sweep` matches).
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
        target: a key of :data:`TARGETS` (``"online-thesis"`` or ``"offline-nn"``).
        grid: name -> list of values; the configurations are the Cartesian product.
        random: name -> ``(lo, hi, "log" | "lin")``; ``n_random`` samples, each joined with every
            grid point.
        n_random: number of random samples (0: no random search).
        random_seed: seed of the random search (numpy ``default_rng``).
        fixed: name -> value overriding a default for every configuration.
        seeds: per-configuration seeds (data and initial weights; see the module docstring).
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


class SweepResult(NamedTuple):
    """Outcome of :func:`run_sweep`.

    Attributes:
        spec: the sweep.
        names: the swept names (grid, then random), the table's configuration columns.
        rows: one dict per configuration and seed: ``group``, the swept names, ``seed`` and the
            target's metrics (online-thesis: :func:`_ot_metrics`; offline-nn:
            :func:`_offline_metrics`).
        timing: seconds per batch (``batches``) and in all (``total_s``); not part of the result
            proper (a resumed run differs only here).
    """

    spec: SweepSpec
    names: tuple[str, ...]
    rows: list[dict[str, Any]]
    timing: dict[str, Any]


# ----------------------------------------------------------------------------- spec


def _fail(msg: str) -> None:
    raise ValueError(msg)


MAX_RUNS = 100_000  # configurations x seeds of one sweep; checked on the spec, before any expansion
_POSITIVE_DATASET = ("fs", "w_max", "test_gyr_amplitude", "acc_lsb_per_g", "gyr_lsb_per_rads")


def n_runs(spec: SweepSpec) -> int:
    """How many runs a spec asks for (grid points x random samples x seeds), counted without
    expanding anything (exact Python integers: a 40^6 grid is 4.1e9)."""
    n = 1
    for v in spec.grid.values():
        n *= len(v) if isinstance(v, (list, tuple)) else 1
    if spec.random:
        n *= max(int(spec.n_random), 0)
    return n * max(len(spec.seeds), 1)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _interval(lo: float | int, hi: float | int, lo_open: bool) -> str:
    if math.isinf(hi):
        return f"{'>' if lo_open else '>='} {lo:g}"
    return f"in {'(' if lo_open else '['}{lo:g}, {hi:g}]"


def _dataset_defaults(target: Target) -> dict[str, Any]:
    return {} if target.dataset is None else target.dataset._asdict()


def _check_value(target: Target, name: str, v: Any, where: str) -> None:
    if name.startswith(_DATASET_PREFIX):
        default = _dataset_defaults(target)[name[len(_DATASET_PREFIX):]]
        if isinstance(default, bool) and isinstance(v, bool):
            return
        if not _is_number(v) or (isinstance(default, int) and (int(v) != v or v < 1)):
            _fail(f"{where}: {name} = {v!r} is not a valid {type(default).__name__}")
        field = name[len(_DATASET_PREFIX):]
        if v < 0 or (field in _POSITIVE_DATASET and v <= 0):
            _fail(f"{where}: {name} = {v!r} must be {'> 0' if field in _POSITIVE_DATASET else '>= 0'}")
        return
    if name in target.bools:
        if not isinstance(v, bool):
            _fail(f"{where}: {name} = {v!r} must be true or false")
        return
    if not _is_number(v):
        _fail(f"{where}: {name} = {v!r} is not a finite number")
    if name in target.ints and int(v) != v:
        _fail(f"{where}: {name} = {v!r} must be an integer")
    if name in target.ranges:
        lo, hi, lo_open = target.ranges[name]
        if not ((lo < v if lo_open else lo <= v) and v <= hi):
            _fail(f"{where}: {name} = {v!r} must be {_interval(lo, hi, lo_open)}")


def _check_name(target: Target, name: str, where: str) -> None:
    if name.startswith(_DATASET_PREFIX):
        if target.dataset is None:
            _fail(f"{where}: target {target.name} has no dataset settings ({name!r})")
        if name[len(_DATASET_PREFIX):] not in target.dataset._fields:
            _fail(f"{where}: unknown dataset field {name!r}; known: {', '.join(target.dataset._fields)}")
        return
    if name not in target.defaults:
        _fail(f"{where}: unknown hyperparameter {name!r} for target {target.name}; known: {', '.join(target.defaults)}")


def _dataset(spec: SweepSpec, target: Target) -> Any:
    """The spec's dataset settings (the target's default when ``spec.dataset`` is ``None``)."""
    return target.dataset if spec.dataset is None else spec.dataset


def check_spec(spec: SweepSpec) -> Target:
    """Refuse a malformed spec with a one-line ``ValueError``; returns its :class:`Target`.

    Args:
        spec: the sweep.
    """
    if spec.target not in TARGETS:
        _fail(f"sweep spec: unknown target {spec.target!r}; known: {', '.join(TARGETS)}")
    t = TARGETS[spec.target]
    for name, vals in spec.grid.items():
        _check_name(t, name, "sweep spec grid")
        if not isinstance(vals, (list, tuple)) or not vals:
            _fail(f"sweep spec grid: {name} must be a non-empty list of values")
        for v in vals:
            _check_value(t, name, v, "sweep spec grid")
    for name, rng in spec.random.items():
        _check_name(t, name, "sweep spec random")
        if name.startswith(_DATASET_PREFIX) or name in t.static:
            _fail(f"sweep spec random: {name} is static (it sets shapes); put it in the grid")
        if name in t.bools:
            _fail(f"sweep spec random: {name} is true/false; put it in the grid")
        if name in spec.grid:
            _fail(f"sweep spec random: {name} is also in the grid")
        if not (isinstance(rng, (list, tuple)) and len(rng) == 3 and rng[2] in ("log", "lin")):
            _fail(f"sweep spec random: {name} must be [lo, hi, \"log\" | \"lin\"], got {rng!r}")
        lo, hi, scale = rng
        for v in (lo, hi):
            _check_value(t, name, v, "sweep spec random")
        if not lo <= hi or (scale == "log" and lo <= 0):
            _fail(f"sweep spec random: {name} range [{lo}, {hi}] is empty or not positive for log")
    if spec.random and spec.n_random < 1:
        _fail("sweep spec random: n must be at least 1")
    for name, v in spec.fixed.items():
        _check_name(t, name, "sweep spec fixed")
        _check_value(t, name, v, "sweep spec fixed")
        if name in spec.grid or name in spec.random:
            _fail(f"sweep spec fixed: {name} is also swept")
    if not spec.seeds or any(not isinstance(s, int) or isinstance(s, bool) or not 0 <= s < 2**31 for s in spec.seeds):
        _fail(f"sweep spec seeds: expected a non-empty list of integers in [0, 2**31), got {list(spec.seeds)!r}")
    if len(set(spec.seeds)) != len(spec.seeds):
        _fail("sweep spec seeds: repeated seed")
    if not isinstance(spec.batch_size, int) or spec.batch_size < 0:
        _fail(f"sweep spec batch_size: expected an integer >= 0, got {spec.batch_size!r}")
    if (n := n_runs(spec)) > MAX_RUNS:
        _fail(f"sweep spec: {n:.3g} runs (grid x random n x seeds), more than the {MAX_RUNS} one sweep may hold; "
              "sweep a coarser grid or fewer random samples")
    swept = (*spec.grid, *spec.random)
    if spec.heatmap and (len(spec.heatmap) != 2 or any(h not in swept for h in spec.heatmap)):
        _fail(f"sweep spec heatmap: expected two of the swept names {list(swept)}, got {list(spec.heatmap)!r}")
    if t.dataset is None:
        if spec.dataset is not None:
            _fail(f"sweep spec dataset: target {t.name} uses a fixed dataset and has no dataset settings")
    else:
        if not isinstance(spec.dataset, (type(t.dataset), type(None))):
            _fail(f"sweep spec dataset: expected a {type(t.dataset).__name__} for target {t.name}")
        for f, v in _dataset(spec, t)._asdict().items():
            _check_value(t, _DATASET_PREFIX + f, v, "sweep spec dataset")
    return t


def spec_from_dict(d: dict[str, Any]) -> SweepSpec:
    """A :class:`SweepSpec` from its JSON form (see ``docs/sweep_example.json``); one-line ``ValueError``.

    Args:
        d: ``{"target", "grid", "random": {"n", "seed", "params": {name: [lo, hi, scale]}},
            "fixed", "seeds", "dataset": {dataset field: value}, "heatmap", "batch_size"}``; every
            key optional (``target``: ``"online-thesis"``; ``dataset`` must be absent or ``{}`` for
            a target without dataset settings).
    """
    if not isinstance(d, dict):
        _fail("sweep spec: expected a JSON object")
    known = {"target", "grid", "random", "fixed", "seeds", "dataset", "heatmap", "batch_size"}
    if extra := sorted(set(d) - known):
        _fail(f"sweep spec: unknown key(s) {', '.join(map(repr, extra))}; known: {', '.join(sorted(known))}")
    for k in ("grid", "fixed", "dataset", "random"):
        if not isinstance(d.get(k, {}), dict):
            _fail(f"sweep spec {k}: expected an object")
    rnd = d.get("random", {})
    if extra := sorted(set(rnd) - {"n", "seed", "params"}):
        _fail(f"sweep spec random: unknown key(s) {', '.join(map(repr, extra))}; known: n, seed, params")
    if not isinstance(rnd.get("params", {}), dict):
        _fail("sweep spec random params: expected an object")
    target = d.get("target", "online-thesis")
    if not isinstance(target, str) or target not in TARGETS:
        _fail(f"sweep spec: unknown target {target!r}; known: {', '.join(TARGETS)}")
    ds, ds0 = d.get("dataset", {}), TARGETS[target].dataset
    if ds0 is None and ds:
        _fail(f"sweep spec dataset: target {target} uses a fixed dataset and has no dataset settings")
    if ds0 is not None and (bad := sorted(set(ds) - set(ds0._fields))):
        _fail(f"sweep spec dataset: unknown field(s) {', '.join(map(repr, bad))}")
    heatmap = d.get("heatmap", [])
    if not isinstance(heatmap, list) or not all(isinstance(h, str) for h in heatmap):
        _fail(f"sweep spec heatmap: expected a list of two swept names, got {heatmap!r}")
    seeds = d.get("seeds", [0])
    if not isinstance(seeds, list):
        _fail("sweep spec seeds: expected a list of integers")
    n_random, random_seed = rnd.get("n", 0), rnd.get("seed", 0)
    for k, v in (("n", n_random), ("seed", random_seed)):
        if not isinstance(v, int) or isinstance(v, bool) or v < 0:
            _fail(f"sweep spec random {k}: expected an integer >= 0, got {v!r}")
    spec = SweepSpec(
        target=target,
        grid={k: list(v) if isinstance(v, list) else v for k, v in d.get("grid", {}).items()},
        random={k: tuple(v) if isinstance(v, list) else v for k, v in rnd.get("params", {}).items()},
        n_random=n_random,
        random_seed=random_seed,
        fixed=dict(d.get("fixed", {})),
        seeds=tuple(seeds),
        dataset=None if ds0 is None else ds0._replace(**ds),
        heatmap=tuple(heatmap),
        batch_size=d.get("batch_size", 0),
    )
    check_spec(spec)
    return spec


def spec_to_dict(spec: SweepSpec) -> dict[str, Any]:
    """The JSON form of a spec (inverse of :func:`spec_from_dict`)."""
    ds = _dataset(spec, TARGETS[spec.target]) if spec.target in TARGETS else spec.dataset
    return {
        "target": spec.target,
        "grid": {k: list(v) for k, v in spec.grid.items()},
        "random": {"n": spec.n_random, "seed": spec.random_seed, "params": {k: list(v) for k, v in spec.random.items()}},
        "fixed": dict(spec.fixed),
        "seeds": list(spec.seeds),
        "dataset": {} if ds is None else ds._asdict(),
        "heatmap": list(spec.heatmap),
        "batch_size": spec.batch_size,
    }


def load_sweep_spec(path: str | os.PathLike) -> SweepSpec:
    """Read a JSON sweep spec (one-line ``ValueError`` naming the file on bad input).

    Args:
        path: the JSON file.
    """
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise ValueError(f"{path}: cannot read ({e.strerror or e})") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not JSON ({e.msg} at line {e.lineno})") from None
    try:
        return spec_from_dict(d)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None


# ----------------------------------------------------------------------------- configurations


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


def expand(spec: SweepSpec) -> list[dict[str, Any]]:
    """Every configuration of a sweep: ``{swept name: value, ..., "seed": s}`` (grid x random x seeds).

    Args:
        spec: the sweep (checked; ``ValueError`` if malformed).
    """
    target = check_spec(spec)
    names = list(spec.grid)
    points = [dict(zip(names, vals, strict=True)) for vals in itertools.product(*spec.grid.values())]
    samples = _random_samples(spec, target)
    return [{**p, **r, "seed": s} for p in points for r in samples for s in spec.seeds]


def _full(spec: SweepSpec, target: Target, config: dict[str, Any]) -> dict[str, Any]:
    """Every hyperparameter of a configuration (defaults < fixed < swept)."""
    return {**target.defaults, **{k: v for k, v in spec.fixed.items() if not k.startswith(_DATASET_PREFIX)},
            **{k: v for k, v in config.items() if k != "seed" and not k.startswith(_DATASET_PREFIX)}}


def _static_key(spec: SweepSpec, target: Target, config: dict[str, Any]) -> tuple:
    full = _full(spec, target, config)
    ds = {**{k: v for k, v in spec.fixed.items() if k.startswith(_DATASET_PREFIX)},
          **{k: v for k, v in config.items() if k.startswith(_DATASET_PREFIX)}}
    return tuple((k, full[k]) for k in target.static) + tuple(sorted(ds.items()))


def _key_label(key: tuple) -> str:
    return ",".join(f"{k}={v}" for k, v in key) or "all"


class Batch(NamedTuple):
    """One vmapped call of :func:`run_sweep` (static: it fixes the compiled shapes).

    Attributes:
        key: the group key, ``((static name, value), ...)``.
        label: ``name=value,...`` (``#j``: the j-th batch of the group); the checkpoint's key.
        configs: the configurations it runs (entries of :func:`expand`).
    """

    key: tuple
    label: str
    configs: list[dict[str, Any]]


def plan(spec: SweepSpec) -> list[Batch]:
    """Split the configurations into compile-compatible groups, and groups into batches.

    Groups follow the first appearance of their static key in :func:`expand`'s order; a group
    with more than ``spec.batch_size`` (> 0) configurations is split into batches of that size.

    Args:
        spec: the sweep.
    """
    target = check_spec(spec)
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for c in expand(spec):
        groups.setdefault(_static_key(spec, target, c), []).append(c)
    out = []
    for key, configs in groups.items():
        size = spec.batch_size or len(configs)
        chunks = [configs[i:i + size] for i in range(0, len(configs), size)]
        for j, chunk in enumerate(chunks):
            label = _key_label(key) + (f"#{j}" if len(chunks) > 1 else "")
            out.append(Batch(key, label, chunk))
    return out


# ----------------------------------------------------------------------------- online-thesis

_OT_TRACED = tuple(f for f in ot.OnlineThesisHParams._fields if f != "key")
_OT_INTS = ("init_epochs", "gyr_steps", "acc_steps", "init_every")


def weights_key(seed: int) -> jax.Array:
    """The PRNG key of the initial weights of online-thesis seed ``seed`` (its dataset uses ``PRNGKey(seed)``).

    Args:
        seed: the configuration's seed.
    """
    return jax.random.fold_in(jax.random.PRNGKey(seed), 1)


def _ot_metrics(data, r: ot.OnlineThesisResult) -> dict[str, jax.Array]:
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
    return ot.default_hparams(weights_key(seed), **{k: int(full[k]) if k in _OT_INTS else float(full[k]) for k in _OT_TRACED})


def _dataset_config(spec: SweepSpec, target: Target, key: tuple) -> Any:
    ds = {k[len(_DATASET_PREFIX):]: v for k, v in key if k.startswith(_DATASET_PREFIX)}
    return _dataset(spec, target)._replace(**ds)


def _ot_run_one(spec: SweepSpec, config: dict[str, Any]) -> dict[str, float]:
    target = TARGETS["online-thesis"]
    full = _full(spec, target, config)
    key = _static_key(spec, target, config)
    data = dataset2(jax.random.PRNGKey(config["seed"]), _dataset_config(spec, target, key))
    r = ot.run_online_thesis(data, _hparams(full, config["seed"]), init_every=int(full["init_every"]))
    return {k: float(v) for k, v in _ot_metrics(data, r).items()}


def _ot_group_fn(datas, per_config, *, dt: float, init_every: int):
    """vmap of the whole algorithm + metrics over the configuration axis (datas indexed by seed)."""

    def one(i, hp):
        d = jax.tree.map(lambda x: x[i], datas)._replace(dt=dt)
        return _ot_metrics(d, ot.run_dataset(d, hp, init_every))

    return jax.vmap(one)(*per_config)


_OT_JIT = jax.jit(_ot_group_fn, static_argnames=("dt", "init_every"))


def _ot_prepare(spec: SweepSpec, key: tuple, configs: list[dict[str, Any]]) -> Prepared:
    target = TARGETS["online-thesis"]
    config = _dataset_config(spec, target, key)
    seeds = sorted({c["seed"] for c in configs})
    datas = [dataset2(jax.random.PRNGKey(s), config)._replace(dt=None) for s in seeds]
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *datas)
    hps = ot.stack_hparams([_hparams(_full(spec, target, c), c["seed"]) for c in configs])
    seed_idx = jnp.asarray([seeds.index(c["seed"]) for c in configs], dtype=jnp.int32)
    init_every = int(_full(spec, target, configs[0])["init_every"])
    return Prepared(functools.partial(_OT_JIT, dt=1.0 / config.fs, init_every=init_every), stacked, (seed_idx, hps))


def _ot_describe(spec: SweepSpec) -> str:
    ds = _dataset(spec, TARGETS["online-thesis"])
    return f"Dataset 2 with {ds.n_train} training sequences of {ds.n_samples} samples; fixed {spec.fixed or 'nothing'}"


# ----------------------------------------------------------------------------- offline-nn

#: Dataset 1 surrogate of the offline-nn target: ``dataset1(PRNGKey(OFFLINE_DATASET_KEY))``, as
#: ``experiments/offline.py``.
OFFLINE_DATASET_KEY = 0
_OFFLINE_SEED_KEY = 1  # experiments/offline.py's SEED_KEY
_OFFLINE_SPLIT_SEEDS = 5  # experiments/offline.py's full run: split(PRNGKey(1), 5)
_OFFLINE_STATIC = ("l", "width", "warm_start", "row_chunk", "max_epochs", "slope")
_OFFLINE_TRAIN = NNTrainSpec()  # the chapter-3 recipe: the target's defaults


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
    root = jax.random.PRNGKey(_OFFLINE_SEED_KEY)
    base = jax.random.split(root, _OFFLINE_SPLIT_SEEDS)[seed] if seed < _OFFLINE_SPLIT_SEEDS else jax.random.fold_in(root, seed)
    init_key, perm_key = jax.random.split(base)
    return init_key, perm_key


class _OfflineStatic(NamedTuple):
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


def _offline_static(full: dict[str, Any]) -> _OfflineStatic:
    return _OfflineStatic(int(full["l"]), int(full["width"]), bool(full["warm_start"]), int(full["row_chunk"]),
                          int(full["max_epochs"]), float(full["slope"]))


def _offline_rows(data, seed: int, l: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(init_key, counts (l, 3), labels (l, 3))`` of a seed: its first ``l`` permuted training rows."""
    init_key, perm_key = offline_seed_keys(seed)
    n = data.train.acc.shape[0]
    sel = np.flatnonzero(np.asarray(nested_subset_weights(perm_key, n, (l,)))[0] > 0)
    return init_key, data.train.acc[sel], data.train.acc_ref[sel]


def _offline_metrics(out_va, out_te, lin, data, epochs, best_epoch, max_epochs: int) -> dict[str, jax.Array]:
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


class _OfflineShared(NamedTuple):
    """The replicated data of an offline-nn batch (seeds stacked on the first axis)."""

    init_keys: jax.Array
    y: jax.Array
    x: jax.Array
    data: Any
    bounds: Any


def _offline_group_fn(shared: _OfflineShared, per_config, *, st: _OfflineStatic):
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
        return _offline_metrics(out_va, out_te, lin, shared.data, res.epochs, res.best_epoch, st.max_epochs)

    return jax.vmap(one)(*per_config)


_OFFLINE_JIT = jax.jit(_offline_group_fn, static_argnames=("st",))


def _offline_call(shared, per_config, *, st: _OfflineStatic) -> dict[str, jax.Array]:
    # Full float32 matmuls, as experiments/offline.py: GPUs may default to TF32 (~1e-3 relative).
    with jax.default_matmul_precision("highest"):
        return _OFFLINE_JIT(shared, per_config, st=st)


def _offline_data():
    data = dataset1(jax.random.PRNGKey(OFFLINE_DATASET_KEY), Dataset1Config())
    return data, bounds_from_spec(data.spec, ACC_RANGE_G)


def _offline_prepare(spec: SweepSpec, key: tuple, configs: list[dict[str, Any]]) -> Prepared:
    target = TARGETS["offline-nn"]
    st = _offline_static(_full(spec, target, configs[0]))
    data, bounds = _offline_data()
    seeds = sorted({c["seed"] for c in configs})
    keys, ys, xs = zip(*(_offline_rows(data, s, st.l) for s in seeds), strict=True)
    shared = _OfflineShared(jnp.stack(keys), jnp.stack(ys), jnp.stack(xs), data, bounds)
    fulls = [_full(spec, target, c) for c in configs]
    cfg = TrainConfig(
        learning_rate=jnp.asarray([float(f["lr"]) for f in fulls], jnp.float32),
        patience=jnp.asarray([int(f["patience"]) for f in fulls], jnp.int32),
        min_delta=jnp.zeros(len(fulls), jnp.float32),
        min_rel_delta=jnp.asarray([float(f["min_rel_delta"]) for f in fulls], jnp.float32),
    )
    seed_idx = jnp.asarray([seeds.index(c["seed"]) for c in configs], dtype=jnp.int32)
    return Prepared(functools.partial(_offline_call, st=st), shared, (seed_idx, cfg))


def _offline_run_one(spec: SweepSpec, config: dict[str, Any]) -> dict[str, Any]:
    """One configuration through ``experiments/offline.py``'s own path (:func:`jaxcal.offline.nn_calibrate_rows`).

    The learning rate there is a (constant) optax schedule and every setting is static: a second
    route to the numbers the vmapped :func:`_offline_group_fn` gives.
    """
    full = _full(spec, TARGETS["offline-nn"], config)
    st = _offline_static(full)
    data, bounds = _offline_data()
    init_key, y, x = _offline_rows(data, config["seed"], st.l)
    lr = float(full["lr"])
    train = NNTrainSpec(lr_init=lr, lr_final=lr, patience=int(full["patience"]), max_epochs=st.max_epochs,
                        min_rel_delta=float(full["min_rel_delta"]), warm_start=st.warm_start,
                        row_chunk=st.row_chunk or None)
    y_eval = jnp.concatenate([data.val.acc, data.test.acc])
    val = (data.val.acc, data.val.acc_ref)
    with jax.default_matmul_precision("highest"):
        out, epochs, best = jax.jit(lambda k, y, x: nn_calibrate_rows(k, st.mlp, bounds, (y, x), val, y_eval, train))(
            init_key, y, x)
        lin = jax.jit(fit_affine)(x, y, jnp.ones(y.shape[0], y.dtype))
    n_va = data.val.acc.shape[0]
    m = _offline_metrics(out[:n_va], out[n_va:], lin, data, epochs, best, st.max_epochs)
    return {k: _scalar(np.asarray(v)) for k, v in m.items()}


def _offline_describe(spec: SweepSpec) -> str:
    target = TARGETS["offline-nn"]
    swept = {*spec.grid, *spec.random}
    rest = {k: v for k, v in _full(spec, target, {}).items() if k not in swept}
    return (f"the fixed Dataset 1 surrogate, dataset1(PRNGKey({OFFLINE_DATASET_KEY})), 1000 train / 184 val / 184 test; "
            f"NN 3-width-3 trained by Adam on l rows drawn per seed, early stopping on the validation loss; linear: the "
            f"12-parameter model on the same rows; settings not swept: {', '.join(f'{k} = {v}' for k, v in rest.items())}")


# ----------------------------------------------------------------------------- targets

TARGETS: dict[str, Target] = {
    "online-thesis": Target(
        name="online-thesis",
        traced=_OT_TRACED,
        static=("init_every",),
        ints=_OT_INTS,
        bools=(),
        ranges={"init_epochs": (0, math.inf, False), "gyr_steps": (0, math.inf, False), "acc_steps": (0, math.inf, False),
                "init_every": (1, math.inf, False), "w": (0.0, 1.0, False), "init_lr": (0.0, math.inf, True),
                "gyr_lr": (0.0, math.inf, True), "acc_lr": (0.0, math.inf, True)},
        defaults={**{f: ot.OnlineThesisHParams._field_defaults[f] for f in _OT_TRACED}, "init_every": ot.INIT_EVERY},
        dataset=Dataset2Config(),
        metrics=(("test_gyr_mrads", "test gyr [mrad/s]"), ("test_acc_mg", "test acc [mg]"),
                 ("val_e_g_last50_mrads", "val e_g last 50 [mrad/s]"), ("val_e_a_last50_mg", "val e_a last 50 [mg]"),
                 ("init_test_gyr_mrads", "after init gyr [mrad/s]"), ("init_test_acc_mg", "after init acc [mg]")),
        heatmap_metrics=("test_gyr_mrads", "test_acc_mg"),
        best=(("test_gyr_mrads", "gyroscope error", "mrad/s"), ("test_acc_mg", "accelerometer error", "mg")),
        best_context=(),
        describe=_ot_describe,
        prepare=_ot_prepare,
        run_one=_ot_run_one,
    ),
    "offline-nn": Target(
        name="offline-nn",
        traced=("lr", "patience", "min_rel_delta"),
        static=_OFFLINE_STATIC,
        ints=("patience", "l", "width", "row_chunk", "max_epochs"),
        bools=("warm_start",),
        ranges={"lr": (0.0, math.inf, True), "patience": (1, math.inf, False), "min_rel_delta": (0.0, 1.0, False),
                "l": (4, Dataset1Config().n_train, False), "width": (1, math.inf, False),
                "row_chunk": (0, math.inf, False), "max_epochs": (1, math.inf, False), "slope": (0.0, 1.0, False)},
        defaults={"lr": _OFFLINE_TRAIN.lr_init, "patience": _OFFLINE_TRAIN.patience,
                  "min_rel_delta": _OFFLINE_TRAIN.min_rel_delta, "l": Dataset1Config().n_train,
                  "width": THESIS_OFFLINE_WIDTHS[0], "warm_start": _OFFLINE_TRAIN.warm_start,
                  "row_chunk": _OFFLINE_TRAIN.row_chunk or 0, "max_epochs": _OFFLINE_TRAIN.max_epochs,
                  "slope": THESIS_LEAKY_SLOPE},
        dataset=None,
        metrics=(("test_mg", "NN test [mg]"), ("linear_mg", "linear test [mg]"), ("val_mg", "NN val [mg]"),
                 ("epochs", "epochs"), ("best_epoch", "best epoch"), ("hit_cap", "share at max_epochs")),
        heatmap_metrics=("test_mg", "epochs"),
        best=(("test_mg", "NN test error", "mg"),),
        best_context=(("linear_mg", "linear model on the same rows", "mg"), ("epochs", "epochs", "")),
        describe=_offline_describe,
        prepare=_offline_prepare,
        run_one=_offline_run_one,
    ),
}


# ----------------------------------------------------------------------------- one batch


def run_one(spec: SweepSpec, config: dict[str, Any]) -> dict[str, Any]:
    """One configuration on its own (no vmap, no sharding): the reference :func:`run_sweep` matches.

    Args:
        spec: the sweep (defaults, fixed values and dataset settings).
        config: one entry of :func:`expand`.
    """
    return check_spec(spec).run_one(spec, config)


def _scalar(v: np.ndarray | np.generic) -> bool | int | float:
    """A row value as plain Python: ``bool``, ``int`` or ``float`` after the array's dtype."""
    if v.dtype == np.bool_:
        return bool(v)
    return int(v) if np.issubdtype(v.dtype, np.integer) else float(v)


def _gather(x: jax.Array) -> np.ndarray:
    if x.is_fully_addressable:
        return np.asarray(x)
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(x, tiled=True))


def _run_batch(spec: SweepSpec, target: Target, batch: Batch, devices: Sequence[jax.Device]) -> list[dict]:
    """One vmapped, jitted, sharded call; the rows of the batch's configurations."""
    n = len(batch.configs)
    configs = batch.configs + [batch.configs[-1]] * (-n % len(devices))
    prep = target.prepare(spec, batch.key, configs)
    mesh = Mesh(np.asarray(devices), ("configs",))
    along, replicated = NamedSharding(mesh, P("configs")), NamedSharding(mesh, P())
    per_config = jax.device_put(prep.per_config, along)
    shared = jax.device_put(prep.shared, replicated)
    out = prep.fn(shared, per_config)
    out = {k: _gather(v)[:n] for k, v in out.items()}
    names = (*spec.grid, *spec.random)
    return [
        {"group": batch.label, **{k: c[k] for k in names}, "seed": c["seed"], **{k: _scalar(v[i]) for k, v in out.items()}}
        for i, c in enumerate(batch.configs)
    ]


# ----------------------------------------------------------------------------- the sweep


def _spec_hash(spec: SweepSpec) -> str:
    return hashlib.sha256(json.dumps(spec_to_dict(spec), sort_keys=True).encode()).hexdigest()[:16]


def _write_json(path: Path, obj: Any) -> None:
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=1) + "\n")


def _load_checkpoint(path: Path, spec: SweepSpec) -> dict[str, list[dict]]:
    if not path.exists():
        return {}
    try:
        ck = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: unreadable checkpoint ({e}); remove it or run without --resume") from None
    if not isinstance(ck, dict) or ck.get("spec_hash") != _spec_hash(spec) or not isinstance(ck.get("batches"), dict):
        raise ValueError(f"{path}: checkpoint of a different sweep spec; remove it or use another --out")
    return ck["batches"]


def run_sweep(
    spec: SweepSpec,
    *,
    out_dir: str | os.PathLike | None = None,
    resume: bool = False,
    devices: Sequence[jax.Device] | None = None,
    log: Callable[[str], None] | None = None,
) -> SweepResult:
    """Run a sweep: one vmapped, jitted call per batch, sharded over ``devices``.

    Args:
        spec: the sweep (checked first; ``ValueError`` if malformed).
        out_dir: where ``checkpoint.json`` is rewritten after each batch (``None``: no checkpoint).
        resume: skip the batches already in ``out_dir``'s checkpoint (it must be of the same spec).
        devices: the devices of the configuration axis' mesh (default ``jax.local_devices()``;
            multi-host: ``jax.devices()`` after ``jax.distributed.initialize()``).
        log: called with one progress line (ETA) per batch; ``None``: silent.

    Returns:
        :class:`SweepResult` with rows in :func:`expand`'s order.
    """
    target = check_spec(spec)
    batches = plan(spec)
    devices = list(jax.local_devices() if devices is None else devices)
    ck_path = None if out_dir is None else Path(out_dir) / CHECKPOINT
    if resume and ck_path is None:
        _fail("run_sweep: resume needs out_dir")
    done = _load_checkpoint(ck_path, spec) if resume else {}
    if ck_path is not None:
        ck_path.parent.mkdir(parents=True, exist_ok=True)
    todo = [b for b in batches if b.label not in done]
    timing: dict[str, float] = {}
    t_start = time.perf_counter()
    for k, b in enumerate(todo):
        t0 = time.perf_counter()
        done[b.label] = _run_batch(spec, target, b, devices)
        timing[b.label] = time.perf_counter() - t0
        if ck_path is not None:
            _write_json(ck_path, {"spec_hash": _spec_hash(spec), "batches": done})
        if log is not None:
            elapsed = time.perf_counter() - t_start
            eta = elapsed / (k + 1) * (len(todo) - k - 1)
            log(f"sweep: batch {len(batches) - len(todo) + k + 1}/{len(batches)} ({b.label}, {len(b.configs)} "
                f"configurations on {len(devices)} device(s)) in {timing[b.label]:.1f} s; ETA {eta:.0f} s")
    names = (*spec.grid, *spec.random)
    order: dict[tuple, int] = {}
    for i, c in enumerate(expand(spec)):
        order.setdefault(tuple(c[k] for k in (*names, "seed")), i)
    rows = sorted((r for b in batches for r in done[b.label]), key=lambda r: order[tuple(r[k] for k in (*names, "seed"))])
    return SweepResult(spec, names, rows, {"batches": timing, "total_s": time.perf_counter() - t_start,
                                           "resumed": len(batches) - len(todo), "devices": len(devices)})


# ----------------------------------------------------------------------------- output


def failed_runs(result: SweepResult) -> int:
    """Runs whose every metric is non-finite (diverged, or a configuration that cannot run)."""
    keys = [k for k, _ in TARGETS[result.spec.target].metrics]

    def bad(r: dict) -> bool:
        vals = [r.get(k) for k in keys if isinstance(r.get(k), (int, float))]
        return bool(vals) and not any(math.isfinite(v) for v in vals)

    return sum(bad(r) for r in result.rows)


def _seed_means(result: SweepResult) -> list[dict[str, Any]]:
    """Rows averaged over seeds (one per configuration), in first-appearance order."""
    by: dict[tuple, list[dict]] = {}
    for r in result.rows:
        by.setdefault(tuple(r[k] for k in result.names), []).append(r)
    out = []
    for key, rs in by.items():
        m = dict(zip(result.names, key, strict=True))
        for col, _ in TARGETS[result.spec.target].metrics:
            m[col] = float(np.mean([r[col] for r in rs]))
        m["n_seeds"] = len(rs)
        out.append(m)
    return out


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _markdown(result: SweepResult) -> str:
    spec = result.spec
    target = TARGETS[spec.target]
    means = _seed_means(result)
    cols = [*result.names, *(c for c, _ in target.metrics)]
    heads = [*result.names, *(h for _, h in target.metrics)]
    lines = [
        f"# Sweep: {spec.target}",
        "",
        f"Written by `jaxcal sweep` ({len(result.rows)} runs: {len(means)} configurations x {len(spec.seeds)} seeds "
        f"{list(spec.seeds)}; {target.describe(spec)}). Errors are test-set means "
        f"(eq. 3.8) averaged over the seeds; {result.timing.get('total_s', 0):.1f} s on "
        f"{result.timing.get('devices', 1)} device(s).",
        "",
    ]
    if means:
        show = lambda m: ", ".join(f"{k} = {_fmt(m[k])}" for k in result.names) or "the only configuration"  # noqa: E731
        words = []
        for col, phrase, unit in target.best:
            b = min(means, key=lambda m: m[col])
            others = "; ".join(f"{p} {b[c]:.4g}{' ' + u if u else ''}" for c, p, u in (*target.best, *target.best_context) if c != col)
            words.append(f"Lowest {phrase}: {b[col]:.2f} {unit} ({show(b)}{'; ' + others if others else ''}).")
        lines += [" ".join(words), ""]
    lines += ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    lines += ["| " + " | ".join(_fmt(m[c]) for c in cols) + " |" for m in means]
    lines += ["", "Per seed: `sweep.json` (`rows`).", ""]
    return "\n".join(lines)


def _heatmap_axes(result: SweepResult) -> tuple[str, str] | None:
    if result.spec.heatmap:
        return tuple(result.spec.heatmap)
    return tuple(result.names[:2]) if len(result.names) >= 2 else None


def _tick(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def _write_heatmap(path: Path, result: SweepResult, axes: tuple[str, str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    target = TARGETS[result.spec.target]
    heads = dict(target.metrics)
    xa, ya = axes
    xs = sorted({r[xa] for r in result.rows})
    ys = sorted({r[ya] for r in result.rows})
    fig, panes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, col in zip(panes, target.heatmap_metrics, strict=True):
        grid = np.full((len(ys), len(xs)), np.nan)
        for j, y in enumerate(ys):
            for i, x in enumerate(xs):
                v = [r[col] for r in result.rows if r[xa] == x and r[ya] == y]
                grid[j, i] = np.mean(v) if v else np.nan
        fin = grid[np.isfinite(grid)]
        # a log colour scale when the cells span more than a decade (e.g. converged vs unconverged fits)
        norm = LogNorm() if fin.size and fin.min() > 0 and fin.max() > 10 * fin.min() else None
        im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis", norm=norm)
        ax.set_xticks(range(len(xs)), [_tick(x) for x in xs], rotation=45)
        ax.set_yticks(range(len(ys)), [_tick(y) for y in ys])
        ax.set_xlabel(xa)
        ax.set_ylabel(ya)
        ax.set_title(f"{heads[col]}, mean over seeds and other axes")
        for j in range(len(ys)):
            for i in range(len(xs)):
                if np.isfinite(grid[j, i]):
                    ax.text(i, j, f"{grid[j, i]:.3g}", ha="center", va="center", color="w", fontsize=8)
        fig.colorbar(im, ax=ax)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def write_sweep(out_dir: str | os.PathLike, result: SweepResult) -> list[Path]:
    """Write ``sweep.json``, ``sweep.md`` and (two swept names or more) ``sweep_heatmap.png``: all three
    finished in a temporary folder inside ``out_dir`` first, then moved into place (an earlier heatmap
    removed when this sweep has none), so an interruption leaves the earlier results whole.

    Args:
        out_dir: the directory (created if needed).
        result: from :func:`run_sweep`.

    Returns:
        The paths written.
    """
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".sweep.", suffix=".partial", dir=d))
    try:  # every file finished beside the folder first: an interruption leaves the earlier results whole
        names = ["sweep.md", "sweep.json"]
        _write_json(tmp / "sweep.json", {"spec": spec_to_dict(result.spec), "names": list(result.names),
                                         "rows": result.rows, "timing": result.timing})
        (tmp / "sweep.md").write_text(_markdown(result))
        axes = _heatmap_axes(result)
        if axes is not None:
            _write_heatmap(tmp / "sweep_heatmap.png", result, axes)
            names.insert(0, "sweep_heatmap.png")
        else:  # an earlier sweep's heatmap would not describe these results
            (d / "sweep_heatmap.png").unlink(missing_ok=True)
        for n in names:  # sweep.json, the record, last
            os.replace(tmp / n, d / n)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return [d / n for n in ("sweep.json", "sweep.md", "sweep_heatmap.png") if n in names]
