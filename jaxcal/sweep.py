"""Hyperparameter sweeps as one vmapped, jitted, sharded call per compile-compatible group.

A :class:`SweepSpec` names a target (``"online-thesis"``: the thesis's online algorithm on simulated
Dataset 2, :mod:`jaxcal.online_thesis`), a grid (name -> values) and/or a random search (name ->
``(lo, hi, "log" | "lin")``, ``n_random`` samples drawn with ``random_seed``), fixed overrides, the
seeds and the dataset settings. :func:`expand` lists every configuration (grid x random samples x
seeds); :func:`plan` splits them into **groups** whose configurations share every *static* field
(fields that set shapes or Python control flow, e.g. ``init_every`` or ``dataset.n_train``: a
change recompiles) and stacks the *traced* fields (learning rates, steps, ``w``, initial scales,
seeds): each group (or each batch of at most ``batch_size`` of its configurations, padded to the
same size so they share one compilation) is ONE ``jax.jit(jax.vmap(...))`` call.

**Sharding.** The stacked configuration axis is laid on a ``jax.sharding.Mesh`` over the devices
(default: all local devices) with ``NamedSharding(mesh, P("configs"))``; the axis is padded to a
multiple of the device count (repeating the last configuration) and the padding dropped after.
The datasets (one per seed) are replicated. The same call therefore uses every GPU of a node, or
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

**Per-configuration randomness.** Seed ``s`` draws its dataset from ``PRNGKey(s)`` and its initial
weights from :func:`weights_key` ``(s)``, as :func:`run_one` does for a single configuration.

I/O happens only in :func:`load_sweep_spec`, :func:`write_sweep` and in :func:`run_sweep` when it
is given ``out_dir`` (the checkpoint); progress lines go through the ``log`` callable (default: none).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
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
from jaxcal.recording import atomic_output
from jaxcal.simulate.dataset2 import Dataset2Config, dataset2

__all__ = [
    "CHECKPOINT",
    "TARGETS",
    "Batch",
    "SweepResult",
    "SweepSpec",
    "Target",
    "check_spec",
    "expand",
    "load_sweep_spec",
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


class Target(NamedTuple):
    """What a sweep can tune and how one configuration's fields are split.

    Attributes:
        name: the target's name in a spec (``"online-thesis"``).
        traced: hyperparameters stacked along the configuration axis (vmapped).
        static: hyperparameters that set shapes or control flow (a group key: a change recompiles);
            ``dataset.<field>`` of :class:`~jaxcal.simulate.Dataset2Config` are static too.
        ints: the names whose values are integers (random samples are rounded).
        defaults: every hyperparameter's default value.
    """

    name: str
    traced: tuple[str, ...]
    static: tuple[str, ...]
    ints: tuple[str, ...]
    defaults: dict[str, Any]


_OT_TRACED = tuple(f for f in ot.OnlineThesisHParams._fields if f != "key")
TARGETS: dict[str, Target] = {
    "online-thesis": Target(
        name="online-thesis",
        traced=_OT_TRACED,
        static=("init_every",),
        ints=("init_epochs", "gyr_steps", "acc_steps", "init_every"),
        defaults={**{f: ot.OnlineThesisHParams._field_defaults[f] for f in _OT_TRACED}, "init_every": ot.INIT_EVERY},
    ),
}


class SweepSpec(NamedTuple):
    """A sweep (plain Python values; the whole spec is static: it decides the groups).

    Attributes:
        target: a key of :data:`TARGETS` (``"online-thesis"``).
        grid: name -> list of values; the configurations are the Cartesian product.
        random: name -> ``(lo, hi, "log" | "lin")``; ``n_random`` samples, each joined with every
            grid point.
        n_random: number of random samples (0: no random search).
        random_seed: seed of the random search (numpy ``default_rng``).
        fixed: name -> value overriding a default for every configuration.
        seeds: per-configuration seeds (dataset and initial weights; see the module docstring).
        dataset: the Dataset 2 settings (``dataset.<field>`` in ``grid`` overrides them per group).
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
    dataset: Dataset2Config = Dataset2Config()
    heatmap: tuple[str, ...] = ()
    batch_size: int = 0


