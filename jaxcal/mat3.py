"""Products and the inverse of 3x3 blocks written as elementwise arithmetic.

``m @ v`` with a contracted dimension of 3 is a dot or a reduction to XLA. On the CPU each one is a
kernel of its own (several per step of a compiled loop), and under ``jax.jacfwd``'s batch of tangents
XLA's CPU backend runs some of them far below its elementwise speed. Written as three multiply-adds
they fuse with their neighbours into one loop: the ``online`` filter's reading model and calibrations
written so ran 1.5x (``diag``) and 1.7x (``affine``) faster (``benchmarks/online_engine.py``).
The sums are taken in the order ``x_0 + x_1 + x_2``, which is not bit-identical to a dot (XLA may
fuse a dot's products and sums differently): use these where speed under ``jacfwd``/``vmap``
matters and last-bit agreement with a ``@`` elsewhere does not (:mod:`jaxcal.online`'s filter).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Float

from jaxcal.arrays import Array

__all__ = ["matvec3", "matmul3", "transpose3", "inv3"]


def matvec3(m: Float[Array, "... 3 3"], v: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """``m @ v`` over the last axes (both broadcast)."""
    return m[..., 0] * v[..., None, 0] + m[..., 1] * v[..., None, 1] + m[..., 2] * v[..., None, 2]


def matmul3(a: Float[Array, "... 3 3"], b: Float[Array, "... 3 3"]) -> Float[Array, "... 3 3"]:
    """``a @ b`` over the last two axes (both broadcast)."""
    return (a[..., :, 0, None] * b[..., None, 0, :] + a[..., :, 1, None] * b[..., None, 1, :]
            + a[..., :, 2, None] * b[..., None, 2, :])


def transpose3(m: Float[Array, "... 3 3"]) -> Float[Array, "... 3 3"]:
    """``m^T`` of each block."""
    return jnp.swapaxes(m, -1, -2)


def inv3(k: Float[Array, "... 3 3"]) -> Float[Array, "... 3 3"]:
    """Inverse as adjugate / determinant (rows of ``k`` crossed). No pivoting: for well-conditioned
    blocks (a calibration near the identity, a rotation), where it agrees with ``jnp.linalg.inv`` to
    a few ulps; singular ``k`` gives inf/nan, not an error."""
    r0, r1, r2 = k[..., 0, :], k[..., 1, :], k[..., 2, :]
    adj = jnp.stack([jnp.cross(r1, r2), jnp.cross(r2, r0), jnp.cross(r0, r1)], axis=-1)
    det = jnp.sum(r0 * adj[..., :, 0], axis=-1)
    return adj / det[..., None, None]
