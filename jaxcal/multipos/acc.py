"""Multipos accelerometer: ``f = A (y - b)`` with ``|f| = 1 g`` in every static pose.

:func:`fit_acc` (9 or 12 parameters, optimistix Levenberg-Marquardt on :func:`acc_residuals` with
its named arguments :class:`AccArgs`, from an ellipsoid start, optional :class:`DatasheetPrior`),
:func:`fit_acc_determined` (only the combinations the poses determine move from the recording's
units) and the per-pose error :func:`acc_norm_errors`.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.constants import ACC_LSB_PER_G, GYR_LSB_PER_DPS
from jaxcal.multipos.data import OBSERVABLE_TOL
from jaxcal.sensor import LinearCal

__all__ = [
    "DatasheetPrior",
    "MPU6050_PRIOR",
    "prior_rows",
    "AccArgs",
    "acc_residuals",
    "ellipsoid_init",
    "fit_acc",
    "fit_acc_jit",
    "fit_acc_determined",
    "acc_norm_errors",
]


class DatasheetPrior(NamedTuple):
    """Optional Gaussian prior (MAP) on the scales and cross-axis terms, from a datasheet.

    With a prior the fits weigh the data residuals by their std (``acc_sigma``: one pose's
    ``|f| - 1`` in g; ``gyr_sigma``: one component of a carried-gravity or known-rotation residual,
    rad) and add rows ``(M_ii - 1) / scale_sigma`` and ``M_ij / cross_sigma`` (i != j) for
    ``M = A / unit_per_lsb`` (relative to the nominal sensitivity). ``None`` for a sensor's
    ``*_unit_per_lsb`` leaves that sensor without prior. Off by default everywhere: multipos needs
    no datasheet; the prior only fills directions the poses do not observe.

    Static: Python floats (it is a field of the static :class:`~jaxcal.multipos.MultiposConfig`, and
    :class:`AccArgs` / :class:`GyroArgs` treat it as static).

    Attributes:
        acc_unit_per_lsb: nominal accelerometer sensitivity (g per LSB); None: no accelerometer prior.
        gyr_unit_per_lsb: nominal gyroscope sensitivity (rad/s per LSB); None: no gyroscope prior.
        scale_sigma: std of the relative scale error ``M_ii - 1`` (the datasheet's sensitivity tolerance).
        cross_sigma: std of a cross-axis term ``M_ij`` (the datasheet's cross-axis sensitivity).
        acc_sigma: std of one pose's ``|f| - 1`` (g).
        gyr_sigma: std of one component of a carried-gravity or known-rotation residual (rad).
    """

    acc_unit_per_lsb: float | None = None
    gyr_unit_per_lsb: float | None = None
    scale_sigma: float = 0.03
    cross_sigma: float = 0.02
    acc_sigma: float = 1e-3
    gyr_sigma: float = 0.01


#: InvenSense MPU-6050 (PS-MPU-6000A rev 3.4) at +-2 g / +-250 deg/s: 16384 LSB/g, 131 LSB/(deg/s),
#: sensitivity tolerance +-3 %, cross-axis sensitivity +-2 % (both sensors).
MPU6050_PRIOR = DatasheetPrior(acc_unit_per_lsb=1.0 / ACC_LSB_PER_G, gyr_unit_per_lsb=float(np.pi / 180.0 / GYR_LSB_PER_DPS))


def prior_rows(a: Float[Array, "3 3"], unit_per_lsb: Any, prior: DatasheetPrior) -> Float[Array, "9"]:
    """Prior residuals of a calibration matrix ``A`` (unit/LSB): 3 scale rows, 6 cross-axis rows.

    Args:
        a: (3, 3) calibration matrix ``A`` (unit per LSB).
        unit_per_lsb: nominal sensitivity (unit per LSB), scalar or per column.
        prior: the :class:`DatasheetPrior` (its ``scale_sigma``, ``cross_sigma``).
    """
    m = a / unit_per_lsb
    off = m[np.array([0, 0, 1, 1, 2, 2]), np.array([1, 2, 0, 2, 0, 1])]
    return jnp.concatenate([(jnp.diag(m) - 1.0) / prior.scale_sigma, off / prior.cross_sigma])


def _lower(a: Float[Array, "3"]) -> Float[Array, "3 3"]:
    z, o = jnp.zeros_like(a[0]), jnp.ones_like(a[0])
    return jnp.stack([jnp.stack([o, z, z]), jnp.stack([a[0], o, z]), jnp.stack([a[1], a[2], o])])


def _acc_matrix(theta: Float[Array, " P"], model: str) -> tuple[Array, Array]:
    """Normalised-frame ``(A', b')`` from the parameter vector."""
    if model == "9":
        return _lower(theta[:3]) * theta[3:6][None, :], theta[6:9]
    return theta[:9].reshape(3, 3), theta[9:12]


class AccArgs(NamedTuple):
    """Arguments of :func:`acc_residuals` (the optimistix ``args`` pytree).

    Traced (arrays; may be vmapped): ``m``, ``w``, ``s0``. Static (Python values, which equinox
    and optimistix treat as static; changing them retraces): ``model``, ``prior``. ``ridge``: a
    Python float (static) or a traced scalar (e.g. a jitted caller's argument).

    Args:
        m: (P, 3) pose means normalised by the ellipsoid start, ``(pose_acc - c0) / s0``.
        w: (P,) weight per pose (0 leaves a pose out).
        model: ``"9"`` or ``"12"`` (see :func:`fit_acc`).
        s0: (3,) the ellipsoid start's semi-axes (raw units per g).
        prior: optional :class:`DatasheetPrior` (``None``: no prior rows, pose rows unscaled).
        ridge: weight of the cross-axis ridge rows (0: rows of zeros).
    """

    m: Float[Array, "P 3"]
    w: Float[Array, " P"]
    model: str
    s0: Float[Array, "3"]
    prior: DatasheetPrior | None = None
    ridge: float | Float[Array, ""] = 0.0


def acc_residuals(theta: Float[Array, " Q"], args: AccArgs) -> Float[Array, " R"]:
    """``sqrt(w_i) (|A'(m_i - b')| - 1)`` per pose (normalised pose means ``m_i``), plus the
    ``A - A^T`` gauge residual of the physical ``A = A' diag(1/s0)`` for the 12-parameter model (zeros for the 9-parameter one).
    With a :class:`DatasheetPrior` (``args.prior``) the pose rows are divided by its
    ``acc_sigma`` and its 9 prior rows on the physical ``A`` are appended. ``args.ridge``
    (default 0): ridge weight on the cross-axis terms of ``A'`` (relative to its diagonal), 6 rows
    ``ridge * A'_ij / A'_jj`` (i != j; the 9-parameter model's three zeros above the diagonal stay 0).

    Args:
        theta: (Q,) parameters of the 9- or 12-parameter model (traced).
        args: :class:`AccArgs` (which of its fields are static is said there).
    """
    m, w, model, s0, prior, ridge = args
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


def ellipsoid_init(m: Float[Array, "P 3"], w: Float[Array, " P"]) -> tuple[Array, Array]:
    """Centre and semi-axes of the axis-aligned ellipsoid through weighted points (least squares
    on ``a x^2 + b y^2 + c z^2 + d x + e y + f z = 1``); per-axis (max + min) / 2 and (max - min) / 2
    where that fit is degenerate.

    Args:
        m: (P, 3) points (pose means, raw units).
        w: (P,) weight per point; 0 leaves a point out.
    """
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
    pose_acc: Float[Array, "P 3"], w: Float[Array, " P"], model: str = "9", max_steps: int = 100,
    prior: DatasheetPrior | None = None, ridge: float | Float[Array, ""] = 1e-2,
) -> tuple[LinearCal, Array]:
    """Accelerometer multi-position fit (weights ``w`` per pose; 0 leaves a pose out; optional
    datasheet ``prior``, MAP). The returned cost leaves the prior and ridge rows out and is
    unweighted.

    ``ridge`` (default 1e-2 g per unit of cross-axis term) keeps the non-orthogonality terms that
    the poses barely see at zero instead of fitting them to noise: with poses along the sensor
    axes only (a six-face protocol, and its repeats) they are unobserved to first order and a free
    fit wanders to ~0.1; with poses in general directions the ridge moves nothing measurable.

    Args:
        pose_acc: (P, 3) pose means (raw units; traced).
        w: (P,) weight per pose (traced, vmappable; 0 leaves a pose out).
        model: ``"9"`` or ``"12"`` (static).
        max_steps: Levenberg-Marquardt iteration cap (static).
        prior: optional :class:`DatasheetPrior` (static; None: the data alone).
        ridge: weight of the cross-axis ridge (Python float, static, or a traced scalar; 0: off).
    """
    c0, s0 = ellipsoid_init(pose_acc, w)
    m = (pose_acc - c0) / s0
    if model == "9":
        theta0 = jnp.concatenate([jnp.zeros(3), jnp.ones(3), jnp.zeros(3)]).astype(m.dtype)
    elif model == "12":
        theta0 = jnp.concatenate([jnp.eye(3).ravel(), jnp.zeros(3)]).astype(m.dtype)
    else:
        raise ValueError(f"acc_model must be '9' or '12', got {model!r}")
    solver = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12)
    args = AccArgs(m, w, model, s0, prior, ridge)
    sol = optx.least_squares(acc_residuals, solver, theta0, args=args, max_steps=max_steps, throw=False)
    a, b = _acc_matrix(sol.value, model)
    cost = jnp.sum(acc_residuals(sol.value, args._replace(prior=None, ridge=0.0)) ** 2)
    return LinearCal(A=a / s0[None, :], b=c0 + s0 * b), cost


#: :func:`fit_acc` compiled, ``model`` and ``max_steps`` static (``ridge`` traced).
fit_acc_jit = jax.jit(fit_acc, static_argnames=("model", "max_steps"))


def fit_acc_determined(
    pose_acc: Float[Array, "P 3"], w: Float[Array, " P"], tol: float = OBSERVABLE_TOL, steps: int = 20
) -> tuple[LinearCal, Array]:
    """Accelerometer fit for poses that do not determine every parameter: start from the
    recording's own units (``A = I``, ``b = 0``; the recording must already be in g) and take
    Gauss-Newton steps on the 9-parameter model (``A = L diag(s)``, ``L`` unit lower triangular)
    restricted to the combinations whose relative singular value in the weighted Jacobian of
    ``|A (m_i - b)| - 1`` exceeds ``tol`` (truncated SVD). The others stay as recorded: the
    minimum-norm correction the data support. Returns the calibration and the number of
    combinations moved (of 9).

    Args:
        pose_acc: (P, 3) pose means (in g; traced).
        w: (P,) weight per pose (traced, vmappable; 0 leaves a pose out).
        tol: relative singular value below which a combination is left as recorded.
        steps: Gauss-Newton steps.
    """
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
    return LinearCal(*_acc_matrix(th, "9")), n


def acc_norm_errors(acc: LinearCal, pose_acc: Float[Array, "P 3"]) -> Float[Array, " P"]:
    """``| |f_i| - 1 |`` per pose (g) for calibrated pose means.

    Args:
        acc: accelerometer calibration (applied form, to g).
        pose_acc: (P, 3) pose means (raw units).
    """
    return jnp.abs(jnp.linalg.norm((pose_acc - acc.b) @ acc.A.T, axis=-1) - 1.0)