class SweepResult(NamedTuple):
    """Outcome of :func:`run_sweep`.

    Attributes:
        spec: the sweep.
        names: the swept names (grid, then random), the table's configuration columns.
        rows: one dict per configuration and seed: ``group``, the swept names, ``seed``, the test
            errors ``test_acc_mg`` / ``test_gyr_mrads`` (mean Euclidean error, eq. 3.8, after the
            whole algorithm), the same after the initial training (``init_test_*``), the validation
            errors of eq. 4.14 after the last sequence (``val_e_*_final``) and averaged over the
            last 50 sequences (``val_e_*_last50``), and the initial-training losses.
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


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_value(target: Target, name: str, v: Any, where: str) -> None:
    if name.startswith(_DATASET_PREFIX):
        field = name[len(_DATASET_PREFIX):]
        default = Dataset2Config._field_defaults[field]
        if isinstance(default, bool) and isinstance(v, bool):
            return
        if not _is_number(v) or (isinstance(default, int) and (int(v) != v or v < 1)):
            _fail(f"{where}: {name} = {v!r} is not a valid {type(default).__name__}")
        return
    if not _is_number(v):
        _fail(f"{where}: {name} = {v!r} is not a finite number")
    if name in target.ints and (int(v) != v or v < (1 if name == "init_every" else 0)):
        _fail(f"{where}: {name} = {v!r} must be a non-negative integer")
    if name == "w" and not 0.0 <= v <= 1.0:
        _fail(f"{where}: w = {v!r} must lie in [0, 1]")
    if name.endswith("_lr") and v <= 0:
        _fail(f"{where}: {name} = {v!r} must be positive")


def _check_name(target: Target, name: str, where: str) -> None:
    if name.startswith(_DATASET_PREFIX):
        if name[len(_DATASET_PREFIX):] not in Dataset2Config._fields:
            _fail(f"{where}: unknown dataset field {name!r}; known: {', '.join(Dataset2Config._fields)}")
        return
    if name not in target.defaults:
        _fail(f"{where}: unknown hyperparameter {name!r} for target {target.name}; known: {', '.join(target.defaults)}")


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
    swept = (*spec.grid, *spec.random)
    if spec.heatmap and (len(spec.heatmap) != 2 or any(h not in swept for h in spec.heatmap)):
        _fail(f"sweep spec heatmap: expected two of the swept names {list(swept)}, got {list(spec.heatmap)!r}")
    for f, v in spec.dataset._asdict().items():
        _check_value(t, _DATASET_PREFIX + f, v, "sweep spec dataset")
    return t


def spec_from_dict(d: dict[str, Any]) -> SweepSpec:
    """A :class:`SweepSpec` from its JSON form (see ``docs/sweep_example.json``); one-line ``ValueError``.

    Args:
        d: ``{"target", "grid", "random": {"n", "seed", "params": {name: [lo, hi, scale]}},
            "fixed", "seeds", "dataset": {Dataset2Config field: value}, "heatmap", "batch_size"}``;
            every key but ``target`` optional.
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
    ds = d.get("dataset", {})
    if bad := sorted(set(ds) - set(Dataset2Config._fields)):
        _fail(f"sweep spec dataset: unknown field(s) {', '.join(map(repr, bad))}")
    seeds = d.get("seeds", [0])
    if not isinstance(seeds, list):
        _fail("sweep spec seeds: expected a list of integers")
    n_random, random_seed = rnd.get("n", 0), rnd.get("seed", 0)
    for k, v in (("n", n_random), ("seed", random_seed)):
        if not isinstance(v, int) or isinstance(v, bool) or v < 0:
            _fail(f"sweep spec random {k}: expected an integer >= 0, got {v!r}")
    spec = SweepSpec(
        target=d.get("target", "online-thesis"),
        grid={k: list(v) if isinstance(v, list) else v for k, v in d.get("grid", {}).items()},
        random={k: tuple(v) if isinstance(v, list) else v for k, v in rnd.get("params", {}).items()},
        n_random=n_random,
        random_seed=random_seed,
        fixed=dict(d.get("fixed", {})),
        seeds=tuple(seeds),
        dataset=Dataset2Config()._replace(**ds),
        heatmap=tuple(d.get("heatmap", ())),
        batch_size=d.get("batch_size", 0),
    )
    check_spec(spec)
    return spec


