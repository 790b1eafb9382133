"""Running a sweep: one vmapped, jitted, sharded call per batch, with checkpoint and resume.

**Sharding.** The stacked configuration axis is laid on a ``jax.sharding.Mesh`` over the devices
(default: all local devices) with ``NamedSharding(mesh, P("configs"))``; the axis is padded to a
multiple of the device count (repeating the last configuration) and the padding dropped after.
The data (one copy per seed) are replicated. The same call therefore uses every GPU of a node, or
the ``--xla_force_host_platform_device_count=N`` CPU devices of a test. On a multi-host cluster,
call ``jax.distributed.initialize()`` in every process first (same spec everywhere) and pass
``devices=jax.devices()`` (the global devices): every process builds the same inputs, each device
computes its shard, and the results are gathered with
``jax.experimental.multihost_utils.process_allgather``; let one process (``jax.process_index() ==
0``) call :func:`jaxcal.sweep.write_sweep`.

**Checkpoint and resume.** With ``out_dir``, :func:`run_sweep` rewrites ``out_dir/checkpoint.json``
(atomically: temporary file + ``os.replace``) after each batch with every finished batch's rows;
``resume=True`` skips the batches already there. Each batch is deterministic and keeps its size, so
a killed run resumed gives exactly the rows of an uninterrupted one.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from jaxcal.recording import atomic_output
from jaxcal.sweep.base import SweepSpec, Target, scalar
from jaxcal.sweep.plan import Batch, batches, configurations
from jaxcal.sweep.spec import CheckedSpec, checked, spec_to_dict

__all__ = ["CHECKPOINT", "SweepResult", "run_one", "run_sweep", "write_json"]

CHECKPOINT = "checkpoint.json"


class SweepResult(NamedTuple):
    """Outcome of :func:`run_sweep`.

    Attributes:
        spec: the sweep.
        names: the swept names (grid, then random), the table's configuration columns.
        rows: one dict per configuration and seed: ``group``, the swept names, ``seed`` and the
            target's metrics (see each target's module).
        timing: seconds per batch (``batches``) and in all (``total_s``); not part of the result
            proper (a resumed run differs only here).
    """

    spec: SweepSpec
    names: tuple[str, ...]
    rows: list[dict[str, Any]]
    timing: dict[str, Any]


def run_one(spec: SweepSpec | CheckedSpec, config: dict[str, Any]) -> dict[str, Any]:
    """One configuration on its own (no vmap, no sharding): the reference :func:`run_sweep` matches.

    Args:
        spec: the sweep (defaults, fixed values and dataset settings); a plain spec is checked.
        config: one entry of :func:`~jaxcal.sweep.expand`.
    """
    spec, target = checked(spec)
    return target.run_one(spec, config)


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
        {"group": batch.label, **{k: c[k] for k in names}, "seed": c["seed"], **{k: scalar(v[i]) for k, v in out.items()}}
        for i, c in enumerate(batch.configs)
    ]


def _spec_hash(spec: SweepSpec) -> str:
    return hashlib.sha256(json.dumps(spec_to_dict(spec), sort_keys=True).encode()).hexdigest()[:16]


def write_json(path: Path, obj: Any) -> None:
    """Write ``obj`` as indented JSON, atomically (the checkpoint, ``sweep.json``)."""
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
    spec: SweepSpec | CheckedSpec,
    *,
    out_dir: str | os.PathLike | None = None,
    resume: bool = False,
    devices: Sequence[jax.Device] | None = None,
    log: Callable[[str], None] | None = None,
) -> SweepResult:
    """Run a sweep: one vmapped, jitted call per batch, sharded over ``devices``.

    Args:
        spec: the sweep (a plain spec is checked first, ``ValueError`` if malformed; a
            :class:`~jaxcal.sweep.spec.CheckedSpec` is not checked again).
        out_dir: where ``checkpoint.json`` is rewritten after each batch (``None``: no checkpoint).
        resume: skip the batches already in ``out_dir``'s checkpoint (it must be of the same spec).
        devices: the devices of the configuration axis' mesh (default ``jax.local_devices()``;
            multi-host: ``jax.devices()`` after ``jax.distributed.initialize()``).
        log: called with one progress line (ETA) per batch; ``None``: silent.

    Returns:
        :class:`SweepResult` with rows in :func:`~jaxcal.sweep.expand`'s order.
    """
    spec, target = checked(spec)  # the one check of this run (none for a CheckedSpec)
    planned = batches(spec, target)
    devices = list(jax.local_devices() if devices is None else devices)
    ck_path = None if out_dir is None else Path(out_dir) / CHECKPOINT
    if resume and ck_path is None:
        raise ValueError("run_sweep: resume needs out_dir")
    done = _load_checkpoint(ck_path, spec) if resume else {}
    if ck_path is not None:
        ck_path.parent.mkdir(parents=True, exist_ok=True)
    todo = [b for b in planned if b.label not in done]
    timing: dict[str, float] = {}
    t_start = time.perf_counter()
    for k, b in enumerate(todo):
        t0 = time.perf_counter()
        done[b.label] = _run_batch(spec, target, b, devices)
        timing[b.label] = time.perf_counter() - t0
        if ck_path is not None:
            write_json(ck_path, {"spec_hash": _spec_hash(spec), "batches": done})
        if log is not None:
            elapsed = time.perf_counter() - t_start
            eta = elapsed / (k + 1) * (len(todo) - k - 1)
            log(f"sweep: batch {len(planned) - len(todo) + k + 1}/{len(planned)} ({b.label}, {len(b.configs)} "
                f"configurations on {len(devices)} device(s)) in {timing[b.label]:.1f} s; ETA {eta:.0f} s")
    names = (*spec.grid, *spec.random)
    order: dict[tuple, int] = {}
    for i, c in enumerate(configurations(spec, target)):
        order.setdefault(tuple(c[k] for k in (*names, "seed")), i)
    rows = sorted((r for b in planned for r in done[b.label]), key=lambda r: order[tuple(r[k] for k in (*names, "seed"))])
    return SweepResult(spec, names, rows, {"batches": timing, "total_s": time.perf_counter() - t_start,
                                           "resumed": len(planned) - len(todo), "devices": len(devices)})
