"""Sweep targets as plug-ins: :data:`TARGETS` (name -> :class:`~jaxcal.sweep.base.Target`), filled below.

Built in (one module each):

* ``online-thesis`` (:mod:`~jaxcal.sweep.targets.online_thesis`): chapter 4 on simulated Dataset 2.
* ``offline-nn`` (:mod:`~jaxcal.sweep.targets.offline_nn`): the chapter-3 NN and the linear model
  on Dataset 1.

Adding a target: write a module whose ``TARGET = Target(...)`` brings its batch runner
(``prepare``), its unvmapped reference (``run_one``), its hyperparameters (traced / static,
defaults, ranges) and its report columns, then add one line ``register(module.TARGET)`` below (or
call :func:`register` from your own code). Spec checking, grouping, sharding, checkpoints and the
report are shared.
"""

from __future__ import annotations

from jaxcal.sweep.base import Target
from jaxcal.sweep.targets import offline_nn, online_thesis

__all__ = ["TARGETS", "register"]

TARGETS: dict[str, Target] = {}


def register(target: Target) -> None:
    """Add a target to :data:`TARGETS` under its name (a name already there is refused).

    Args:
        target: the target.
    """
    if target.name in TARGETS:
        raise ValueError(f"sweep target {target.name!r} is already registered")
    TARGETS[target.name] = target


register(online_thesis.TARGET)
register(offline_nn.TARGET)
