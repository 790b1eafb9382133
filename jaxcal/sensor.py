"""Linear sensor models: diagonal (thesis eq. 2.2 / 4.6) and full affine (eq. 2.3 / 3.1).

Both are written in the *forward* (physical) direction used by the thesis's simulation
(eq. 1.2, 4.6) and by the conventions' discrepancy baseline::

    y = S x + b        (x: true quantity in g or rad/s, y: sensor output in LSB)

and calibration applies the inverse (eq. 3.5) ``x = S^{-1} (y - b)``. For the diagonal model
``S = diag(s)``. Spec conversion (eq. 4.8) is the diagonal inverse with datasheet values.

:class:`LinearCal` is the one interchange type for a linear calibration between modules: the
*applied* form ``x = A (y - b)`` (``A = S^{-1}``). Every method, scorer, model file and peer adapter
passes calibrations as ``LinearCal``; ``from_forward`` / ``to_forward`` / ``from_diag`` are the only
converters.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Float

from jaxcal.arrays import Array

__all__ = [
    "Diag",
    "Affine",
    "LinearCal",
    "diag_forward",
    "diag_inverse",
    "affine_forward",
    "affine_inverse",
    "affine_from_diag",
    "spec_diag",
    "spec_convert",
]


class Diag(NamedTuple):
    """Per-axis scale and bias: ``y = s * x + b`` (eq. 4.6). ``s`` in LSB/unit, ``b`` in LSB."""

    s: Float[Array, "3"]
    b: Float[Array, "3"]


class Affine(NamedTuple):
    """Scale, non-orthogonality, misalignment and bias: ``y = S x + b`` (eq. 2.3, 3.1).

    ``S`` (3, 3) holds the scale factors on its diagonal and the cross-axis terms
    ``m_ij`` off it; ``b`` (3,) is the bias. The 12 parameters of the thesis's linear model.
    """

    S: Float[Array, "3 3"]
    b: Float[Array, "3"]


class LinearCal(NamedTuple):
    """A linear calibration in the applied direction: ``x = A (y - b)`` (eq. 3.5 with ``A = S^{-1}``).

    Args:
        A: (3, 3) matrix, physical unit per sensor unit (e.g. g/LSB); the inverse of the forward
            model's ``S``.
        b: (3,) bias in the sensor's units (e.g. LSB), subtracted before ``A``.
    """

    A: Float[Array, "3 3"]
    b: Float[Array, "3"]

    @classmethod
    def from_forward(cls, p: Affine) -> "LinearCal":
        """The calibration that undoes the forward model ``y = S x + b``: ``A = S^{-1}``."""
        return cls(A=jnp.linalg.inv(jnp.asarray(p.S)), b=jnp.asarray(p.b))

    @classmethod
    def from_diag(cls, p: Diag) -> "LinearCal":
        """The calibration that undoes the diagonal model ``y = s x + b``: ``A = diag(1 / s)``."""
        return cls(A=jnp.diag(1.0 / jnp.asarray(p.s)), b=jnp.asarray(p.b))

    def to_forward(self) -> Affine:
        """The forward model ``y = S x + b`` with ``S = A^{-1}`` that this calibration inverts."""
        return Affine(S=jnp.linalg.inv(self.A), b=self.b)

    def apply(self, y: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
        """Calibrated values ``A (y - b)`` of sensor outputs ``y`` (rows)."""
        return (y - self.b) @ self.A.T


def diag_forward(p: Diag, x: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Sensor output of the diagonal model (eq. 4.6, before rounding).

    Args:
        p: diagonal model (``s`` LSB per unit, ``b`` LSB).
        x: (..., 3) true quantity (g or rad/s).
    """
    return p.s * x + p.b


def diag_inverse(p: Diag, y: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Calibrate with the diagonal model: ``x = (y - b) / s`` (eq. 4.8 with spec values).

    Args:
        p: diagonal model (``s`` LSB per unit, ``b`` LSB).
        y: (..., 3) sensor outputs (LSB).
    """
    return (y - p.b) / p.s


def affine_forward(p: Affine, x: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Sensor output of the affine model ``y = S x + b`` (eq. 3.1).

    Args:
        p: affine model (``S`` LSB per unit, ``b`` LSB).
        x: (..., 3) true quantity (g or rad/s).
    """
    return x @ p.S.T + p.b


def affine_inverse(p: Affine, y: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Calibrate with the affine model: ``x = S^{-1} (y - b)`` (eq. 3.5).

    Args:
        p: affine model (``S`` LSB per unit, ``b`` LSB).
        y: (..., 3) sensor outputs (LSB).
    """
    s_b = jnp.broadcast_to(p.S, y.shape[:-1] + (3, 3))
    return jnp.linalg.solve(s_b, (y - p.b)[..., None])[..., 0]


def affine_from_diag(p: Diag) -> Affine:
    """The affine model equal to a diagonal one."""
    return Affine(S=jnp.diag(p.s), b=p.b)


def spec_diag(lsb_per_unit: float | Float[Array, ""] | Float[Array, "3"],
              bias_lsb: float | Float[Array, ""] | Float[Array, "3"] = 0.0) -> Diag:
    """Datasheet ("spec") model: nominal scale (LSB per g or per rad/s) and bias (LSB).

    Args:
        lsb_per_unit: nominal sensitivity, scalar or per axis (LSB per g or per rad/s).
        bias_lsb: nominal bias, scalar or per axis (LSB).
    """
    s = jnp.broadcast_to(jnp.asarray(lsb_per_unit, dtype=jnp.float32), (3,))
    b = jnp.broadcast_to(jnp.asarray(bias_lsb, dtype=jnp.float32), (3,))
    return Diag(s=s, b=b)


def spec_convert(y: Float[Array, "... 3"], spec: Diag) -> Float[Array, "... 3"]:
    """Spec conversion of raw counts to physical units, thesis eq. 4.8.

    Args:
        y: (..., 3) raw counts (LSB).
        spec: datasheet model (:func:`spec_diag`).
    """
    return diag_inverse(spec, y)
