"""Multipos accelerometer: ``f = A (y - b)`` with ``|f| = 1 g`` in every static pose.

:func:`fit_acc` (9 or 12 parameters, optimistix Levenberg-Marquardt from an ellipsoid start,
optional :class:`DatasheetPrior`), :func:`fit_acc_determined` (only the combinations the poses
determine move from the recording's units) and the per-pose error :func:`acc_norm_errors`.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from jaxcal.multipos.data import InverseAffine
from jaxcal.multipos.observe import OBSERVABLE_TOL


class DatasheetPrior(NamedTuple):
    """Optional Gaussian prior (MAP) on the scales and cross-axis terms, from a datasheet.

    With a prior the fits weigh the data residuals by their std (``acc_sigma``: one pose's
    ``|f| - 1`` in g; ``gyr_sigma``: one component of a carried-gravity or known-rotation residual,
    rad) and add rows ``(M_ii - 1) / scale_sigma`` and ``M_ij / cross_sigma`` (i != j) for
    ``M = A / unit_per_lsb`` (relative to the nominal sensitivity). ``None`` for a sensor's
    ``*_unit_per_lsb`` leaves that sensor without prior. Off by default everywhere: multipos needs
    no datasheet; the prior only fills directions the poses do not observe.
    """

    acc_unit_per_lsb: float | None = None
    gyr_unit_per_lsb: float | None = None
    scale_sigma: float = 0.03
    cross_sigma: float = 0.02
    acc_sigma: float = 1e-3
    gyr_sigma: float = 0.01


#: InvenSense MPU-6050 (PS-MPU-6000A rev 3.4) at +-2 g / +-250 deg/s: 16384 LSB/g, 131 LSB/(deg/s),
#: sensitivity tolerance +-3 %, cross-axis sensitivity +-2 % (both sensors).
MPU6050_PRIOR = DatasheetPrior(acc_unit_per_lsb=1.0 / 16384.0, gyr_unit_per_lsb=float(np.pi / 180.0 / 131.0))


def prior_rows(a: Float[Array, "3 3"], unit_per_lsb: Any, prior: DatasheetPrior) -> Float[Array, "9"]:
    """Prior residuals of a calibration matrix ``A`` (unit/LSB): 3 scale rows, 6 cross-axis rows."""
    m = a / unit_per_lsb
    off = m[np.array([0, 0, 1, 1, 2, 2]), np.array([1, 2, 0, 2, 0, 1])]
    return jnp.concatenate([(jnp.diag(m) - 1.0) / prior.scale_sigma, off / prior.cross_sigma])


def _lower(a: Float[Array, "3"]) -> Float[Array, "3 3"]:
    z, o = jnp.zeros_like(a[0]), jnp.ones_like(a[0])
    return jnp.stack([jnp.stack([o, z, z]), jnp.stack([a[0], o, z]), jnp.stack([a[1], a[2], o])])


def _acc_matrix(theta: Float[Array, "P"], model: str) -> tuple[Array, Array]:
    """Normalised-frame ``(A', b')`` from the parameter vector."""
    if model == "9":
        return _lower(theta[:3]) * theta[3:6][None, :], theta[6:9]
    return theta[:9].reshape(3, 3), theta[9:12]


def acc_residuals(theta: Float[Array, "Q"], args: tuple) -> Float[Array, "P+3"]:
    """``sqrt(w_i) (|A'(m_i - b')| - 1)`` per pose (normalised pose means ``m_i``), plus the
    ``A - A^T`` gauge residual of the physical ``A = A' diag(1/s0)`` for the 12-parameter model (zeros for the 9-parameter one).
    With a :class:`DatasheetPrior` (``args[4]``, optional) the pose rows are divided by its
    ``acc_sigma`` and its 9 prior rows on the physical ``A`` are appended. ``args[5]`` (optional,
    default 0): ridge weight on the cross-axis terms of ``A'`` (relative to its diagonal), 6 rows
    ``ridge * A'_ij / A'_jj`` (i != j; the 9-parameter model's three zeros above the diagonal stay 0)."""
    m, w, model, s0 = args[:4]
    prior = args[4] if len(args) > 4 else None
    ridge = args[5] if len(args) > 5 else 0.0
    a, b = _acc_matrix(theta, model)
    f = (m - b) @ a.T
    r = jnp.sqrt(w) * (jnp.linalg.norm(f, axis=-1) - 1.0)
    ap = a * (jnp.mean(s0) / s0)[None, :]  # the physical A, up to one common factor
    gauge = jnp.stack([ap[0, 1] - ap[1, 0], ap[0, 2] - ap[2, 0], ap[1, 2] - ap[2, 1]]) if model == "12" else jnp.zeros(3, m.dtype)
    rel = a / jnp.diag(a)[None, :]
    r = jnp.concatenate([r, ridge * rel[np.array([0, 0, 1, 1, 2, 2]), np.array([1, 2, 0, 2, 0, 1])]])
    if prior is None or prior.acc_unit_per_lsb is None:
        return jnp.concatenate([r, gauge])
    return jnp.concatenate([r / prior.acc_sigma, gauge, prior_rows(a / s0[None, :], prior.acc_unit_per_lsb, prior)])


def ellipsoid_init(m: Float[Array, "P 3"], w: Float[Array, "P"]) -> tuple[Array, Array]:
    """Centre and semi-axes of the axis-aligned ellipsoid through weighted points (least squares
    on ``a x^2 + b y^2 + c z^2 + d x + e y + f z = 1``); per-axis (max + min) / 2 and (max - min) / 2
    where that fit is degenerate."""
    mu = jnp.sum(w[:, None] * m, 0) / jnp.sum(w)
    sd = jnp.sqrt(jnp.sum(w[:, None] * (m - mu) ** 2, 0) / jnp.sum(w)) + 1e-12
    x = (m - mu) / sd
    d = jnp.concatenate([x * x, x], axis=1) * jnp.sqrt(w)[:, None]
    coef, *_ = jnp.linalg.lstsq(d, jnp.sqrt(w), rcond=None)
    q, l = coef[:3], coef[3:]
    ok = jnp.all(q > 0)
    qs = jnp.where(ok, q, 1.0)
    c = -l / (2 * qs)
    rhs = 1.0 + jnp.sum(l * l / (4 * qs))
    r = jnp.sqrt(jnp.maximum(rhs / qs, 1e-24))
    big = jnp.where(w[:, None] > 0, m, -jnp.inf).max(0)
    small = jnp.where(w[:, None] > 0, m, jnp.inf).min(0)
    c_mm, r_mm = 0.5 * (big + small), jnp.maximum(0.5 * (big - small), 1e-12)
    ok = ok & jnp.all(jnp.isfinite(r)) & jnp.all(r * sd > 0.2 * r_mm)
    return jnp.where(ok, mu + c * sd, c_mm), jnp.where(ok, r * sd, r_mm)


def fit_acc(
    pose_acc: Float[Array, "P 3"], w: Float[Array, "P"], model: str = "9", max_steps: int = 100,
    prior: DatasheetPrior | None = None, ridge: float = 1e-2,
) -> tuple[InverseAffine, Array]:
    """Accelerometer multi-position fit (weights ``w`` per pose; 0 leaves a pose out; optional
    datasheet ``prior``, MAP). The returned cost leaves the prior and ridge rows out and is
    unweighted.

    ``ridge`` (default 1e-2 g per unit of cross-axis term) keeps the non-orthogonality terms that
    the poses barely see at zero instead of fitting them to noise: with poses along the sensor
    axes only (a six-face protocol, and its repeats) they are unobserved to first order and a free
    fit wanders to ~0.1; with poses in general directions the ridge moves nothing measurable."""
    c0, s0 = ellipsoid_init(pose_acc, w)
    m = (pose_acc - c0) / s0
    if model == "9":
        theta0 = jnp.concatenate([jnp.zeros(3), jnp.ones(3), jnp.zeros(3)]).astype(m.dtype)
    elif model == "12":
        theta0 = jnp.concatenate([jnp.eye(3).ravel(), jnp.zeros(3)]).astype(m.dtype)
    else:
        raise ValueError(f"acc_model must be '9' or '12', got {model!r}")
    solver = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12)
    sol = optx.least_squares(acc_residuals, solver, theta0, args=(m, w, model, s0, prior, ridge), max_steps=max_steps, throw=False)
    a, b = _acc_matrix(sol.value, model)
    cost = jnp.sum(acc_residuals(sol.value, (m, w, model, s0)) ** 2)
    return InverseAffine(A=a / s0[None, :], b=c0 + s0 * b), cost


