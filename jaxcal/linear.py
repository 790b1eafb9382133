"""The thesis's linear 12-parameter calibration (eq. 3.1-3.5), solved with optimistix.

Given labels ``x_l`` (true specific force, g) and outputs ``y_l`` (LSB), find ``M = [S | b]``
minimising ``sum_l |y_l - S x_l - b|^2``. The problem is linear in ``M``, so one Gauss-Newton
step of :func:`optimistix.least_squares` reaches the optimum; :func:`fit_affine_closed_form`
is the normal-equation solution of eq. 3.3 for comparison.

Note: eq. 3.3 is printed ``M = U A^T (A^T A)^{-1}``; with ``A`` of shape 4 x L the dimensionally
consistent normal equations are ``M = U A^T (A A^T)^{-1}``, which is what is implemented.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.sensor import Affine

__all__ = [
    "affine_residuals",
    "fit_affine",
    "fit_affine_jit",
    "fit_affine_closed_form",
]


def _design(x: Float[Array, "L 3"]) -> Float[Array, "L 4"]:
    """Rows ``[x_l, 1]``: the transpose of the thesis's ``A`` (eq. 3.2)."""
    return jnp.concatenate([x, jnp.ones_like(x[:, :1])], axis=1)


def _split(m: Float[Array, "3 4"]) -> Affine:
    return Affine(S=m[:, :3], b=m[:, 3])


def affine_residuals(m: Float[Array, "3 4"], data: tuple[Array, Array, Array]) -> Float[Array, "L 3"]:
    """Weighted residuals ``sqrt(w_l) (y_l - M [x_l; 1])`` of eq. 3.2.

    Args:
        m: (3, 4) parameters ``M = [S | b]``.
        data: ``(x (L, 3) labels, y (L, 3) outputs, w (L,) weights)``, optimistix's ``args``.
    """
    x, y, w = data
    return jnp.sqrt(w)[:, None] * (y - _design(x) @ m.T)


def fit_affine(
    x: Float[Array, "L 3"],
    y: Float[Array, "L 3"],
    weights: Float[Array, " L"] | None = None,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-10,
) -> Affine:
    """Least-squares fit of ``y = S x + b`` with optimistix (Gauss-Newton; exact in one step).

    Args:
        x: reference (true) input, e.g. ``acc_ref`` in g, at least 4 non-coplanar samples.
        y: sensor output, e.g. ``acc`` in LSB.
        weights: optional non-negative per-sample weights (0 drops a sample; used to vmap over
            subsets of one padded dataset).
        rtol, atol: relative and absolute convergence tolerances of the Gauss-Newton solver.

    Returns:
        The fitted :class:`~jaxcal.sensor.Affine` (``S`` in LSB/unit, ``b`` in LSB).

    Pure and jit/vmap-able over leading dataset axes.
    """
    w = jnp.ones(x.shape[0], dtype=x.dtype) if weights is None else weights
    # Initial guess: the closed-form-free mean model (S = 0, b = mean y); GN solves it exactly.
    m0 = jnp.zeros((3, 4), dtype=x.dtype)
    solver = optx.GaussNewton(rtol=rtol, atol=atol)
    sol = optx.least_squares(affine_residuals, solver, m0, args=(x, y, w), max_steps=8, throw=False)
    return _split(sol.value)


#: :func:`fit_affine` compiled.
fit_affine_jit = jax.jit(fit_affine)


def fit_affine_closed_form(
    x: Float[Array, "L 3"], y: Float[Array, "L 3"], weights: Float[Array, " L"] | None = None
) -> Affine:
    """Normal-equation solution of eq. 3.3, ``M = U W A^T (A W A^T)^{-1}``.

    Args:
        x: (L, 3) reference (true) input, e.g. g.
        y: (L, 3) sensor output, e.g. LSB.
        weights: optional (L,) non-negative per-sample weights; None: all 1.
    """
    a = _design(x)
    w = jnp.ones(x.shape[0], dtype=x.dtype) if weights is None else weights
    aw = a * w[:, None]
    m = jnp.linalg.solve(a.T @ aw, aw.T @ y).T
    return _split(m)
