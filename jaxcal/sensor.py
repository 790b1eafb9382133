"""Linear sensor models: diagonal (thesis eq. 2.2 / 4.6) and full affine (eq. 2.3 / 3.1).

Both are written in the *forward* (physical) direction used by the thesis's simulation
(eq. 1.2, 4.6) and by the conventions' discrepancy baseline::

    y = S x + b        (x: true quantity in g or rad/s, y: sensor output in LSB)

and calibration applies the inverse (eq. 3.5) ``x = S^{-1} (y - b)``. For the diagonal model
``S = diag(s)``. Spec conversion (eq. 4.8) is the diagonal inverse with datasheet values.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float


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


def diag_forward(p: Diag, x: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Sensor output of the diagonal model (eq. 4.6, before rounding)."""
    return p.s * x + p.b


def diag_inverse(p: Diag, y: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Calibrate with the diagonal model: ``x = (y - b) / s`` (eq. 4.8 with spec values)."""
    return (y - p.b) / p.s


def affine_forward(p: Affine, x: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Sensor output of the affine model ``y = S x + b`` (eq. 3.1)."""
    return x @ p.S.T + p.b


def affine_inverse(p: Affine, y: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Calibrate with the affine model: ``x = S^{-1} (y - b)`` (eq. 3.5)."""
    s_b = jnp.broadcast_to(p.S, y.shape[:-1] + (3, 3))
    return jnp.linalg.solve(s_b, (y - p.b)[..., None])[..., 0]


def affine_from_diag(p: Diag) -> Affine:
    """The affine model equal to a diagonal one."""
    return Affine(S=jnp.diag(p.s), b=p.b)


def spec_diag(lsb_per_unit: float | Float[Array, "3"], bias_lsb: float | Float[Array, "3"] = 0.0) -> Diag:
    """Datasheet ("spec") model: nominal scale (LSB per g or per rad/s) and bias (LSB)."""
    s = jnp.broadcast_to(jnp.asarray(lsb_per_unit, dtype=jnp.float32), (3,))
    b = jnp.broadcast_to(jnp.asarray(bias_lsb, dtype=jnp.float32), (3,))
    return Diag(s=s, b=b)


def spec_convert(y: Float[Array, "... 3"], spec: Diag) -> Float[Array, "... 3"]:
    """Spec conversion of raw counts to physical units, thesis eq. 4.8."""
    return diag_inverse(spec, y)
