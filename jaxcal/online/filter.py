"""The streaming filter of :mod:`jaxcal.online`: the static parameter layout (``kind``), the
consistency residuals of one sequence, and the information filter's ``init``/``predict``/``update``
as a :class:`Filter` (:func:`make_filter`); :func:`to_linear_cal` turns its parameters into the
interchange type. The model and the estimator are described in :mod:`jaxcal.online`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float, Int

from jaxcal.arrays import Array
from jaxcal.mat3 import inv3, matvec3
from jaxcal.rotation import propagate_specific_force
from jaxcal.sensor import Affine, Diag, LinearCal

__all__ = [
    "KINDS",
    "PROPAGATE_UNROLL",
    "Calib",
    "Filter",
    "HOLD",
    "OnlineHP",
    "OnlineState",
    "make_filter",
    "diag_theta",
    "forward_models",
    "tangent_basis",
    "to_linear_cal",
]

KINDS = ("diag", "affine")
# Rotation steps per iteration of the sequence propagation's compiled loop (static; bit-identical for any
# value); benchmarks/online_unroll.py times the choice (measured so far only on another machine's CPU).
PROPAGATE_UNROLL = 4
# The propagation's 3x3 products as elementwise multiply-adds (static; rotation.propagate_specific_force).
PROPAGATE_ELEMENTWISE = True


# ----------------------------------------------------------------------------------------------
# parameter layout (static: one per kind)
# ----------------------------------------------------------------------------------------------


class _Layout(NamedTuple):
    """Where the free entries of ``D_a``, ``D_g`` and the biases sit in ``theta`` (static: Python
    values only; arrays are made at each use, so the x64 setting of the caller applies)."""

    ia: tuple[int, ...]  # flat indices of the free entries of D_a (3 x 3)
    ig: tuple[int, ...]  # flat indices of the free entries of D_g
    diag_a: tuple[bool, ...]  # which of ia / ig are diagonal (scale) entries
    diag_g: tuple[bool, ...]
    sa: slice  # theta slices: D_a entries, e_a, D_g entries, e_g
    sea: slice
    sg: slice
    seg: slice
    n: int  # number of parameters


def _layout(kind: str) -> _Layout:
    """The layout of ``kind``: ``diag`` (6 + 6) or ``affine`` (9 + 12, ``D_a`` upper triangular)."""
    if kind == "diag":
        ia = ig = (0, 4, 8)
    elif kind == "affine":
        ia = (0, 1, 2, 4, 5, 8)  # upper triangle (gauge fix)
        ig = tuple(range(9))
    else:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    na, ng = len(ia), len(ig)
    is_diag = lambda idx: tuple(i in (0, 4, 8) for i in idx)  # noqa: E731
    return _Layout(
        ia, ig, is_diag(ia), is_diag(ig),
        slice(0, na), slice(na, na + 3), slice(na + 3, na + 3 + ng), slice(na + 3 + ng, na + 6 + ng), na + ng + 6,
    )


class Calib(NamedTuple):
    """The filter's internal parameterisation, in spec-converted units: ``a_c = K_a u_a - e_a``,
    ``w_c = K_g u_g - e_g`` (``u = (y - b_spec) / s_spec``, eq. 4.8).

    Internal: it is relative to the datasheet models, so it is no interchange type; convert with
    :func:`to_linear_cal` (a :class:`~jaxcal.sensor.LinearCal` per sensor, in sensor units).
    """

    K_a: Float[Array, "3 3"]
    e_a: Float[Array, "3"]
    K_g: Float[Array, "3 3"]
    e_g: Float[Array, "3"]


def _unpack(lay: _Layout, theta: Float[Array, " Q"]) -> Calib:
    """Map the flat parameter vector to the two linear calibrations (``theta = 0``: spec)."""
    eye = jnp.eye(3, dtype=theta.dtype)
    k_a = eye + jnp.zeros(9, theta.dtype).at[np.array(lay.ia)].set(theta[lay.sa]).reshape(3, 3)
    k_g = eye + jnp.zeros(9, theta.dtype).at[np.array(lay.ig)].set(theta[lay.sg]).reshape(3, 3)
    return Calib(k_a, theta[lay.sea], k_g, theta[lay.seg])


def _per_param(lay: _Layout, scale: Any, cross: Any, acc_bias: Any, gyr_bias: Any) -> Float[Array, " Q"]:
    """A per-parameter vector from four class values (scale entries, cross-axis, biases)."""
    parts = [
        jnp.where(jnp.asarray(np.array(lay.diag_a)), scale, cross),
        jnp.broadcast_to(acc_bias, (3,)),
        jnp.where(jnp.asarray(np.array(lay.diag_g)), scale, cross),
        jnp.broadcast_to(gyr_bias, (3,)),
    ]
    return jnp.concatenate([jnp.asarray(p, dtype=jnp.result_type(float)) for p in parts])


def _calibrate_acc(lay: _Layout, theta: Float[Array, " Q"], u: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Calibrated specific force (g) of spec-converted accelerometer readings ``u``."""
    c = _unpack(lay, theta)
    return matvec3(c.K_a, u) - c.e_a


