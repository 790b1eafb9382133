"""Multipos gyroscope: ``w = G (y - b) [- G_s f]`` integrated between poses must carry gravity.

Pure residuals of the gyro fit (:func:`gyr_residuals` with its named arguments :class:`GyroArgs`:
carried-gravity rows, plus optional known-rotation and vertical-turn rows), the rotation of a
transition from its block sums (:func:`block_rotvecs`, :func:`carry_rotation`), the label-free
Ferraris start :func:`turn_init` and the scores :func:`gyro_angle_errors`, :func:`known_rotation_errors`, :func:`vertical_turn_errors`.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.multipos.acc import DatasheetPrior, prior_rows
from jaxcal.multipos.data import KnownRotations, MultiposData, VerticalTurns, calibrated_acc_sums
from jaxcal.rotation import angle_between, exp_so3, log_so3
from jaxcal.sensor import LinearCal

__all__ = [
    "carry_rotation",
    "cofactor",
    "block_rotvecs",
    "known_rotation_residuals",
    "vertical_turn_residuals",
    "vertical_turn_errors",
    "turn_init",
    "rest_gsens",
    "GyroArgs",
    "gyr_residuals",
    "gyro_angle_errors",
    "gyro_angle_errors_jit",
    "known_rotation_errors",
]


def carry_rotation(w: Float[Array, "J L 3"], dt: Float[Array, "J L"]) -> Float[Array, "J 3 3"]:
    """``R_j = prod_l Exp(w_jl dt_jl)`` (ordered, left to right) for every transition.

    Padding steps have ``dt = 0`` (identity). The product is a pairwise tree reduction
    (``log2 L`` batched matrix products) rather than an ``L``-step scan: same result, far fewer
    sequential steps.

    Args:
        w: (J, L, 3) rates (rad/s), or block rotation vectors (rad) with ``dt`` ones.
        dt: (J, L) step durations (s); 0 on padding steps.
    """
    L = w.shape[1]
    n = 1 << max(0, int(np.ceil(np.log2(max(L, 1)))))
    r = exp_so3(w * dt[..., None])
    if n > L:
        eye = jnp.broadcast_to(jnp.eye(3, dtype=r.dtype), (r.shape[0], n - L, 3, 3))
        r = jnp.concatenate([r, eye], axis=1)
    while r.shape[1] > 1:
        r = r[:, 0::2] @ r[:, 1::2]
    return r[:, 0]


def cofactor(g: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """Cofactor matrix, ``(G u) x (G v) = cof(G) (u x v)`` for every ``u, v``."""
    return jnp.stack([jnp.cross(g[:, 1], g[:, 2]), jnp.cross(g[:, 2], g[:, 0]), jnp.cross(g[:, 0], g[:, 1])], axis=1)


def block_rotvecs(
    g: Float[Array, "3 3"], b: Float[Array, "3"], gsens: Float[Array, "3 3"], d: MultiposData | KnownRotations,
    seg_f_off: Float[Array, "J L 3"],
) -> Float[Array, "J L 3"]:
    """Rotation vector of every block for ``w = G (y - b) - G_s f`` (second-order Magnus; the
    g-sensitivity term enters to first order, ``seg_f_off`` = block sums of calibrated ``f dt``).

    Args:
        g: (3, 3) gyro matrix ``G`` (applied form).
        b: (3,) gyro bias (raw units).
        gsens: (3, 3) g-sensitivity ``G_s`` ((rad/s)/g).
        d: block sums of the transitions or known-rotation sections.
        seg_f_off: (J, L, 3) block sums of calibrated ``f dt`` (:func:`calibrated_acc_sums`).
    """
    first = (d.sy - b * d.sdt[..., None]) @ g.T
    cross = d.c0 - jnp.cross(b, d.p1) + jnp.cross(b, d.p2)
    return first + 0.5 * cross @ cofactor(g).T - seg_f_off @ gsens.T


def known_rotation_residuals(
    g: Float[Array, "3 3"], b: Float[Array, "3"], gsens: Float[Array, "3 3"], known: KnownRotations, fsum: Float[Array, "K L 3"]
) -> Float[Array, "K 3"]:
    """``log_so3(R_known^T R_int)`` per known-rotation section (rad, 3 components; physical
    convention, ``R_int = prod Exp(w dt)`` of ``w = G (y - b) - G_s f``). Pure and vmappable.

    Args:
        g: (3, 3) gyro matrix ``G`` (applied form).
        b: (3,) gyro bias (raw units).
        gsens: (3, 3) g-sensitivity ``G_s`` ((rad/s)/g).
        known: the known-rotation sections.
        fsum: (K, L, 3) their calibrated accelerometer block sums (:func:`calibrated_acc_sums`).
    """
    r = carry_rotation(block_rotvecs(g, b, gsens, known, fsum), jnp.ones_like(known.sdt))
    return log_so3(jnp.swapaxes(known.R, -1, -2) @ r)


def _turn_axes(acc: LinearCal, turns: VerticalTurns) -> Float[Array, "K 3"]:
    f = (turns.rest_acc - acc.b) @ acc.A.T
    return f / jnp.linalg.norm(f, axis=-1, keepdims=True)


def vertical_turn_residuals(
    g: Float[Array, "3 3"], b: Float[Array, "3"], gsens: Float[Array, "3 3"], acc: LinearCal, turns: VerticalTurns
) -> Float[Array, "K 3"]:
    """``I_k - angle_k s_k u_k`` per turn (rad): ``I_k = G (y_int - b dt) - G_s f dt`` the
    integrated calibrated rate, ``u_k`` the calibrated gravity direction at the adjacent rests,
    ``s_k = sign(I_k . u_k)`` the sense of the turn. Zero for an exact turn about the vertical.

    Args:
        g: (3, 3) gyro matrix ``G`` (applied form).
        b: (3,) gyro bias (raw units).
        gsens: (3, 3) g-sensitivity ``G_s`` ((rad/s)/g).
        acc: accelerometer calibration giving the turning axes.
        turns: the vertical turns.
    """
    u = _turn_axes(acc, turns)
    i = (turns.y_int - b * turns.dt_sum[:, None]) @ g.T - (u * turns.dt_sum[:, None]) @ gsens.T
    s = jnp.sign(jnp.sum(i * u, -1))
    return i - (turns.angle * s)[:, None] * u


def vertical_turn_errors(
    gyr: LinearCal, gsens: Float[Array, "3 3"], acc: LinearCal, turns: VerticalTurns
) -> Float[Array, " K"]:
    """Norm of :func:`vertical_turn_residuals` per turn (rad): the angle by which the integrated
    turn misses a whole turn about the measured vertical.

    Args:
        gyr: gyroscope calibration (applied form).
        gsens: (3, 3) g-sensitivity ``G_s`` ((rad/s)/g).
        acc: accelerometer calibration giving the turning axes.
        turns: the vertical turns.
    """
    return jnp.linalg.norm(vertical_turn_residuals(gyr.A, gyr.b, gsens, acc, turns), axis=-1)


def turn_init(b: Float[Array, "3"], acc: LinearCal, turns: VerticalTurns, w: Float[Array, " K"], sign: Any = 1.0) -> Float[Array, "3 3"]:
    """Closed-form gyro matrix from vertical turns (weights ``w``; at least three about independent
    axes): least squares ``G Y = U`` with ``Y_k = y_int_k - b dt_k`` and ``U_k = angle_k s_k u_k``,
    where the sense ``s_k = sign(sign * Y_k . u_k)`` follows a guess of ``sign(G)`` (``sign``). This
    is the Ferraris gyro calibration with the axes measured by the accelerometer instead of labelled.

    Args:
        b: (3,) gyro bias (raw units).
        acc: accelerometer calibration giving the turning axes.
        turns: the vertical turns.
        w: (K,) weight per turn (0 leaves a turn out).
        sign: guess of ``sign(G)`` (+1 or -1).
    """
    u = _turn_axes(acc, turns)
    y = turns.y_int - b * turns.dt_sum[:, None]
    s = jnp.sign(sign * jnp.sum(y * u, -1))
    target = (turns.angle * s)[:, None] * u
    yw = y * w[:, None]
    # weighted normal equations of min sum_k w_k |G y_k - target_k|^2: (Y^T W Y) G^T = Y^T W T
    return jnp.linalg.lstsq(yw.T @ y, yw.T @ target, rcond=1e-10)[0].T


def rest_gsens(
    pose_gyr: Float[Array, "P 3"], f: Float[Array, "P 3"], w: Float[Array, " P"]
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """Gyro bias and g-sensitivity from the rests alone: the weighted least-squares fit of
    ``pose_gyr_k = b + H f_k`` (``H`` raw gyro units per g; the applied-form g-sensitivity is
    ``G_s = G H`` for a gyro matrix ``G``). At rest the true rate is zero, so each pose's mean
    output is the bias plus the g-sensitivity's response to that pose's specific force: four or
    more poses whose gravity directions span 3-D determine both, trace included (the vertical
    component of the Earth's rate, ``15.04 sin(latitude)`` deg/h, at most 0.0042 (deg/s)/g, reads
    as part of the isotropic ``tr(G_s)/3``). Pure and vmappable; a zero weight leaves a pose out.

    Args:
        pose_gyr: (P, 3) mean gyroscope output per pose (raw units).
        f: (P, 3) calibrated specific force per pose (g).
        w: (P,) weight per pose (e.g. its sample count; 0 leaves it out).
    """
    sw = jnp.sqrt(w / jnp.max(w))[:, None]
    x = jnp.concatenate([jnp.ones_like(f[:, :1]), f], axis=1)
    coef = jnp.linalg.lstsq(x * sw, pose_gyr * sw)[0]
    return coef[0], coef[1:].T


class GyroArgs(NamedTuple):
    """Arguments of :func:`gyr_residuals` (the optimistix ``args`` pytree). An optional term is
    absent when its fields are ``None`` (``known``: known rotations; ``turns``: vertical turns;
    ``prior``: datasheet prior); drop one with ``args._replace(prior=None)``.

    Traced (arrays; may be vmapped): every field but the static ones. Static (Python values,
    which equinox and optimistix treat as static; changing them retraces): ``g_sensitivity``,
    ``prior`` (a :class:`DatasheetPrior` of Python floats), and which optional terms are present.

    Args:
        data: the prepared poses and transitions (:class:`MultiposData`).
        bias: (3,) gyro bias ``b_g`` (raw units), held fixed.
        scale: scalar start scale ``s0``: ``G = s0 (I + theta[:9])``.
        g_sensitivity: also fit ``G_s = theta[9:18]`` (else ``G_s = 0``, or ``G H`` with ``rest_gsens``).
        fsum: (J, L, 3) calibrated accelerometer block sums (:func:`calibrated_acc_sums`).
        u: (P, 3) calibrated unit gravity direction of every pose.
        w: (J,) weight per transition (0 leaves it out).
        known: optional :class:`KnownRotations`.
        known_w: (K,) weights of the known rotations (with ``known``).
        known_fsum: (K, L, 3) their calibrated accelerometer block sums (with ``known``).
        prior: optional :class:`DatasheetPrior` on ``G``.
        turns: optional :class:`VerticalTurns`.
        turns_w: (T,) weights of the turns (with ``turns``).
        acc: the accelerometer calibration giving the turns' axes (with ``turns``).
        rest_gsens: optional (3, 3) g-sensitivity ``H`` in raw units per g, held fixed
            (:func:`rest_gsens`): ``G_s = G H`` follows the gyro matrix (needs ``g_sensitivity``
            off).
    """

    data: MultiposData
    bias: Float[Array, "3"]
    scale: Float[Array, ""]
    g_sensitivity: bool
    fsum: Float[Array, "J L 3"]
    u: Float[Array, "P 3"]
    w: Float[Array, " J"]
    known: KnownRotations | None = None
    known_w: Float[Array, " K"] | None = None
    known_fsum: Float[Array, "K L 3"] | None = None
    prior: DatasheetPrior | None = None
    turns: VerticalTurns | None = None
    turns_w: Float[Array, " T"] | None = None
    acc: LinearCal | None = None
    rest_gsens: Float[Array, "3 3"] | None = None


def gyr_residuals(theta: Float[Array, " Q"], args: GyroArgs) -> Float[Array, " R"]:
    """``sqrt(w_j) (R_j^T u_j - u_{j+1})`` for every transition ``j`` (physical convention).

    Optional terms (:class:`GyroArgs`, absent when ``None``): known-rotation rows
    ``sqrt(w_k) log_so3(R_known^T R_int)`` (:func:`known_rotation_residuals`), vertical-turn rows
    ``sqrt(w_k) (I_k - angle_k s_k u_k)`` (:func:`vertical_turn_residuals`, axes from the
    accelerometer calibration ``args.acc``) and, with a :class:`DatasheetPrior`, all data rows
    divided by its ``gyr_sigma`` plus its 9 prior rows on ``G``.

    Args:
        theta: (Q,) parameters, ``G = s0 (I + theta[:9])`` and ``G_s = theta[9:18]`` (traced; with
            ``args.rest_gsens`` ``H``, ``G_s = G H`` and ``Q = 9``).
        args: :class:`GyroArgs` (which of its fields are static is said there).
    """
    d, bg, s0, gs, fsum, u, wj, known, known_w, kfsum, prior, turns, turns_w, acc, h = args
    g = s0 * (jnp.eye(3, dtype=theta.dtype) + theta[:9].reshape(3, 3))
    gsm = theta[9:18].reshape(3, 3) if gs else (jnp.zeros((3, 3), theta.dtype) if h is None else g @ h)
    r = carry_rotation(block_rotvecs(g, bg, gsm, d, fsum), jnp.ones_like(d.sdt))
    pred = jnp.einsum("jba,jb->ja", r, u[:-1])  # R^T u_j
    rows = [(jnp.sqrt(wj)[:, None] * (pred - u[1:])).ravel()]
    if known is not None:
        kr = known_rotation_residuals(g, bg, gsm, known, kfsum)
        rows.append((jnp.sqrt(known_w * known.seg_ok.astype(kr.dtype))[:, None] * kr).ravel())
    if turns is not None:
        tr = vertical_turn_residuals(g, bg, gsm, acc, turns)
        rows.append((jnp.sqrt(turns_w * turns.seg_ok.astype(tr.dtype))[:, None] * tr).ravel())
    if prior is not None and prior.gyr_unit_per_lsb is not None:
        rows = [x / prior.gyr_sigma for x in rows] + [prior_rows(g, prior.gyr_unit_per_lsb, prior)]
    return jnp.concatenate(rows)


def gyro_angle_errors(
    gyr: LinearCal, gsens: Float[Array, "3 3"], acc: LinearCal, data: MultiposData
) -> Float[Array, " J"]:
    """Angle (rad) between the gyro-carried gravity direction of pose ``j`` and pose ``j + 1``'s.

    Args:
        gyr: gyroscope calibration (applied form).
        gsens: (3, 3) g-sensitivity ``G_s`` ((rad/s)/g).
        acc: accelerometer calibration (applied form).
        data: prepared poses and transitions.
    """
    f = (data.pose_acc - acc.b) @ acc.A.T
    u = f / jnp.linalg.norm(f, axis=-1, keepdims=True)
    rv = block_rotvecs(gyr.A, gyr.b, gsens, data, calibrated_acc_sums(acc, data))
    r = carry_rotation(rv, jnp.ones_like(data.sdt))
    pred = jnp.einsum("jba,jb->ja", r, u[:-1])
    return angle_between(pred, u[1:])


#: :func:`gyro_angle_errors` compiled, for callers outside a trace (scores, rest detection, the field
#: path's carried sigma): op by op it took about 90 ms a call on the MPU-6050's 10 rests.
gyro_angle_errors_jit = jax.jit(gyro_angle_errors)


def known_rotation_errors(
    gyr: LinearCal, gsens: Float[Array, "3 3"], acc: LinearCal, known: KnownRotations
) -> Float[Array, " K"]:
    """Angle (rad) of ``R_known^T R_int`` per known-rotation section: the rotation error.

    Args:
        gyr: gyroscope calibration (applied form).
        gsens: (3, 3) g-sensitivity ``G_s`` ((rad/s)/g).
        acc: accelerometer calibration (applied form).
        known: the known-rotation sections.
    """
    kr = known_rotation_residuals(gyr.A, gyr.b, gsens, known, calibrated_acc_sums(acc, known))
    return jnp.linalg.norm(kr, axis=-1)