def spec_to_dict(spec: SweepSpec) -> dict[str, Any]:
    """The JSON form of a spec (inverse of :func:`spec_from_dict`)."""
    return {
        "target": spec.target,
        "grid": {k: list(v) for k, v in spec.grid.items()},
        "random": {"n": spec.n_random, "seed": spec.random_seed, "params": {k: list(v) for k, v in spec.random.items()}},
        "fixed": dict(spec.fixed),
        "seeds": list(spec.seeds),
        "dataset": spec.dataset._asdict(),
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


def weights_key(seed: int) -> jax.Array:
    """The PRNG key of the initial weights of seed ``seed`` (its dataset uses ``PRNGKey(seed)``).

    Args:
        seed: the configuration's seed.
    """
    return jax.random.fold_in(jax.random.PRNGKey(seed), 1)


def _metrics(data, r: ot.OnlineThesisResult) -> dict[str, jax.Array]:
    """The row metrics of one run (inside jit/vmap): mg and mrad/s."""
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
    ints = TARGETS["online-thesis"].ints
    return ot.default_hparams(weights_key(seed), **{k: int(full[k]) if k in ints else float(full[k]) for k in _OT_TRACED})


def _dataset_config(spec: SweepSpec, key: tuple) -> Dataset2Config:
    ds = {k[len(_DATASET_PREFIX):]: v for k, v in key if k.startswith(_DATASET_PREFIX)}
    return spec.dataset._replace(**ds)


def run_one(spec: SweepSpec, config: dict[str, Any]) -> dict[str, float]:
    """One configuration on its own (no vmap, no sharding): the reference :func:`run_sweep` matches.

    Args:
        spec: the sweep (defaults, fixed values and dataset settings).
        config: one entry of :func:`expand`.
    """
    target = check_spec(spec)
    full = _full(spec, target, config)
    key = _static_key(spec, target, config)
    data = dataset2(jax.random.PRNGKey(config["seed"]), _dataset_config(spec, key))
    r = ot.run_online_thesis(data, _hparams(full, config["seed"]), init_every=int(full["init_every"]))
    return {k: float(v) for k, v in _metrics(data, r).items()}


def _group_fn(datas, seed_idx, hps, *, dt: float, init_every: int):
    """vmap of the whole algorithm + metrics over the configuration axis (datas indexed by seed)."""

    def one(i, hp):
        d = jax.tree.map(lambda x: x[i], datas)._replace(dt=dt)
        return _metrics(d, ot.run_dataset(d, hp, init_every))

    return jax.vmap(one)(seed_idx, hps)


_GROUP_JIT = jax.jit(_group_fn, static_argnames=("dt", "init_every"))


def _gather(x: jax.Array) -> np.ndarray:
    if x.is_fully_addressable:
        return np.asarray(x)
    from jax.experimental import multihost_utils

    return np.asarray(multihost_utils.process_allgather(x, tiled=True))


def _run_batch(spec: SweepSpec, target: Target, batch: Batch, devices: Sequence[jax.Device]) -> list[dict]:
    """One vmapped, jitted, sharded call; the rows of the batch's configurations."""
    full0 = _full(spec, target, batch.configs[0])
    config = _dataset_config(spec, batch.key)
    seeds = sorted({c["seed"] for c in batch.configs})
    datas = [dataset2(jax.random.PRNGKey(s), config)._replace(dt=None) for s in seeds]
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *datas)
    n = len(batch.configs)
    pad = -n % len(devices)
    configs = batch.configs + [batch.configs[-1]] * pad
    hps = ot.stack_hparams([_hparams(_full(spec, target, c), c["seed"]) for c in configs])
    seed_idx = jnp.asarray([seeds.index(c["seed"]) for c in configs], dtype=jnp.int32)
    mesh = Mesh(np.asarray(devices), ("configs",))
    along, replicated = NamedSharding(mesh, P("configs")), NamedSharding(mesh, P())
    hps, seed_idx = jax.device_put((hps, seed_idx), along)
    stacked = jax.device_put(stacked, replicated)
    out = _GROUP_JIT(stacked, seed_idx, hps, dt=1.0 / config.fs, init_every=int(full0["init_every"]))
    out = {k: _gather(v)[:n] for k, v in out.items()}
    names = [k for k in (*spec.grid, *spec.random)]
    return [
        {"group": batch.label, **{k: c[k] for k in names}, "seed": c["seed"], **{k: float(v[i]) for k, v in out.items()}}
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
    rows = [r for b in batches for r in done[b.label]]
    names = (*spec.grid, *spec.random)
    return SweepResult(spec, names, rows, {"batches": timing, "total_s": time.perf_counter() - t_start,
                                           "resumed": len(batches) - len(todo), "devices": len(devices)})


# ----------------------------------------------------------------------------- output

_METRIC_COLS = (("test_gyr_mrads", "test gyr [mrad/s]"), ("test_acc_mg", "test acc [mg]"),
                ("val_e_g_last50_mrads", "val e_g last 50 [mrad/s]"), ("val_e_a_last50_mg", "val e_a last 50 [mg]"),
                ("init_test_gyr_mrads", "after init gyr [mrad/s]"), ("init_test_acc_mg", "after init acc [mg]"))


def _seed_means(result: SweepResult) -> list[dict[str, Any]]:
    """Rows averaged over seeds (one per configuration), in first-appearance order."""
    by: dict[tuple, list[dict]] = {}
    for r in result.rows:
        by.setdefault(tuple(r[k] for k in result.names), []).append(r)
    out = []
    for key, rs in by.items():
        m = dict(zip(result.names, key, strict=True))
        for col, _ in _METRIC_COLS:
            m[col] = float(np.mean([r[col] for r in rs]))
        m["n_seeds"] = len(rs)
        out.append(m)
    return out


def _markdown(result: SweepResult) -> str:
    spec = result.spec
    means = _seed_means(result)
    cols = [*result.names, *(c for c, _ in _METRIC_COLS)]
    heads = [*result.names, *(h for _, h in _METRIC_COLS)]

    def fmt(v):
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    lines = [
        f"# Sweep: {spec.target}",
        "",
        f"Written by `jaxcal sweep` ({len(result.rows)} runs: {len(means)} configurations x {len(spec.seeds)} seeds "
        f"{list(spec.seeds)}; Dataset 2 with {spec.dataset.n_train} training sequences of {spec.dataset.n_samples} "
        f"samples; fixed {spec.fixed or 'nothing'}). Errors are test-set means (eq. 3.8) averaged over the seeds; "
        f"{result.timing.get('total_s', 0):.1f} s on {result.timing.get('devices', 1)} device(s).",
        "",
    ]
    if means:
        bg = min(means, key=lambda m: m["test_gyr_mrads"])
        ba = min(means, key=lambda m: m["test_acc_mg"])
        show = lambda m: ", ".join(f"{k} = {fmt(m[k])}" for k in result.names) or "the only configuration"  # noqa: E731
        lines += [f"Lowest gyroscope error: {bg['test_gyr_mrads']:.2f} mrad/s ({show(bg)}; accelerometer "
                  f"{bg['test_acc_mg']:.2f} mg). Lowest accelerometer error: {ba['test_acc_mg']:.2f} mg ({show(ba)}).", ""]
    lines += ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    lines += ["| " + " | ".join(fmt(m[c]) for c in cols) + " |" for m in means]
    lines += ["", "Per seed: `sweep.json` (`rows`).", ""]
    return "\n".join(lines)


def _heatmap_axes(result: SweepResult) -> tuple[str, str] | None:
    if result.spec.heatmap:
        return tuple(result.spec.heatmap)
    return tuple(result.names[:2]) if len(result.names) >= 2 else None


def _write_heatmap(path: Path, result: SweepResult, axes: tuple[str, str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xa, ya = axes
    xs = sorted({r[xa] for r in result.rows})
    ys = sorted({r[ya] for r in result.rows})
    fig, panes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, (col, head) in zip(panes, _METRIC_COLS[:2], strict=True):
        grid = np.full((len(ys), len(xs)), np.nan)
        for j, y in enumerate(ys):
            for i, x in enumerate(xs):
                v = [r[col] for r in result.rows if r[xa] == x and r[ya] == y]
                grid[j, i] = np.mean(v) if v else np.nan
        im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
        ax.set_xticks(range(len(xs)), [f"{x:.3g}" for x in xs], rotation=45)
        ax.set_yticks(range(len(ys)), [f"{y:.3g}" for y in ys])
        ax.set_xlabel(xa)
        ax.set_ylabel(ya)
        ax.set_title(f"{head}, mean over seeds and other axes")
        for j in range(len(ys)):
            for i in range(len(xs)):
                if np.isfinite(grid[j, i]):
                    ax.text(i, j, f"{grid[j, i]:.3g}", ha="center", va="center", color="w", fontsize=8)
        fig.colorbar(im, ax=ax)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def write_sweep(out_dir: str | os.PathLike, result: SweepResult) -> list[Path]:
    """Write ``sweep.json``, ``sweep.md`` and (two swept names or more) ``sweep_heatmap.png``, each atomically.

    Args:
        out_dir: the directory (created if needed).
        result: from :func:`run_sweep`.

    Returns:
        The paths written.
    """
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    _write_json(d / "sweep.json", {"spec": spec_to_dict(result.spec), "names": list(result.names),
                                   "rows": result.rows, "timing": result.timing})
    with atomic_output(d / "sweep.md") as tmp:
        tmp.write_text(_markdown(result))
    written = [d / "sweep.json", d / "sweep.md"]
    axes = _heatmap_axes(result)
    if axes is not None:
        _write_heatmap(d / "sweep_heatmap.png", result, axes)
        written.append(d / "sweep_heatmap.png")
    return written
