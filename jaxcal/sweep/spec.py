"""A sweep spec: checked (:func:`check_spec`), read from and written to its JSON form.

:func:`check_spec` is the one place a spec is checked. :func:`checked` wraps its result as a
:class:`CheckedSpec`, the proof that a spec was checked: the public entry points
(:func:`jaxcal.sweep.expand`, :func:`jaxcal.sweep.plan`, :func:`jaxcal.sweep.run_one`,
:func:`jaxcal.sweep.run_sweep`) take a plain :class:`~jaxcal.sweep.base.SweepSpec`, which they
check, or a :class:`CheckedSpec`, which they do not check again. :func:`read_sweep_spec` reads a
file into one, so a CLI run checks its spec once.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, NamedTuple

from jaxcal.sweep.base import DATASET_PREFIX, SweepSpec, Target, dataset_settings
from jaxcal.sweep.targets import TARGETS

__all__ = [
    "MAX_RUNS",
    "CheckedSpec",
    "check_spec",
    "checked",
    "load_sweep_spec",
    "n_runs",
    "read_sweep_spec",
    "spec_from_dict",
    "spec_to_dict",
]


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
    if name.startswith(DATASET_PREFIX):
        default = _dataset_defaults(target)[name[len(DATASET_PREFIX):]]
        if isinstance(default, bool) and isinstance(v, bool):
            return
        if not _is_number(v) or (isinstance(default, int) and (int(v) != v or v < 1)):
            _fail(f"{where}: {name} = {v!r} is not a valid {type(default).__name__}")
        field = name[len(DATASET_PREFIX):]
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
    if name.startswith(DATASET_PREFIX):
        if target.dataset is None:
            _fail(f"{where}: target {target.name} has no dataset settings ({name!r})")
        if name[len(DATASET_PREFIX):] not in target.dataset._fields:
            _fail(f"{where}: unknown dataset field {name!r}; known: {', '.join(target.dataset._fields)}")
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
        if name.startswith(DATASET_PREFIX) or name in t.static:
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
        for f, v in dataset_settings(spec, t)._asdict().items():
            _check_value(t, DATASET_PREFIX + f, v, "sweep spec dataset")
    return t


class CheckedSpec(NamedTuple):
    """A spec and the :class:`~jaxcal.sweep.base.Target` :func:`check_spec` returned for it.

    Attributes:
        spec: the sweep.
        target: its target.
    """

    spec: SweepSpec
    target: Target


def checked(spec: SweepSpec | CheckedSpec) -> CheckedSpec:
    """``spec`` checked once: a :class:`CheckedSpec` is returned as it is, a plain spec is checked
    (:func:`check_spec`; one-line ``ValueError`` if malformed)."""
    return spec if isinstance(spec, CheckedSpec) else CheckedSpec(spec, check_spec(spec))


def _parse(d: dict[str, Any]) -> SweepSpec:
    """The :class:`SweepSpec` of a JSON form (:func:`spec_from_dict`): its structure is refused where
    malformed; its values are left to :func:`check_spec`."""
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
    return spec


def spec_from_dict(d: dict[str, Any]) -> SweepSpec:
    """A :class:`SweepSpec` from its JSON form (see ``docs/sweep_example.json``), checked
    (:func:`check_spec`); one-line ``ValueError``.

    Args:
        d: ``{"target", "grid", "random": {"n", "seed", "params": {name: [lo, hi, scale]}},
            "fixed", "seeds", "dataset": {dataset field: value}, "heatmap", "batch_size"}``; every
            key optional (``target``: ``"online-thesis"``; ``dataset`` must be absent or ``{}`` for
            a target without dataset settings).
    """
    return checked(_parse(d)).spec


def spec_to_dict(spec: SweepSpec) -> dict[str, Any]:
    """The JSON form of a spec (inverse of :func:`spec_from_dict`)."""
    ds = dataset_settings(spec, TARGETS[spec.target]) if spec.target in TARGETS else spec.dataset
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
    """Read a JSON sweep spec, checked (one-line ``ValueError`` naming the file on bad input).

    Args:
        path: the JSON file.
    """
    return read_sweep_spec(path).spec


def read_sweep_spec(path: str | os.PathLike) -> CheckedSpec:
    """:func:`load_sweep_spec` as a :class:`CheckedSpec`, so the run that follows does not check it again.

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
        return checked(_parse(d))
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