def _calibrate_gyr(lay: _Layout, theta: Float[Array, " Q"], u: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Calibrated body rate (rad/s) of spec-converted gyroscope readings ``u``."""
    c = _unpack(lay, theta)
    return matvec3(c.K_g, u) - c.e_g


# ----------------------------------------------------------------------------------------------
# one sequence
# ----------------------------------------------------------------------------------------------


def tangent_basis(f: Float[Array, "3"]) -> Float[Array, "3 2"]:
    """Orthonormal basis of the plane orthogonal to the unit vector ``f``."""
    h = jnp.where(jnp.abs(f[0]) < 0.9, jnp.array([1.0, 0.0, 0.0], f.dtype), jnp.array([0.0, 1.0, 0.0], f.dtype))
    b1 = jnp.cross(f, h)
    b1 = b1 / jnp.linalg.norm(b1)
    b2 = jnp.cross(f, b1)
    return jnp.stack([b1, b2], axis=1)


def _carried_gravity(
    lay: _Layout,
    theta: Float[Array, " Q"],
    delta: Float[Array, "2"],
    f0_ref: Float[Array, "3"],
    u_gyr: Float[Array, "N 3"],
    mask: Float[Array, " N"],
    dt: float | Float[Array, ""],
) -> Float[Array, "N 3"]:
    """``Phi_n(w_c)^T f_0``: gravity from ``f_0 = normalise(f0_ref + B delta)`` carried by the
    calibrated gyroscope (depends on the gyroscope's entries of ``theta`` and ``delta`` only)."""
    w_c = _calibrate_gyr(lay, theta, u_gyr) * mask[:, None]
    f0 = f0_ref + tangent_basis(f0_ref) @ delta
    f0 = f0 / jnp.linalg.norm(f0)
    return propagate_specific_force(f0, w_c[:-1], dt, unroll=PROPAGATE_UNROLL, elementwise=PROPAGATE_ELEMENTWISE)


def _readings_of(lay: _Layout, theta: Float[Array, " Q"], f: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
    """Noise-free spec-converted accelerometer readings ``K_a^{-1} (f + e_a)`` of specific force ``f``
    (depends on the accelerometer's entries of ``theta`` only)."""
    c = _unpack(lay, theta)
    return matvec3(inv3(c.K_a), f + c.e_a)


def _predict_acc_readings(
    lay: _Layout,
    theta: Float[Array, " Q"],
    delta: Float[Array, "2"],
    f0_ref: Float[Array, "3"],
    u_gyr: Float[Array, "N 3"],
    mask: Float[Array, " N"],
    dt: float | Float[Array, ""],
) -> Float[Array, "N 3"]:
    """Noise-free spec-converted accelerometer readings ``K_a^{-1} (Phi_n(w_c)^T f_0 + e_a)`` of one
    sequence: gravity from ``f_0 = normalise(f0_ref + B delta)`` carried by the calibrated gyro."""
    return _readings_of(lay, theta, _carried_gravity(lay, theta, delta, f0_ref, u_gyr, mask, dt))


def _weighted_residuals(
    u_acc: Float[Array, "N 3"],
    u_pred: Float[Array, "N 3"],
    mask: Float[Array, " N"],
    weight: Float[Array, " N"] | None = None,
    weight_t: Float[Array, " N"] | None = None,
) -> Float[Array, " 3*N"]:
    """``u_acc - u_pred`` weighed as :func:`_sequence_residuals` says, flattened."""
    w = mask if weight is None else jnp.sqrt(weight) * mask
    r = u_acc - u_pred
    if weight_t is None:
        return (r * w[:, None]).reshape(-1)
    d = u_pred / jnp.linalg.norm(u_pred, axis=-1, keepdims=True)
    r_along = jnp.sum(r * d, axis=-1, keepdims=True) * d
    return (r_along * w[:, None] + (r - r_along) * (jnp.sqrt(weight_t) * mask)[:, None]).reshape(-1)


def _sequence_residuals(
    lay: _Layout,
    theta: Float[Array, " Q"],
    delta: Float[Array, "2"],
    f0_ref: Float[Array, "3"],
    u_acc: Float[Array, "N 3"],
    u_gyr: Float[Array, "N 3"],
    mask: Float[Array, " N"],
    dt: float | Float[Array, ""],
    weight: Float[Array, " N"] | None = None,
    weight_t: Float[Array, " N"] | None = None,
) -> Float[Array, " 3*N"]:
    """Measurement-space residuals ``u_a,n - K_a^{-1} (Phi_n(w_c)^T f_0 + e_a)`` of one sequence
    (spec-converted accelerometer units, ~g), flattened; masked samples give 0.

    ``weight`` (optional, ``None``: the mask) weighs each sample's residual apart from the mask,
    which also stops the rotation: a sample of weight ``w`` counts as ``w`` samples (its residual is
    multiplied by ``sqrt(w)``), and weight 0 keeps a sample in the gyro's propagation but out of the
    fit (:mod:`jaxcal.field`: the motion samples, whose translational acceleration the model lacks).
    ``weight_t`` (optional, ``None``: ``weight``) weighs the residual's component across the
    predicted direction apart from the one along it: a rest at the end of a motion knows its
    ``|f|`` to the accelerometer's noise but its carried direction only to the gyroscope's
    integration error, which is far larger on real motions (:mod:`jaxcal.field`).

    ``f_0 = normalise(f0_ref + B delta)`` with ``B`` the tangent basis at ``f0_ref``. Masked
    (padding) samples contribute no rotation and no residual. The residual is formed where the
    noise is (the raw reading), not on the calibrated value ``a_c - f``: the latter scales the
    noise by ``K_a`` and is minimised by shrinking ``K_a`` (its global minimum is the trivial
    ``K_a = 0``), which biases the estimate by ~``sigma^2`` and, with datasheet-level noise,
    pulls the gyroscope scale off by several standard deviations.
    """
    u_pred = _predict_acc_readings(lay, theta, delta, f0_ref, u_gyr, mask, dt)
    return _weighted_residuals(u_acc, u_pred, mask, weight, weight_t)


def _residuals_and_jacobian(
    lay: _Layout,
    z: Float[Array, " P"],
    f0_ref: Float[Array, "3"],
    u_acc: Float[Array, "N 3"],
    u_gyr: Float[Array, "N 3"],
    mask: Float[Array, " N"],
    dt: float | Float[Array, ""],
    weight: Float[Array, " N"] | None = None,
    weight_t: Float[Array, " N"] | None = None,
) -> tuple[Float[Array, " 3*N"], Float[Array, "3*N P"]]:
    """:func:`_sequence_residuals` at ``z = (theta, delta)`` and its Jacobian, by the chain rule
    through the carried gravity ``f``: the accelerometer's entries of ``theta`` (the layout's first
    ones) do not move ``f``, so only the gyroscope's entries and ``delta`` are pushed through the
    propagation (8 of 14 columns for ``diag``, 14 of 23 for ``affine``), and all columns through the
    cheap reading model. Equal to ``jax.jacfwd`` of :func:`_sequence_residuals` to rounding."""
    k = lay.sg.start  # theta = (accelerometer entries [:k], gyroscope entries [k:]), then delta
    p = lay.n
    za, zg = z[:k], z[k:]

    def carried(zg_):
        theta = jnp.concatenate([za, zg_[: p - k]])
        return _carried_gravity(lay, theta, zg_[p - k:], f0_ref, u_gyr, mask, dt)

    def residuals(za_, f):
        theta = jnp.concatenate([za_, zg[: p - k]])
        return _weighted_residuals(u_acc, _readings_of(lay, theta, f), mask, weight, weight_t)

    df, f = jax.jacfwd(lambda zg_: (carried(zg_),) * 2, has_aux=True)(zg)  # (N, 3, P - k), (N, 3)
    j_a, r = jax.jacfwd(lambda za_: (residuals(za_, f),) * 2, has_aux=True)(za)
    j_g = jax.vmap(lambda d: jax.jvp(lambda f_: residuals(za, f_), (f,), (d,))[1], in_axes=-1, out_axes=-1)(df)
    return r, jnp.concatenate([j_a, j_g], axis=1)


# ----------------------------------------------------------------------------------------------
# the filter
# ----------------------------------------------------------------------------------------------


class OnlineHP(NamedTuple):
    """Hyperparameters of the streaming filter. Traced: every field may be an array (vmappable;
    changing a value does not recompile).

    Attributes:
        sigma_acc: standard deviation of one accelerometer residual component (g); quantisation
            alone: ``1/sqrt(12)`` LSB / scale.
        n_iter: Gauss-Newton iterations per sequence.
        forgetting: ``lambda`` in ``(0, 1]``; the information is multiplied by it per sequence.
        q_scale, q_cross: process-noise std per sequence of the scale / cross-axis entries.
        q_acc_bias, q_gyr_bias: process-noise std per sequence of the biases (g, rad/s).
        ramp_power: ``p`` of the start-up forgetting schedule: before the ``m``-th update
            (``m = 0, 1, ...``) the information is also multiplied by ``((m + 1) / (m + 2))^p``,
            so that at the end sequence ``j`` weighs ``~ (j / M)^p``. Early sequences are
            linearised far from the truth (a single sequence leaves most directions to the prior,
            and the MAP moves percent-level away); down-weighting their quadratic approximations
            removes the bias they leave. With uniform weights (``p = 0``) the estimator equals the
            batch maximum-likelihood one when noise dominates; ``p = 1`` costs ~15 % in standard
            deviation there. ``0`` disables it.
        prior_scale, prior_cross, prior_acc_bias, prior_gyr_bias: std of the initial prior around
            the spec values (relative, relative, g, rad/s).
        acc_prior_factor: multiplies the accelerometer's prior std (its scale, cross-axis and bias
            entries). 1: the values above. The field path (:func:`jaxcal.field.fit_field`) holds the
            accelerometer at its fit to the rests with :data:`HOLD` (its prior information 1e12 times
            the default's: the filter moved it by under 1e-9 relative in the tests), so that the filter
            corrects the gyroscope only.
    """

    sigma_acc: float | Float[Array, ""] = 1.8e-5
    n_iter: int | Int[Array, ""] = 4
    forgetting: float | Float[Array, ""] = 1.0
    q_scale: float | Float[Array, ""] = 0.0
    q_cross: float | Float[Array, ""] = 0.0
    q_acc_bias: float | Float[Array, ""] = 0.0
    q_gyr_bias: float | Float[Array, ""] = 0.0
    ramp_power: float | Float[Array, ""] = 1.0
    prior_scale: float | Float[Array, ""] = 0.03
    prior_cross: float | Float[Array, ""] = 0.02
    prior_acc_bias: float | Float[Array, ""] = 0.03
    prior_gyr_bias: float | Float[Array, ""] = 0.05
    acc_prior_factor: float | Float[Array, ""] = 1.0


HOLD = 1e-6
"""``OnlineHP.acc_prior_factor`` that holds the accelerometer where the filter starts."""


class OnlineState(NamedTuple):
    """Fixed-size filter state (traced).

    ``theta`` (Q,) is the current estimate; ``info`` (Q, Q) the information matrix of the data
    seen so far, *excluding* the fixed datasheet prior (which is never forgotten, so the estimate
    stays regularised by the spec tolerance even with forgetting); ``count`` the number of
    sequences seen (for the start-up schedule). The posterior information is ``info + Lambda_0``.
    """

    theta: Float[Array, " Q"]
    info: Float[Array, "Q Q"]
    count: Int[Array, ""]


def _prior_info(lay: _Layout, hp: OnlineHP, dtype: Any = None) -> Float[Array, "Q Q"]:
    """``Lambda_0``: the datasheet prior (around ``theta = 0``) with the std of ``hp``."""
    dtype = dtype or jnp.result_type(float)
    sd = _per_param(lay, hp.prior_scale, hp.prior_cross, hp.prior_acc_bias, hp.prior_gyr_bias)
    sd = sd.at[: lay.sea.stop].multiply(hp.acc_prior_factor).astype(dtype)  # the accelerometer's: D_a and e_a
    return jnp.diag(1.0 / sd**2)


def _init_state(lay: _Layout, hp: OnlineHP, dtype: Any = None) -> OnlineState:
    """Start at the spec values (``theta = 0``) with no data information."""
    dtype = dtype or jnp.result_type(float)
    return OnlineState(theta=jnp.zeros(lay.n, dtype), info=jnp.zeros((lay.n, lay.n), dtype), count=jnp.asarray(0))


def _predict(lay: _Layout, state: OnlineState, hp: OnlineHP) -> OnlineState:
    """Forgetting and process noise on the *data* information (the datasheet prior is kept).

    With ``lambda = forgetting * ((m + 1) / (m + 2))^ramp_power`` before the ``m``-th update and
    ``A = (I + lambda Lambda Q)^{-1} lambda``: ``Lambda <- A Lambda``, and the data information
    vector ``Lambda theta_data = (Lambda + Lambda_0) theta`` becomes ``A (Lambda + Lambda_0)
    theta``, so the predicted estimate is ``(A Lambda + Lambda_0)^{-1} A (Lambda + Lambda_0)
    theta``. ``lambda = 1``, ``Q = 0`` is exactly the identity.
    """
    info_0 = _prior_info(lay, hp, state.info.dtype)
    q = _per_param(lay, hp.q_scale, hp.q_cross, hp.q_acc_bias, hp.q_gyr_bias).astype(state.info.dtype) ** 2
    m = state.count.astype(state.info.dtype)
    lam = hp.forgetting * ((m + 1.0) / (m + 2.0)) ** hp.ramp_power
    eye = jnp.eye(state.info.shape[0], dtype=state.info.dtype)
    a = lam * jnp.linalg.inv(eye + lam * state.info * q[None, :])
    info = a @ state.info
    info = 0.5 * (info + info.T)
    eta = a @ ((state.info + info_0) @ state.theta)
    theta = jnp.linalg.solve(info + info_0, eta)
    return OnlineState(theta, info, state.count)


def _update(
    lay: _Layout,
    state: OnlineState,
    u_acc: Float[Array, "N 3"],
    u_gyr: Float[Array, "N 3"],
    mask: Float[Array, " N"],
    dt: float | Float[Array, ""],
    hp: OnlineHP,
    weight: Float[Array, " N"] | None = None,
    weight_t: Float[Array, " N"] | None = None,
) -> OnlineState:
    """Measurement update with one sequence: iterated GN on (theta, f_0) with the previous
    posterior ``|theta - theta_prev|^2_(Lambda + Lambda_0)`` as prior, then Schur-marginalise
    f_0; the stored information excludes ``Lambda_0`` again (it is never forgotten, and counted
    once: centring ``Lambda`` at ``theta_prev`` *and* adding ``|theta|^2_Lambda0`` would count the
    datasheet prior once per sequence and bias the estimate towards the spec values)."""
    p = state.theta.shape[0]
    theta_p, info_p = state.theta, state.info
    info_0 = _prior_info(lay, hp, theta_p.dtype)
    a0 = _calibrate_acc(lay, theta_p, u_acc[0])
    f0_ref = a0 / jnp.linalg.norm(a0)
    w_obs = 1.0 / hp.sigma_acc**2

    def res(z):
        return _sequence_residuals(lay, z[:p], z[p:], f0_ref, u_acc, u_gyr, mask, dt, weight, weight_t)

    def cost(z):
        d = z[:p] - theta_p
        return w_obs * jnp.sum(res(z) ** 2) + d @ (info_p + info_0) @ d

    def normal_eq(z):
        r, j = _residuals_and_jacobian(lay, z, f0_ref, u_acc, u_gyr, mask, dt, weight, weight_t)
        h = w_obs * (j.T @ j)
        g = w_obs * (j.T @ r)
        h = h.at[:p, :p].add(info_p + info_0)
        g = g.at[:p].add((info_p + info_0) @ (z[:p] - theta_p))
        return h, g

    def gn_step(_, z):
        # Gauss-Newton step with a safeguard: the best of step lengths 1, 1/2, ..., 1/8 and 0
        # (the cost never increases; far from the truth a full step can overshoot).
        h, g = normal_eq(z)
        step = jnp.linalg.solve(h, g)
        alphas = jnp.array([1.0, 0.5, 0.25, 0.125, 0.0], z.dtype)
        costs = jax.vmap(lambda a: cost(z - a * step))(alphas)
        costs = jnp.where(jnp.isfinite(costs), costs, jnp.inf)
        return z - alphas[jnp.argmin(costs)] * step

    z = jax.lax.fori_loop(0, hp.n_iter, gn_step, jnp.zeros(p + 2, theta_p.dtype).at[:p].set(theta_p))
    h, _ = normal_eq(z)
    h_tt, h_td, h_dd = h[:p, :p], h[:p, p:], h[p:, p:]
    info = h_tt - h_td @ jnp.linalg.solve(h_dd, h_td.T) - info_0
    return OnlineState(z[:p], 0.5 * (info + info.T), state.count + 1)


class Filter(NamedTuple):
    """The streaming filter of one parameter layout, as functions (optax-style; made by
    :func:`make_filter`).

    Static: a ``Filter`` is one choice of ``kind`` closed over once; as a ``jit`` argument it is
    static (a new kind compiles anew). Everything its functions take is traced: ``theta``
    (length :attr:`n_params`), states, data, ``dt`` and :class:`OnlineHP` may be ``vmap``-ed.

    Attributes:
        kind: ``"diag"`` or ``"affine"``.
        n_params: number of calibration parameters ``Q``: 12 (``diag``) or 21 (``affine``).
        unpack: ``theta -> Calib`` (``theta = 0``: the spec values).
        per_param: ``(scale, cross, acc_bias, gyr_bias) -> (Q,)``, a value per parameter class.
        calibrate_acc: ``(theta, u) -> a_c`` (g) of spec-converted accelerometer readings.
        calibrate_gyr: ``(theta, u) -> w_c`` (rad/s) of spec-converted gyroscope readings.
        predict_acc_readings: ``(theta, delta, f0_ref, u_gyr, mask, dt) -> (N, 3)`` noise-free
            spec-converted accelerometer readings of one sequence.
        sequence_residuals: ``(theta, delta, f0_ref, u_acc, u_gyr, mask, dt, weight=None, weight_t=None)``.
        residuals_and_jacobian: ``(z, f0_ref, u_acc, u_gyr, mask, dt, weight=None, weight_t=None) -> (r, J)``
            at ``z = (theta, delta)``: :attr:`sequence_residuals` and the Jacobian that ``update``
            uses, by the chain rule through the carried gravity.
        prior_info: ``(hp, dtype=None) -> Lambda_0``, the datasheet prior information.
        init: ``(hp, dtype=None) -> OnlineState`` at the spec values.
        predict: ``(state, hp) -> state``: forgetting and process noise.
        update: ``(state, u_acc, u_gyr, mask, dt, hp, weight=None, weight_t=None) -> state``: one sequence
            (``weight``: optional per-sample residual weights, :class:`SequenceBatch`).
    """

    kind: str
    n_params: int
    unpack: Callable[..., Calib]
    per_param: Callable[..., Array]
    calibrate_acc: Callable[..., Array]
    calibrate_gyr: Callable[..., Array]
    predict_acc_readings: Callable[..., Array]
    sequence_residuals: Callable[..., Array]
    residuals_and_jacobian: Callable[..., tuple[Array, Array]]
    prior_info: Callable[..., Array]
    init: Callable[..., OnlineState]
    predict: Callable[..., OnlineState]
    update: Callable[..., OnlineState]


@functools.lru_cache(maxsize=None)
def make_filter(kind: str) -> Filter:
    """The streaming filter of ``kind``, with its parameter layout computed once.

    One object per kind (cached), so a ``Filter`` passed as a static ``jit`` argument compiles
    once per kind.

    Args:
        kind: ``"diag"`` (``K = I + D`` with ``D`` diagonal: 6 + 6 parameters, eq. 4.6 truth) or
            ``"affine"`` (``D_a`` upper triangular, ``D_g`` full: 9 + 12 parameters).
    """
    lay = _layout(kind)
    bind = functools.partial
    return Filter(
        kind=kind,
        n_params=lay.n,
        unpack=bind(_unpack, lay),
        per_param=bind(_per_param, lay),
        calibrate_acc=bind(_calibrate_acc, lay),
        calibrate_gyr=bind(_calibrate_gyr, lay),
        predict_acc_readings=bind(_predict_acc_readings, lay),
        sequence_residuals=bind(_sequence_residuals, lay),
        residuals_and_jacobian=bind(_residuals_and_jacobian, lay),
        prior_info=bind(_prior_info, lay),
        init=bind(_init_state, lay),
        predict=bind(_predict, lay),
        update=bind(_update, lay),
    )


def forward_models(filt: Filter, theta: Float[Array, " Q"], acc_spec: Diag, gyr_spec: Diag) -> tuple[Affine, Affine]:
    """Forward sensor models ``y = S x + b`` (LSB) equal to the calibration ``theta``.

    ``x = K (y - b_spec) / s_spec - e``  <=>  ``y = S x + b`` with ``S = (K diag(1/s_spec))^{-1}``
    and ``b = b_spec + S e``.
    """
    c = filt.unpack(theta)

    def one(k, e, spec):
        a = k / spec.s[None, :]
        s = jnp.linalg.inv(a)
        return Affine(S=s, b=spec.b + s @ e)

    return one(c.K_a, c.e_a, acc_spec), one(c.K_g, c.e_g, gyr_spec)


def to_linear_cal(theta: Float[Array, " Q"], kind: str, acc_spec: Diag, gyr_spec: Diag) -> tuple[LinearCal, LinearCal]:
    """The applied calibrations ``x = A (y - b)`` (sensor units in, g and rad/s out) equal to ``theta``.

    ``x = K (y - b_spec) / s_spec - e`` is ``x = A (y - b)`` with ``A = K diag(1/s_spec)`` and
    ``b = b_spec + A^{-1} e``; ``A`` is returned as the inverse of the forward ``S = A^{-1}``
    (:meth:`~jaxcal.sensor.LinearCal.from_forward`). Call under ``jax.enable_x64(True)`` with
    float64 ``theta`` for full precision.

    Args:
        theta: filter parameters (e.g. :attr:`OnlineState.theta` or one row of a history).
        kind: (static) the layout of ``theta``, ``"diag"`` or ``"affine"``.
        acc_spec, gyr_spec: the datasheet models the filter ran with (eq. 4.8).

    Returns:
        ``(acc_cal, gyr_cal)`` as :class:`~jaxcal.sensor.LinearCal`.
    """
    fa, fg = forward_models(make_filter(kind), theta, acc_spec, gyr_spec)
    return LinearCal.from_forward(fa), LinearCal.from_forward(fg)


def diag_theta(acc: Diag, gyr: Diag, acc_spec: Diag, gyr_spec: Diag) -> Float[Array, " Q"]:
    """The ``"diag"``-layout parameters equal to diagonal models ``acc`` and ``gyr`` (e.g. a
    simulation's truth) for a filter run with the datasheet models ``acc_spec`` and ``gyr_spec``:
    ``K = s_spec / s``, ``e = (b - b_spec) / s`` (the inverse of :func:`to_linear_cal`)."""
    return jnp.concatenate(
        [acc_spec.s / acc.s - 1, (acc.b - acc_spec.b) / acc.s,
         gyr_spec.s / gyr.s - 1, (gyr.b - gyr_spec.b) / gyr.s]
    )


