"""Axis-angle rotations (thesis eq. 4.1-4.3, 4.11) under the physical convention.

Conventions (``CONVENTIONS.md``): orientation ``R`` maps body to world and evolves as
``R(t + dt) = R(t) Exp(w dt)``; the body-frame specific force of a body rotating about the
sensor's centre evolves as ``f(t + dt) = Exp(w dt)^T f(t)``. The thesis prints eq. 4.5 and 4.9
with ``R_n`` instead of its transpose (the opposite sign convention); jaxcal uses the physical one
everywhere and says so where it reproduces the thesis.

Every function here is pure, jit-able and vmappable, and exact to floating-point precision.
``exp_so3`` has finite gradients at the zero vector (the thesis's stationary samples have
``w = 0``; the textbook formula divides by the angle and yields NaN Jacobians there).
:func:`slerp_pairs` is the one exception: numpy float64, for pose tracks read from files.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.mat3 import matmul3, matvec3, transpose3

__all__ = [
    "angle_between",
    "hat",
    "vee",
    "exp_so3",
    "right_jacobian_so3",
    "rotation_from_rate",
    "quat_from_matrix",
    "matrix_from_quat",
    "quat_mul",
    "slerp_pairs",
    "log_so3",
    "compose",
    "total_rotation",
    "propagate_specific_force",
    "integrate_orientation",
    "random_rotation",
    "random_unit_vectors",
]

# Below this squared angle the Taylor series (error O(theta^6)) replaces the closed form.
_SMALL_ANGLE_SQ = 1e-6


def hat(v: Float[Array, "... 3"]) -> Float[Array, "... 3 3"]:
    """Skew-symmetric matrix ``[v]x`` with ``hat(v) @ u == cross(v, u)``."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack(
        [jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2
    )


def vee(m: Float[Array, "... 3 3"]) -> Float[Array, "... 3"]:
    """Inverse of :func:`hat` (takes the skew part of ``m``)."""
    return 0.5 * jnp.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
    )


def _exp_coefficients(theta_sq: Float[Array, "..."]) -> tuple[Array, Array]:
    """``a = sin(t)/t`` and ``b = (1 - cos t)/t^2`` without cancellation or NaN gradients."""
    small = theta_sq < _SMALL_ANGLE_SQ
    safe_sq = jnp.where(small, 1.0, theta_sq)  # double-where: no NaN in the unused branch
    t = jnp.sqrt(safe_sq)
    half = 0.5 * t
    a_exact = jnp.sin(t) / t
    b_exact = 0.5 * (jnp.sin(half) / half) ** 2  # == (1 - cos t)/t^2, no cancellation
    a_taylor = 1.0 - theta_sq / 6.0 + theta_sq**2 / 120.0
    b_taylor = 0.5 - theta_sq / 24.0 + theta_sq**2 / 720.0
    return jnp.where(small, a_taylor, a_exact), jnp.where(small, b_taylor, b_exact)


def exp_so3(v: Float[Array, "... 3"]) -> Float[Array, "... 3 3"]:
    """Rotation matrix of the rotation vector ``v`` (axis * angle, rad): thesis eq. 4.2-4.3.

    ``Exp(v) = I + sin(t)/t [v]x + (1 - cos t)/t^2 [v]x^2`` with ``t = |v|``; identical to the
    thesis's element-wise eq. 4.3 with ``c = cos t``, ``s = sin t``, unit axis ``v/t``.
    """
    a, b = _exp_coefficients(jnp.sum(v * v, axis=-1))
    k = hat(v)
    eye = jnp.eye(3, dtype=v.dtype)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def rotation_from_rate(w: Float[Array, "... 3"], dt: float | Float[Array, ""]) -> Float[Array, "... 3 3"]:
    """``R_n = R(w_n, dt) = Exp(w_n dt)``: thesis eq. 4.1-4.3.

    Args:
        w: (..., 3) body rates (rad/s).
        dt: sample period (s).
    """
    return exp_so3(w * dt)