def fit_acc_determined(
    pose_acc: Float[Array, "P 3"], w: Float[Array, "P"], tol: float = OBSERVABLE_TOL, steps: int = 20
) -> tuple[InverseAffine, Array]:
    """Accelerometer fit for poses that do not determine every parameter: start from the
    recording's own units (``A = I``, ``b = 0``; the recording must already be in g) and take
    Gauss-Newton steps on the 9-parameter model (``A = L diag(s)``, ``L`` unit lower triangular)
    restricted to the combinations whose relative singular value in the weighted Jacobian of
    ``|A (m_i - b)| - 1`` exceeds ``tol`` (truncated SVD). The others stay as recorded: the
    minimum-norm correction the data support. Returns the calibration and the number of
    combinations moved (of 9)."""
    w = jnp.sqrt(w)

    def res(th):
        a, b = _acc_matrix(th, "9")
        return w * (jnp.linalg.norm((pose_acc - b) @ a.T, axis=-1) - 1.0)

    def step(_, carry):
        th, _ = carry
        u, sv, vt = jnp.linalg.svd(jax.jacfwd(res)(th), full_matrices=False)
        keep = sv > tol * sv[0]
        inv = jnp.where(keep, 1.0 / jnp.where(keep, sv, 1.0), 0.0)
        return th - vt.T @ (inv * (u.T @ res(th))), jnp.sum(keep)

    th0 = jnp.concatenate([jnp.zeros(3), jnp.ones(3), jnp.zeros(3)]).astype(pose_acc.dtype)
    th, n = jax.lax.fori_loop(0, steps, step, (th0, jnp.asarray(0)))
    return InverseAffine(*_acc_matrix(th, "9")), n


def acc_norm_errors(acc: InverseAffine, pose_acc: Float[Array, "P 3"]) -> Float[Array, "P"]:
    """``| |f_i| - 1 |`` per pose (g) for calibrated pose means."""
    return jnp.abs(jnp.linalg.norm((pose_acc - acc.b) @ acc.A.T, axis=-1) - 1.0)
