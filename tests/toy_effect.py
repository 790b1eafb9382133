"""A toy effect: the whole of what a new vocabulary effect needs (see ``test_diagnose_vocabulary.py``).

A cubic scale term of the gyroscope, ``x + k3 * x**3`` per axis (``k3`` in 1/(rad/s)^2), placed in
the forward chain after the quadratic scale nonlinearity (``stage`` 2.5). Its record holds the
forward step (JAX), the inverse (numpy, Newton's method), units, the plausible sizes and the motion
that excites it. Register it with one line, ``vocabulary.register(toy_effect.EFFECT)``: selection,
intervals, the report and the ``diagnosed`` model's ``apply`` pick it up.
"""

from __future__ import annotations

import numpy as np

from jaxcal.diagnose.vocabulary import Effect, InverseContext

__all__ = ["EFFECT"]


def _forward(k3, x, inp):
    return x + k3 * x * x * x


def _inverse(k3, x2: np.ndarray, ctx: InverseContext) -> np.ndarray:
    """The root of ``x + k3 x**3 = x2`` per axis near ``x2`` (Newton, from ``x2``; monotonic for
    ``k3 >= 0`` and, for plausible ``k3 < 0``, well inside the fold)."""
    k3 = np.asarray(k3, np.float64)
    x = np.array(x2, np.float64, copy=True)
    for _ in range(30):
        x = x - (x + k3 * x**3 - x2) / (1.0 + 3.0 * k3 * x**2)
    return x


EFFECT = Effect(
    "toy_cubic", "k3", 3, (3,), ("gyr",), {"gyr": "1/(rad/s)^2"}, {"gyr": 0.01}, {"gyr": 0.05},
    "large rates of both signs on every axis", 2.5, _forward, _inverse,
)