def quat_from_matrix(r: Float[Array, "... 3 3"]) -> Float[Array, "... 4"]:
    """Unit quaternion ``[w, x, y, z]`` (Hamilton, scalar first, ``w >= 0``) of a rotation matrix.

    Uses the largest-diagonal branch (Shepperd) so it is accurate at every angle, including pi.
    """
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    tr = m00 + m11 + m22
    cands = jnp.stack(
        [
            jnp.stack([1.0 + tr, r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1),
            jnp.stack([r[..., 2, 1] - r[..., 1, 2], 1.0 + m00 - m11 - m22, r[..., 0, 1] + r[..., 1, 0], r[..., 0, 2] + r[..., 2, 0]], -1),
            jnp.stack([r[..., 0, 2] - r[..., 2, 0], r[..., 0, 1] + r[..., 1, 0], 1.0 - m00 + m11 - m22, r[..., 1, 2] + r[..., 2, 1]], -1),
            jnp.stack([r[..., 1, 0] - r[..., 0, 1], r[..., 0, 2] + r[..., 2, 0], r[..., 1, 2] + r[..., 2, 1], 1.0 - m00 - m11 + m22], -1),
        ],
        -2,
    )  # (..., 4 candidates, 4); candidate i has 4 q_i^2 at index i
    diag = jnp.stack([1.0 + tr, 1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22], -1)
    idx = jnp.argmax(diag, axis=-1)
    q = jnp.take_along_axis(cands, idx[..., None, None], axis=-2)[..., 0, :]
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    return q * jnp.where(q[..., :1] < 0, -1.0, 1.0)


def matrix_from_quat(q: Float[Array, "... 4"]) -> Float[Array, "... 3 3"]:
    """Rotation matrix of a (not necessarily normalised) Hamilton quaternion ``[w, x, y, z]``."""
    q = q / jnp.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return jnp.stack(
        [
            jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def quat_mul(a: Float[Array, "... 4"], b: Float[Array, "... 4"]) -> Float[Array, "... 4"]:
    """Hamilton product ``a ⊗ b`` of ``[w, x, y, z]`` quaternions (broadcasting over leading axes).

    Args:
        a: (..., 4) left factor, ``[w, x, y, z]``.
        b: (..., 4) right factor, ``[w, x, y, z]``.
    """
    aw, av = a[..., :1], a[..., 1:]
    bw, bv = b[..., :1], b[..., 1:]
    w = aw * bw - jnp.sum(av * bv, -1, keepdims=True)
    v = aw * bv + bw * av + jnp.cross(av, bv)
    return jnp.concatenate([w, v], -1)


SLERP_SMALL_SIN = 1e-9
"""Below this ``sin`` of the half angle between two quaternions :func:`slerp_pairs` blends linearly.

In float64 the largest dot product below 1 is ``1 - 2**-53``, whose angle has ``sin`` 1.49e-8, so
every threshold in (0, 1.49e-8] (e.g. 1e-8 or 1e-9) selects the same pairs: only exactly equal
directions (``sin`` 0) take the linear branch."""


def slerp_pairs(q0: Float[np.ndarray, "N 4"], q1: Float[np.ndarray, "N 4"], u: Float[np.ndarray, " N"]) -> Float[np.ndarray, "N 4"]:
    """Row-wise spherical interpolation from ``q0`` to ``q1`` at fractions ``u``, along the shorter arc.

    Numpy float64 (not traced): the readers' pose tracks go through it. ``q1`` rows on the far
    hemisphere of ``q0`` are negated first (the same rotation); the result is renormalised.

    Args:
        q0: unit quaternions ``[w, x, y, z]`` at ``u = 0``.
        q1: unit quaternions ``[w, x, y, z]`` at ``u = 1``.
        u: fractions in [0, 1].
    """
    q1 = np.where(np.sum(q0 * q1, 1, keepdims=True) < 0, -q1, q1)
    d = np.clip(np.sum(q0 * q1, 1, keepdims=True), -1.0, 1.0)
    th = np.arccos(d)
    s = np.sin(th)
    small = s < SLERP_SMALL_SIN
    u = u[:, None]
    w0 = np.where(small, 1 - u, np.sin((1 - u) * th) / np.where(small, 1, s))
    w1 = np.where(small, u, np.sin(u * th) / np.where(small, 1, s))
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def angle_between(a: Float[Array, "... 3"], b: Float[Array, "... 3"]) -> Float[Array, "..."]:
    """Angle (rad, in ``[0, pi]``) between vectors of any length: ``atan2(|a x b|, a . b)``.

    Accurate at every angle, unlike ``arccos`` of the normalised dot product, whose resolution near 0
    is ``sqrt(2 eps)`` (1.5e-8 rad in float64: one rounding of the cosine reads as 1.5e-8 rad). Not
    differentiable where the vectors are parallel (the norm of a zero cross product).
    """
    return jnp.arctan2(jnp.linalg.norm(jnp.cross(a, b), axis=-1), jnp.sum(a * b, axis=-1))


def log_so3(r: Float[Array, "... 3 3"]) -> Float[Array, "... 3"]:
    """Rotation vector of a rotation matrix (inverse of :func:`exp_so3`), angle in ``[0, pi]``."""
    q = quat_from_matrix(r)
    qv = q[..., 1:]
    s_sq = jnp.sum(qv * qv, axis=-1)
    small = s_sq < 1e-12
    s = jnp.sqrt(jnp.where(small, 1.0, s_sq))
    angle = 2.0 * jnp.arctan2(s, q[..., 0])
    scale = jnp.where(small, 2.0 / q[..., 0], angle / s)
    return qv * scale[..., None]


def compose(rs: Float[Array, "N 3 3"]) -> Float[Array, "3 3"]:
    """Ordered product ``R_1 R_2 ... R_N`` (thesis eq. 4.11): the body's total rotation."""
    def step(acc, r):
        return acc @ r, None

    out, _ = jax.lax.scan(step, jnp.eye(3, dtype=rs.dtype), rs)
    return out


def total_rotation(w: Float[Array, "N 3"], dt: float | Float[Array, ""]) -> Float[Array, "3 3"]:
    """``R_tot = prod_n Exp(w_n dt)``: orientation change over a sequence of body rates.

    Args:
        w: (N, 3) body rates (rad/s), in time order.
        dt: sample period (s).
    """
    return compose(rotation_from_rate(w, dt))


def right_jacobian_so3(v: Float[Array, "... 3"]) -> Float[Array, "... 3 3"]:
    """Right Jacobian of :func:`exp_so3`: ``Exp(v + d) = Exp(v) Exp(J_r(v) d) + O(|d|^2)``.

    ``J_r(v) = I - (1 - cos t)/t^2 [v]x + (t - sin t)/t^3 [v]x^2`` with ``t = |v|`` (Sola, Deray,
    Atchuthan, "A micro Lie theory for state estimation in robotics", 2018, eq. 143); the Taylor
    series below the same small angle as :func:`exp_so3`, so it is finite (and ``I``) at ``v = 0``.
    """
    theta_sq = jnp.sum(v * v, axis=-1)
    a, b = _exp_coefficients(theta_sq)
    small = theta_sq < _SMALL_ANGLE_SQ
    safe_sq = jnp.where(small, 1.0, theta_sq)
    c = jnp.where(small, 1.0 / 6.0 - theta_sq / 120.0 + theta_sq**2 / 5040.0, (1.0 - a) / safe_sq)
    k = hat(v)
    eye = jnp.eye(3, dtype=v.dtype)
    return eye - b[..., None, None] * k + c[..., None, None] * (k @ k)


@functools.partial(jax.custom_jvp, nondiff_argnums=(2, 3))
def _propagate(f0: Float[Array, "3"], phi: Float[Array, "N 3"], unroll: int, elementwise: bool) -> Float[Array, "N+1 3"]:
    """``[f_0, ..., f_N]`` with ``f_{n+1} = Exp(phi_n)^T f_n`` (one compiled loop of 3x3 products)."""
    def step(f, r):
        f_next = matvec3(transpose3(r), f) if elementwise else r.T @ f
        return f_next, f_next

    _, fs = jax.lax.scan(step, f0, exp_so3(phi), unroll=unroll)
    return jnp.concatenate([f0[None], fs], axis=0)


@_propagate.defjvp
def _propagate_jvp(unroll: int, elementwise: bool, primals: tuple, tangents: tuple) -> tuple[Array, Array]:
    """The tangent in closed form, with no loop over the tangents.

    With ``Q_n = (Exp(phi_0) ... Exp(phi_{n-1}))^T`` (so ``f_n = Q_n f_0``) and
    ``d Exp(phi)^T g = [Exp(phi)^T g]x J_r(phi) d phi``, the linear recursion
    ``df_{n+1} = Exp(phi_n)^T df_n + [f_{n+1}]x J_r(phi_n) dphi_n`` solves to
    ``df_n = Q_n (df_0 + [f_0]x sum_{k<n} Q_{k+1}^T J_r(phi_k) dphi_k)`` (``Q^T [Q a]x = [a]x Q^T``).
    The primal is the loop's own output, bit for bit; ``Q_n`` and the matrices ``Q_{k+1}^T J_r`` do
    not depend on the tangents, so under ``jax.jacfwd`` they are computed once and the batch of
    tangents meets only a cumulative sum and elementwise 3x3 products. (JAX's own rule carries every
    tangent through all ``N`` steps of the loop: with it the ``online`` filter ran 1.3x (``diag``) and
    1.4x (``affine``) slower, ``benchmarks/online_engine.py``.)
    """
    f0, phi = primals
    df0, dphi = tangents

    out = _propagate(f0, phi, unroll, elementwise)

    def step(q, r_t):
        q_next = matmul3(r_t, q)
        return q_next, q_next

    # Q_1..Q_N (Q_{n+1} = Exp(phi_n)^T Q_n). Measured in the filter on 2 CPU cores: a loop beats a
    # parallel prefix (associative_scan) here, and a cumulative sum beats one by 10-15 %.
    _, qs = jax.lax.scan(step, jnp.eye(3, dtype=phi.dtype), transpose3(exp_so3(phi)), unroll=unroll)
    m = matmul3(transpose3(qs), right_jacobian_so3(phi))  # Q_{k+1}^T J_r(phi_k)
    s = jnp.cumsum(matvec3(m, dphi), axis=0)  # sum_{k<n}, n = 1..N
    s = df0[None] + jnp.cross(f0[None], s)
    dfs = matvec3(qs, s)
    return out, jnp.concatenate([df0[None], dfs], axis=0)


def propagate_specific_force(
    f0: Float[Array, "3"], w: Float[Array, "N 3"], dt: float | Float[Array, ""], unroll: int = 1,
    elementwise: bool = False,
) -> Float[Array, "N+1 3"]:
    """Body-frame specific force along a pure rotation: ``f_{n+1} = Exp(w_n dt)^T f_n``.

    Returns ``[f_0, f_1, ..., f_N]``. This is the physical convention; the thesis's eq. 4.5
    applies ``R_n`` instead of ``R_n^T``.

    Differentiable in ``f0``, ``w`` and ``dt`` with a closed-form tangent (:func:`_propagate_jvp`):
    ``jax.jacfwd`` over many parameters costs a cumulative sum, not one pass of the loop per
    parameter (the ``online`` filter's Gauss-Newton Jacobian, 14 or 23 columns).

    Args:
        f0: (3,) body-frame specific force at the start (g).
        w: (N, 3) body rates (rad/s).
        dt: sample period (s).
        unroll: (static) steps per iteration of the compiled loop (``lax.scan``'s ``unroll``): the
            same products in the same order, so the result is bit-identical; fewer loop iterations
            cost less where each step is a 3x3 product (:mod:`jaxcal.online` streams with 4).
        elementwise: (static) each step's product as three multiply-adds (:mod:`jaxcal.mat3`) instead
            of a dot: fewer kernels per step on the CPU, but not bit-identical to the dot, so
            ``False`` (the simulations' data stay as they were) unless speed matters more.
    """
    return _propagate(f0, w * dt, unroll, elementwise)


def integrate_orientation(
    r0: Float[Array, "3 3"], w: Float[Array, "N 3"], dt: float | Float[Array, ""]
) -> Float[Array, "N+1 3 3"]:
    """Orientation sequence ``R_{n+1} = R_n Exp(w_n dt)`` from ``R_0`` (body to world).

    Args:
        r0: (3, 3) initial orientation, body to world.
        w: (N, 3) body rates (rad/s).
        dt: sample period (s).
    """
    def step(r, dr):
        r_next = r @ dr
        return r_next, r_next

    _, rs = jax.lax.scan(step, r0, rotation_from_rate(w, dt))
    return jnp.concatenate([r0[None], rs], axis=0)


def random_rotation(key: jax.Array, shape: tuple[int, ...] = ()) -> Float[Array, "... 3 3"]:
    """Rotations uniform on SO(3) (normalised Gaussian quaternions).

    Args:
        key: PRNG key.
        shape: batch shape of the output (static: it sets the shape).
    """
    q = jax.random.normal(key, shape + (4,))
    return matrix_from_quat(q)


def random_unit_vectors(key: jax.Array, n: int) -> Float[Array, "n 3"]:
    """``n`` directions uniform on the unit sphere.

    Args:
        key: PRNG key.
        n: number of directions (static: it sets the shape).
    """
    v = jax.random.normal(key, (n, 3))
    return v / jnp.linalg.norm(v, axis=-1, keepdims=True)
