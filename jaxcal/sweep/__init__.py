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

One module per step, each importing only those above it:

* :mod:`~jaxcal.sweep.base`: the types (:class:`SweepSpec`, :class:`Target`, :class:`Prepared`)
  and how a configuration's fields resolve (defaults < fixed < swept; the group key);
* :mod:`~jaxcal.sweep.targets`: :data:`TARGETS`, one module per target (``online-thesis``,
  ``offline-nn``), each bringing its batch runner, unvmapped reference, hyperparameters and report
  columns;
* :mod:`~jaxcal.sweep.spec`: :func:`check_spec` (the only check; a run checks once: the entry points
  take a :class:`CheckedSpec` and do not check it again), the JSON form (:func:`spec_from_dict`,
  :func:`spec_to_dict`, :func:`load_sweep_spec`, :func:`read_sweep_spec`);
* :mod:`~jaxcal.sweep.plan`: :func:`expand`, :func:`plan`, :class:`Batch`;
* :mod:`~jaxcal.sweep.run`: :func:`run_sweep` (sharding over a device ``Mesh``, checkpoint and
  resume), :func:`run_one` (the reference a sweep's rows match);
* :mod:`~jaxcal.sweep.report`: :func:`write_sweep` (``sweep.json`` / ``sweep.md`` / heatmap),
  :func:`failed_runs`.

I/O happens only in :func:`load_sweep_spec`, :func:`write_sweep` and in :func:`run_sweep` when it
is given ``out_dir`` (the checkpoint); progress lines go through the ``log`` callable (default: none).
"""

from __future__ import annotations

from jaxcal.sweep.base import Prepared, SweepSpec, Target
from jaxcal.sweep.plan import Batch, expand, plan
from jaxcal.sweep.report import failed_runs, write_sweep
from jaxcal.sweep.run import CHECKPOINT, SweepResult, run_one, run_sweep
from jaxcal.sweep.spec import (
    MAX_RUNS,
    CheckedSpec,
    check_spec,
    checked,
    load_sweep_spec,
    n_runs,
    read_sweep_spec,
    spec_from_dict,
    spec_to_dict,
)
from jaxcal.sweep.targets import TARGETS
from jaxcal.sweep.targets.offline_nn import OFFLINE_DATASET_KEY, offline_seed_keys
from jaxcal.sweep.targets.online_thesis import weights_key

__all__ = [
    "CHECKPOINT",
    "MAX_RUNS",
    "OFFLINE_DATASET_KEY",
    "TARGETS",
    "Batch",
    "CheckedSpec",
    "Prepared",
    "SweepResult",
    "SweepSpec",
    "Target",
    "check_spec",
    "checked",
    "expand",
    "failed_runs",
    "load_sweep_spec",
    "n_runs",
    "offline_seed_keys",
    "plan",
    "read_sweep_spec",
    "run_one",
    "run_sweep",
    "spec_from_dict",
    "spec_to_dict",
    "weights_key",
    "write_sweep",
]
