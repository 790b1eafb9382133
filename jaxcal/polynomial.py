"""Polynomial (cubic) calibration ``x = f(y)`` of a 3-axis sensor (the nonlinear sensor model of thesis
section 2.1.2, which the thesis mentions but never tests).

The raw counts ``y`` (LSB, any scale) are first mapped affinely into about ``[-1, 1]`` per axis
(:func:`jaxcal.normalise.normalise`, with :class:`~jaxcal.normalise.Bounds` from the data or from
the datasheet), so the monomials are of order one and the design matrix is well conditioned. Then
each output axis ``i`` is a full polynomial of total degree ``d`` in the three normalised inputs::

    x_i = sum_q coef[i, q] u_0^a_q u_1^b_q u_2^c_q,      a_q + b_q + c_q <= d

with every cross term: ``C(d + 3, 3)`` monomials per axis (:func:`monomials`), i.e. 4 (affine),
10 (quadratic) or 20 (cubic) per axis and 12, 30 or 60 parameters in all (:func:`n_params`). The
first four monomials are ``1, u_0, u_1, u_2``: ``coef[:, :4]`` is the affine part, ``coef[:, 4:]``
the polynomial terms of degree 2 and 3.

Fit. The model is linear in ``coef``, so it is a weighted linear least-squares problem, solved in
closed form (no iterations; float64 inputs give a float64 solve). The affine part is profiled out:
with ``A`` the weighted affine columns and ``N`` the weighted polynomial columns,

1. project ``A`` out of ``N`` and of the targets (``P = I - A A^+``, :func:`jax.numpy.linalg.lstsq`);
2. solve ``min |P X - P N beta|^2 + ridge * sum(w) |beta|^2`` for the polynomial coefficients
   ``beta`` by an SVD least squares on the ridge-augmented system ``[P N; sqrt(ridge sum w) I]``;
3. ``alpha = A^+ (X - N beta)`` for the affine coefficients.

This is the exact weighted least-squares solution whenever the design determines ``coef``. When it
does not (fewer weighted samples than monomials, e.g. ``l = 18 < 20``, or samples that leave some
combinations free, such as static orientations on a sphere where ``|x|^2 = 1``), ``ridge = 0``
returns the **minimum-norm** solution in the polynomial coefficients: the affine part is still the
best fit given them, and of all ``beta`` that fit the data equally well the one of least Euclidean
norm (in the normalised basis) is returned, never NaN. It is the ``ridge -> 0+`` limit of the ridge
solution. ``ridge > 0`` penalises only the polynomial terms, relative to the weighted mean squared
residual (the objective is ``sum_l w_l |x_l - f(y_l)|^2 / sum_l w_l + ridge |beta|^2``), so the same
``ridge`` means the same thing at every subset size, and ``ridge -> infinity`` gives the affine fit.

Singular values below ``1e3`` machine epsilons of the largest count as zero (:data:`RCOND_EPS`);
the cut-off does not depend on the number of rows, so padded 0-weight rows change nothing
(:func:`cubic_calibrate_subsets` vmaps over 0/1 weight rows of one padded training set).

Static vs traced: ``degree`` is static (it sets the number of monomials: a Python ``int``, close
over it under ``jit``); ``ridge``, the weights and the bounds may be traced.
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.normalise import Bounds, normalise

__all__ = [
    "RCOND_EPS",
    "CubicCal",
    "RIDGES",
    "cubic_calibrate",
    "cubic_calibrate_subsets",
    "data_bounds",
    "degree_of",
    "design",
    "fit_cubic",
    "fit_cubic_validated",
    "monomials",
    "n_monomials",
    "n_params",
]

RCOND_EPS = 1e3
"""Singular values below ``RCOND_EPS * eps(dtype) * s_max`` are treated as zero in every solve
(float64: ``2.2e-13``, float32: ``1.2e-4``)."""


class CubicCal(NamedTuple):
    """A fitted polynomial calibration ``x = coef @ design(normalise(y, bounds))``.

    Args:
        coef: ``(3, Q)`` coefficient of each monomial of :func:`monomials` per output axis, in the
            output unit (e.g. g); ``Q = C(d + 3, 3)`` fixes the degree (:func:`degree_of`).
        bounds: the input normalisation (eq. 3.7 form): raw counts at ``u = -1`` and ``u = +1``.
    """

    coef: Float[Array, "3 Q"]
    bounds: Bounds


def monomials(degree: int) -> tuple[tuple[int, int, int], ...]:
    """Exponents ``(a, b, c)`` of every monomial ``u_0^a u_1^b u_2^c`` of total degree ``<= degree``.

    Graded order: ``1``, then ``u_0, u_1, u_2``, then the degree-2 terms, ... (within a degree,
    lexicographically descending: ``u_0^2, u_0 u_1, u_0 u_2, u_1^2, u_1 u_2, u_2^2``).

    Args:
        degree: total degree, at least 1 (static).
    """
    if degree < 1:
        raise ValueError(f"polynomial degree must be at least 1, got {degree}")
    out = []
    for k in range(degree + 1):
        out += sorted((e for e in itertools.product(range(k + 1), repeat=3) if sum(e) == k), reverse=True)
    return tuple(out)


def n_monomials(degree: int) -> int:
    """``C(degree + 3, 3)``: monomials per output axis (4, 10, 20 for degree 1, 2, 3)."""
    return math.comb(degree + 3, 3)


def n_params(degree: int = 3) -> int:
    """Parameters of the 3-output model: ``3 C(degree + 3, 3)`` (12 affine, 30 quadratic, 60 cubic)."""
    return 3 * n_monomials(degree)


def degree_of(n_terms: int) -> int:
    """The degree whose monomial count is ``n_terms`` (inverse of :func:`n_monomials`).

    Raises:
        ValueError: ``n_terms`` is no monomial count (4, 10, 20, 35, ...).
    """
    d = 1
    while n_monomials(d) < n_terms:
        d += 1
    if n_monomials(d) != n_terms:
        raise ValueError(f"{n_terms} terms is no full polynomial in 3 variables (4, 10, 20, 35, ...)")
    return d


def design(u: Float[Array, "N 3"], degree: int) -> Float[Array, "N Q"]:
    """Design matrix: every monomial of :func:`monomials` evaluated at each row of ``u``.

    Args:
        u: ``(N, 3)`` normalised inputs.
        degree: total degree (static).
    """
    # powers[k][:, i] = u_i^k, built by products (no pow of negative bases)
    powers = [jnp.ones_like(u)]
    for _ in range(degree):
        powers.append(powers[-1] * u)
    return jnp.stack([powers[a][:, 0] * powers[b][:, 1] * powers[c][:, 2] for a, b, c in monomials(degree)], axis=1)


def data_bounds(y: Float[Array, "L 3"], w: Float[Array, " L"] | None = None) -> Bounds:
    """Normalisation bounds from the data: per axis the least and greatest count among the rows of
    positive weight (so ``u`` spans ``[-1, 1]`` on them). An axis without spread (or no row of
    positive weight) gets a span of 1 count, so nothing divides by zero.

    Args:
        y: ``(L, 3)`` raw counts.
        w: optional ``(L,)`` non-negative weights; rows of weight 0 are ignored.
    """
    keep = jnp.ones(y.shape[0], dtype=bool) if w is None else w > 0
    lo = jnp.min(jnp.where(keep[:, None], y, jnp.inf), axis=0)
    hi = jnp.max(jnp.where(keep[:, None], y, -jnp.inf), axis=0)
    lo = jnp.where(jnp.isfinite(lo), lo, 0.0)
    hi = jnp.where(jnp.isfinite(hi) & (hi > lo), hi, lo + 1.0)
    return Bounds(lo=lo, hi=hi)


def _lstsq(a: Float[Array, "R C"], b: Float[Array, "R K"]) -> Float[Array, "C K"]:
    """Minimum-norm least squares ``a^+ b`` (SVD), cut-off :data:`RCOND_EPS` eps, row-count free."""
    return jnp.linalg.lstsq(a, b, rcond=RCOND_EPS * float(jnp.finfo(a.dtype).eps))[0]


def fit_cubic(
    y: Float[Array, "L 3"],
    x: Float[Array, "L 3"],
    w: Float[Array, " L"] | None = None,
    degree: int = 3,
    ridge: float | Float[Array, ""] = 0.0,
    *,
    bounds: Bounds | None = None,
) -> CubicCal:
    """Weighted least-squares fit of the polynomial calibration ``x = f(y)`` (module docstring).

    Args:
        y: ``(L, 3)`` raw sensor output (LSB, any scale).
        x: ``(L, 3)`` reference labels (physical units, e.g. g).
        w: optional ``(L,)`` non-negative weights (0 drops a row; 0/1 rows select subsets of a
            padded set). ``None``: all 1.
        degree: total polynomial degree (static; 3: 20 monomials per axis, 60 parameters).
        ridge: non-negative penalty on the squared polynomial (degree >= 2) coefficients, relative
            to the weighted mean squared residual; 0: exact least squares, minimum-norm when the
            data do not determine every coefficient (e.g. fewer samples than monomials).
        bounds: input normalisation; ``None``: :func:`data_bounds` of the weighted rows.

    Returns:
        The fitted :class:`CubicCal`, in the dtype of the inputs (pass float64 under
        ``jax.enable_x64`` for a float64 solve).

    Pure and jit/vmap-able (``degree`` static).
    """
    wt = jnp.ones(y.shape[0], dtype=y.dtype) if w is None else jnp.asarray(w, y.dtype)
    bnd = data_bounds(y, wt) if bounds is None else bounds
    sw = jnp.sqrt(wt)[:, None]
    phi = design(normalise(y, bnd), degree) * sw
    xs = x * sw
    a, nl = phi[:, :4], phi[:, 4:]
    if nl.shape[1] == 0:
        return CubicCal(coef=_lstsq(a, xs).T, bounds=bnd)
    nl_perp = nl - a @ _lstsq(a, nl)
    x_perp = xs - a @ _lstsq(a, xs)
    k = nl.shape[1]
    scale = jnp.sqrt(jnp.asarray(ridge, y.dtype) * jnp.sum(wt))
    aug = jnp.concatenate([nl_perp, scale * jnp.eye(k, dtype=y.dtype)], axis=0)
    beta = _lstsq(aug, jnp.concatenate([x_perp, jnp.zeros((k, 3), y.dtype)], axis=0))
    alpha = _lstsq(a, xs - nl @ beta)
    return CubicCal(coef=jnp.concatenate([alpha, beta], axis=0).T, bounds=bnd)


def cubic_calibrate(model: CubicCal, y: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
    """Calibrated output ``x = f(y)`` of a fitted :class:`CubicCal` (degree read from ``coef``'s shape).

    Args:
        model: the fitted calibration.
        y: ``(N, 3)`` raw counts, in the unit the model was fitted on.
    """
    degree = degree_of(model.coef.shape[1])
    return design(normalise(y, model.bounds), degree) @ model.coef.T


RIDGES = (0.0, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
"""Candidate ridge strengths of :func:`fit_cubic_validated` (relative: see :func:`fit_cubic`)."""


def fit_cubic_validated(
    y: Float[Array, "L 3"],
    x: Float[Array, "L 3"],
    w: Float[Array, " L"] | None,
    val: tuple[Float[Array, "V 3"], Float[Array, "V 3"]],
    degree: int = 3,
    ridges: tuple[float, ...] = RIDGES,
    *,
    bounds: Bounds | None = None,
) -> tuple[CubicCal, Float[Array, ""]]:
    """:func:`fit_cubic` with the ridge strength picked from ``ridges`` by the validation MSE.

    The validation rows play the part they play for the NN (early stopping): with few training
    rows (``l = 18`` < 20 monomials) ``ridge = 0`` interpolates the noise, and a ridge keeps the
    polynomial terms small.

    Args:
        y: ``(L, 3)`` raw sensor output.
        x: ``(L, 3)`` reference labels.
        w: optional ``(L,)`` row weights.
        val: ``(y, x)`` validation rows that pick the ridge.
        degree: total degree (static).
        ridges: candidate strengths (static).
        bounds: input normalisation; ``None``: :func:`data_bounds` of the weighted rows.

    Returns:
        The fit at the chosen strength, and that strength.
    """
    fits = [fit_cubic(y, x, w, degree, r, bounds=bounds) for r in ridges]
    mse = jnp.stack([jnp.mean((cubic_calibrate(f, val[0]) - val[1]) ** 2) for f in fits])
    best = jnp.argmin(jnp.where(jnp.isfinite(mse), mse, jnp.inf))
    pick = jax.tree.map(lambda *leaves: jnp.stack(leaves)[best], *fits)
    return pick, jnp.asarray(ridges)[best]


def cubic_calibrate_subsets(
    y_tr: Float[Array, "L 3"],
    x_tr: Float[Array, "L 3"],
    weights: Float[Array, "K L"],
    y_te: Float[Array, "T 3"],
    *,
    degree: int = 3,
    ridge: float | Float[Array, ""] = 0.0,
    bounds: Bounds | None = None,
    val: tuple[Float[Array, "V 3"], Float[Array, "V 3"]] | None = None,
) -> Float[Array, "K T 3"]:
    """Calibrated test outputs of the polynomial model fitted on each subset (the polynomial
    counterpart of :func:`jaxcal.offline.linear_calibrate_subsets`).

    Args:
        y_tr, x_tr: padded training counts (LSB) and labels (g).
        weights: ``(K, L)`` 0/1 subset rows.
        y_te: test counts (LSB).
        degree: total degree (static).
        ridge: penalty on the polynomial terms (see :func:`fit_cubic`); 0: minimum-norm when a
            subset is smaller than the number of monomials.
        bounds: input normalisation; ``None``: each subset's own data range.
        val: validation ``(y, x)``: if given, the ridge is picked per subset from :data:`RIDGES`
            (:func:`fit_cubic_validated`) and ``ridge`` is ignored.
    """

    def one(w):
        if val is not None:
            return cubic_calibrate(fit_cubic_validated(y_tr, x_tr, w, val, degree, bounds=bounds)[0], y_te)
        return cubic_calibrate(fit_cubic(y_tr, x_tr, w, degree, ridge, bounds=bounds), y_te)

    return jax.vmap(one)(weights)
