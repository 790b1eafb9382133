"""jaxcal's streaming self-calibration: an iterated information filter on exact consistency residuals.

The thesis (chapter 4) calibrates an accelerometer and a gyroscope against each other, one
sequence at a time, with two small neural networks. This module does the same job with a
*parametric* model estimated by maximum likelihood in streaming form, and reaches the
quantisation floor of Dataset 2.

Model. Raw counts are first spec-converted (eq. 4.8), ``u = (y - b_spec) / s_spec``; the
calibration is linear in ``u``::

    a_c = K_a u_a - e_a        (g)        w_c = K_g u_g - e_g        (rad/s)

with ``K = I + D``. ``kind="diag"``: ``D`` diagonal (thesis eq. 4.6 truth, 6 + 6 parameters);
``kind="affine"``: ``D_a`` upper triangular (6) and ``D_g`` full (9), 9 + 12 parameters. A rotation
applied to both sensor frames leaves every self-consistency residual unchanged, so a full affine
model has a 3-dimensional gauge freedom; restricting the accelerometer matrix to upper-triangular
fixes it (as in Tedaldi et al. 2014).

Measurement model of one sequence (body rotating about the sensor's centre, CONVENTIONS.md):
every accelerometer sample is gravity seen from the body, ``f_n = Phi_n(w_c)^T f_0`` with
``f_{n+1} = Exp(w_c,n dt)^T f_n`` (:func:`jaxcal.rotation.propagate_specific_force`) and an
unknown start direction ``f_0`` on the unit sphere (a 2-dof nuisance). The residuals
``r_n = u_a,n - K_a^{-1} (f_n + e_a)`` (all ``N`` samples, 3 components; formed in measurement
space, where the noise is) contain the thesis's two constraints as
special cases: unit norm of the static ends (eq. 4.13, L2) and gravity carried by the calibrated
gyroscope from the first to the last sample (eq. 4.11-4.12), and add every intermediate sample.
No static-gyro residual is used: at the static ends the raw gyro reads ``round(b)`` exactly, so
those samples carry a bias of up to 0.5 LSB that does not average out.

Estimator. The state is ``(theta, Lambda)``: the current estimate and its information matrix
(length ``n_params`` and ``n_params x n_params``; fixed size, independent of the number of sequences). For each new sequence:
(1) prediction: exponential forgetting ``Lambda <- lambda Lambda`` and additive process noise
``Q`` (covariance), computed as ``(I + lambda Lambda Q)^{-1} lambda Lambda`` so that ``Q = 0``
is exact; (2) a few Gauss-Newton iterations on ``|r(theta, f_0)|^2 / sigma^2 + |theta -
theta_prior|^2_Lambda`` (jointly in ``theta`` and the 2-dof ``f_0`` perturbation; Jacobians with
``jax.jacfwd``); (3) marginalisation of ``f_0`` by the Schur complement, which gives the new
``Lambda``. This is an iterated extended information filter (MAP relinearised per sequence). The
whole pass is one ``jax.lax.scan`` inside one ``jit``; hyperparameters are a NamedTuple of
(traceable) arrays, so passes ``vmap`` over them. Use float64 (the public entry points switch it
on locally): the rounding floor is 1e-5 relative.

Static and traced. The parameter layout (``kind``) is the only static choice: :func:`make_filter`
closes over it once and returns a :class:`Filter` (``init``, ``predict``, ``update``, ``unpack``,
``calibrate_acc`` ...), optax-style, so the functions inside take no ``kind``. The entry points
(:func:`online_scan`, :func:`online_pass`, :func:`online_nn_scan`, :func:`to_linear_cal`,
:func:`fit_online_recording`) take ``kind`` as a static argument (a new kind compiles anew);
:class:`OnlineHP`, :class:`NNOnlineHP`, states and data are traced (vmappable, no recompile).
:class:`Calib` is the filter's internal, spec-relative parameterisation; the interchange type is
:class:`~jaxcal.sensor.LinearCal` (:func:`to_linear_cal`).

Dimension letters: ``Q`` parameters (``n_params``), ``M`` sequences, ``N`` samples per sequence,
``L`` samples of a recording, ``B`` sequences in the replay buffer.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Float, Int

from jaxcal.arrays import Array
from jaxcal.nn import THESIS_LEAKY_SLOPE, THESIS_ONLINE_WIDTHS
from jaxcal.normalise import Bounds, normalise
from jaxcal.online_thesis import acc_loss, gyro_loss
from jaxcal.rotation import propagate_specific_force
from jaxcal.sensor import Affine, Diag, LinearCal
from jaxcal.sequences import pad_with_mask

__all__ = [
    "KINDS",
    "Filter",
    "NNOnlineHP",
    "NNState",
    "OnlineHP",
    "OnlineState",
    "SequenceBatch",
    "ZeroLastMLP",
    "fit_online_recording",
    "make_filter",
    "diag_theta",
    "nn_calibrate",
    "nn_calibrate_acc",
    "nn_calibrate_gyr",
    "online_nn_scan",
    "online_nn_scan_jit",
    "online_pass",
    "online_scan",
    "online_scan_jit",
    "spec_sequences",
    "tangent_basis",
    "thesis_acc_loss",
    "thesis_gyro_loss",
    "to_linear_cal",
]

KINDS = ("diag", "affine")
# Rotation steps per iteration of the sequence propagation's compiled loop (static; bit-identical for any
# value): 4 ran the filter 1.19x (diag) and 1.39x (affine) faster than 1, 8 and 16 less (benchmarks/online_unroll.py).
PROPAGATE_UNROLL = 4


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
    return u @ c.K_a.T - c.e_a


def _calibrate_gyr(lay: _Layout, theta: Float[Array, " Q"], u: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Calibrated body rate (rad/s) of spec-converted gyroscope readings ``u``."""
    c = _unpack(lay, theta)
    return u @ c.K_g.T - c.e_g


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
    c = _unpack(lay, theta)
    w_c = _calibrate_gyr(lay, theta, u_gyr) * mask[:, None]
    f0 = f0_ref + tangent_basis(f0_ref) @ delta
    f0 = f0 / jnp.linalg.norm(f0)
    f = propagate_specific_force(f0, w_c[:-1], dt, unroll=PROPAGATE_UNROLL)
    return jnp.linalg.solve(c.K_a, (f + c.e_a).T).T


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
    w = mask if weight is None else jnp.sqrt(weight) * mask
    r = u_acc - u_pred
    if weight_t is None:
        return (r * w[:, None]).reshape(-1)
    d = u_pred / jnp.linalg.norm(u_pred, axis=-1, keepdims=True)
    r_along = jnp.sum(r * d, axis=-1, keepdims=True) * d
    return (r_along * w[:, None] + (r - r_along) * (jnp.sqrt(weight_t) * mask)[:, None]).reshape(-1)


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
    sd = _per_param(lay, hp.prior_scale, hp.prior_cross, hp.prior_acc_bias, hp.prior_gyr_bias).astype(dtype)
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
        r = res(z)
        j = jax.jacfwd(res)(z)
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
        prior_info=bind(_prior_info, lay),
        init=bind(_init_state, lay),
        predict=bind(_predict, lay),
        update=bind(_update, lay),
    )


def _forward_models(filt: Filter, theta: Float[Array, " Q"], acc_spec: Diag, gyr_spec: Diag) -> tuple[Affine, Affine]:
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
    fa, fg = _forward_models(make_filter(kind), theta, acc_spec, gyr_spec)
    return LinearCal.from_forward(fa), LinearCal.from_forward(fg)


def diag_theta(acc: Diag, gyr: Diag, acc_spec: Diag, gyr_spec: Diag) -> Float[Array, " Q"]:
    """The ``"diag"``-layout parameters equal to diagonal models ``acc`` and ``gyr`` (e.g. a
    simulation's truth) for a filter run with the datasheet models ``acc_spec`` and ``gyr_spec``:
    ``K = s_spec / s``, ``e = (b - b_spec) / s`` (the inverse of :func:`to_linear_cal`)."""
    return jnp.concatenate(
        [acc_spec.s / acc.s - 1, (acc.b - acc_spec.b) / acc.s,
         gyr_spec.s / gyr.s - 1, (gyr.b - gyr_spec.b) / gyr.s]
    )


# ----------------------------------------------------------------------------------------------
# streaming passes
# ----------------------------------------------------------------------------------------------


class SequenceBatch(NamedTuple):
    """Sequences in spec-converted units, padded to a common length ``N`` with a mask (traced).

    ``weight`` and ``weight_t`` (optional; given together): each sample's residual weights along and
    across the predicted direction, apart from the mask (see :func:`_sequence_residuals`); a
    sequence whose weights are all 0 is skipped (no prediction, no update), so one batch of fixed
    shape serves every held-out fold (:mod:`jaxcal.field`).
    """

    u_acc: Float[Array, "M N 3"]
    u_gyr: Float[Array, "M N 3"]
    mask: Float[Array, "M N"]
    weight: Float[Array, "M N"] | None = None
    weight_t: Float[Array, "M N"] | None = None


def spec_sequences(acc: Float[Array, "M N 3"], gyr: Float[Array, "M N 3"], acc_spec: Diag, gyr_spec: Diag,
                   mask: Float[Array, "M N"] | None = None) -> SequenceBatch:
    """Spec-convert raw sequences (eq. 4.8) into a :class:`SequenceBatch`.

    Args:
        acc: (M, N, 3) raw accelerometer sequences (LSB).
        gyr: (M, N, 3) raw gyroscope sequences (LSB).
        acc_spec, gyr_spec: datasheet models (eq. 4.8).
        mask: (M, N) 1 on samples, 0 on padding; None: all ones.
    """
    if mask is None:
        mask = jnp.ones(acc.shape[:2], acc.dtype)
    return SequenceBatch((acc - acc_spec.b) / acc_spec.s, (gyr - gyr_spec.b) / gyr_spec.s, mask)


def _scan(filt: Filter, state0: OnlineState, batch: SequenceBatch, dt: float | Float[Array, ""],
          hp: OnlineHP) -> tuple[OnlineState, Float[Array, "M Q"]]:
    """``predict`` then ``update`` per sequence, in one ``lax.scan``."""

    if batch.weight is None:
        def step(state, seq):
            ua, ug, m = seq
            state = filt.update(filt.predict(state, hp), ua, ug, m, dt, hp)
            return state, state.theta

        return jax.lax.scan(step, state0, (batch.u_acc, batch.u_gyr, batch.mask))

    def weighted_step(state, seq):
        ua, ug, m, w, wt = seq
        new = filt.update(filt.predict(state, hp), ua, ug, m, dt, hp, w, wt)
        keep = jnp.any(w > 0)
        state = jax.tree_util.tree_map(lambda a, b: jnp.where(keep, a, b), new, state)
        return state, state.theta

    wt = batch.weight if batch.weight_t is None else batch.weight_t
    return jax.lax.scan(weighted_step, state0, (batch.u_acc, batch.u_gyr, batch.mask, batch.weight, wt))


def online_scan(
    state0: OnlineState, batch: SequenceBatch, dt: float | Float[Array, ""], hp: OnlineHP, kind: str
) -> tuple[OnlineState, Float[Array, "M Q"]]:
    """One streaming pass (pure): the final state and the estimate after every sequence (for
    convergence curves; not part of the state).

    Call under ``jit`` with ``kind`` static; everything else is traced (``vmap`` over ``hp`` runs
    several filters at once).

    Args:
        state0: initial state, e.g. ``make_filter(kind).init(hp, jnp.float64)``.
        batch: the sequences, spec-converted (:func:`spec_sequences`), visited in order.
        dt: sample period (s).
        hp: :class:`OnlineHP` (traced).
        kind: (static) ``"diag"`` or ``"affine"`` (:func:`make_filter`).
    """
    return _scan(make_filter(kind), state0, batch, dt, hp)


#: :func:`online_scan` compiled (``kind`` static), as :func:`online_pass` runs it.
online_scan_jit = jax.jit(online_scan, static_argnames=("kind",))


def online_pass(
    acc: Float[Array, "M N 3"],
    gyr: Float[Array, "M N 3"],
    dt: float | Float[Array, ""],
    acc_spec: Diag,
    gyr_spec: Diag,
    hp: OnlineHP = OnlineHP(),
    kind: str = "diag",
    mask: Float[Array, "M N"] | None = None,
) -> tuple[OnlineState, Float[Array, "M Q"]]:
    """Stream raw sequences (LSB) through the filter once, in float64 (one ``jit``; ``kind`` static).

    Args:
        acc, gyr: raw counts of ``M`` sequences of ``N`` samples, visited in order.
        dt: sample period (s).
        acc_spec, gyr_spec: datasheet models (initial point; eq. 4.8).
        hp: :class:`OnlineHP` (traced).
        kind: (static) ``"diag"`` or ``"affine"``.
        mask: optional (M, N) validity mask for padded sequences.

    Returns:
        Final :class:`OnlineState` and the estimate after each sequence, both float64 (use them
        inside ``jax.enable_x64(True)``; convert with :func:`to_linear_cal`).
    """
    with jax.enable_x64(True):
        f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
        aspec = Diag(f64(acc_spec.s), f64(acc_spec.b))
        gspec = Diag(f64(gyr_spec.s), f64(gyr_spec.b))
        batch = spec_sequences(f64(acc), f64(gyr), aspec, gspec, None if mask is None else f64(mask))
        hp64 = OnlineHP(*[jnp.asarray(v) for v in hp])
        state0 = make_filter(kind).init(hp64, jnp.float64)
        return online_scan_jit(state0, batch, f64(dt), hp64, kind)


# ----------------------------------------------------------------------------------------------
# recordings (CLI entry point)
# ----------------------------------------------------------------------------------------------


def fit_online_recording(
    acc: Float[Array, "L 3"],
    gyr: Float[Array, "L 3"],
    seq: Int[Array, " L"],
    t_or_dt: Float[Array, " L"] | float,
    acc_spec: Diag | None,
    gyr_spec: Diag | None,
    hp: OnlineHP = OnlineHP(),
    kind: str = "affine",
) -> tuple[LinearCal, LinearCal]:
    """Self-calibrate a recording of rotation sequences without labels (method ``online``).

    Each contiguous run of equal ``seq`` is one sequence, rotated about the sensor's centre;
    sequences are padded to one length (:func:`jaxcal.sequences.pad_with_mask`) and streamed in
    order through :func:`online_pass`.

    Args:
        acc, gyr: raw outputs (LSB).
        seq: sequence ids (samples of one sequence contiguous).
        t_or_dt: sample times (s) or the sample period.
        acc_spec, gyr_spec: datasheet models. If ``None``: the accelerometer scale is the median
            norm of the raw output (bias 0); the gyroscope bias is the median raw output of the
            first and last samples of the sequences and its scale is the median ratio of the
            integrated raw rate to the angle between the first and last accelerometer readings.
        hp: :class:`OnlineHP` (the prior is widened to 0.3 relative when a spec is estimated).
        kind: ``"affine"`` (default) or ``"diag"``.

    Returns:
        ``(acc_cal, gyr_cal)``: :class:`~jaxcal.sensor.LinearCal` applied calibrations ``x = A (y - b)``
        (numpy float64; ``A`` is ``numpy.linalg.inv`` of the filter's forward ``S``).
    """
    acc = np.asarray(acc, np.float64)
    gyr = np.asarray(gyr, np.float64)
    if np.ndim(t_or_dt) == 0:
        dt = float(t_or_dt)
    else:
        dt = float(np.median(np.diff(np.asarray(t_or_dt, np.float64))))
    pa, mk = pad_with_mask(acc, seq)
    pg, _ = pad_with_mask(gyr, seq)
    lengths = mk.sum(1).astype(int)
    if acc_spec is None:
        s = float(np.median(np.linalg.norm(acc, axis=1)))
        acc_spec = Diag(np.full(3, s), np.zeros(3))
        hp = hp._replace(prior_scale=max(float(hp.prior_scale), 0.3), prior_acc_bias=max(float(hp.prior_acc_bias), 0.3))
    if gyr_spec is None:
        ends = np.concatenate([pg[:, 0], pg[np.arange(len(pg)), lengths - 1]])
        b = np.median(ends, axis=0)
        ua = (pa - np.asarray(acc_spec.b)) / np.asarray(acc_spec.s)
        a1 = ua[:, 0]
        an = ua[np.arange(len(ua)), lengths - 1]
        cosang = np.sum(a1 * an, 1) / (np.linalg.norm(a1, axis=1) * np.linalg.norm(an, axis=1))
        ang = np.arccos(np.clip(cosang, -1.0, 1.0))
        raw_ang = np.linalg.norm(((pg - b) * mk[..., None]).sum(1) * dt, axis=1)
        ok = ang > 0.05
        scale = float(np.median(raw_ang[ok] / ang[ok])) if np.any(ok) else 1.0
        gyr_spec = Diag(np.full(3, scale), b)
        hp = hp._replace(prior_scale=max(float(hp.prior_scale), 0.3), prior_gyr_bias=max(float(hp.prior_gyr_bias), 0.3))
    state, _ = online_pass(pa, pg, dt, acc_spec, gyr_spec, hp, kind, mask=mk)
    with jax.enable_x64(True):
        f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
        models = _forward_models(make_filter(kind), state.theta, Diag(f64(acc_spec.s), f64(acc_spec.b)),
                                 Diag(f64(gyr_spec.s), f64(gyr_spec.b)))
    am, gm = (LinearCal(np.linalg.inv(np.asarray(m.S)), np.asarray(m.b)) for m in models)
    return am, gm


# ----------------------------------------------------------------------------------------------
# NN variant: affine backbone (the filter above) + small NN residual trained with the thesis's losses
# ----------------------------------------------------------------------------------------------


class ZeroLastMLP(nn.Module):
    """Thesis Fig. 4.5 network (3-5-10-5-3, leaky ReLU 0.1) with a zero-initialised output layer."""

    widths: tuple[int, ...] = THESIS_ONLINE_WIDTHS
    slope: float = THESIS_LEAKY_SLOPE

    @nn.compact
    def __call__(self, x: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
        for w in self.widths:
            x = nn.leaky_relu(nn.Dense(w)(x), negative_slope=self.slope)
        return nn.Dense(3, kernel_init=nn.initializers.zeros)(x)


class NNOnlineHP(NamedTuple):
    """Hyperparameters of the NN residual. Traced: every field may be an array (vmappable).

    Attributes:
        learning_rate: Adam step size for both networks.
        steps: Adam steps per network per new sequence (alternating acc then gyro, as the thesis).
        acc_loss_weight: ``w`` of eq. 4.13 (thesis: 0.90).
        out_scale_acc, out_scale_gyr: the network output is multiplied by these (g, rad/s).
    """

    learning_rate: float | Float[Array, ""] = 1e-3
    steps: int | Int[Array, ""] = 2
    acc_loss_weight: float | Float[Array, ""] = 0.9
    out_scale_acc: float | Float[Array, ""] = 1e-3
    out_scale_gyr: float | Float[Array, ""] = 1e-3


class NNState(NamedTuple):
    """State of the NN variant: filter state, two residual networks, Adam states, replay ring."""

    filt: OnlineState
    params_a: Any
    params_g: Any
    opt_a: Any
    opt_g: Any
    buf_a: Float[Array, "B N 3"]
    buf_g: Float[Array, "B N 3"]
    buf_w: Float[Array, " B"]
    count: Int[Array, ""]


def nn_calibrate(sensor: str, filt: Filter, theta, params, raw_u, bounds: Bounds, hp: NNOnlineHP, mlp=ZeroLastMLP()):
    """Backbone + NN residual calibration of one sensor's spec-converted readings ``raw_u``.

    Args:
        sensor: ``"acc"`` or ``"gyr"`` (static): the backbone's ``calibrate_<sensor>`` and
            ``hp.out_scale_<sensor>``.
        filt: the backbone's :class:`Filter` (static).
        theta: (Q,) backbone parameters (traced).
        params: the residual network's parameters (traced).
        raw_u: (..., 3) spec-converted readings.
        bounds: eq. 3.6 bounds of the network input (spec-converted units).
        hp: :class:`NNOnlineHP` (traced).
        mlp: the residual network (static).
    """
    backbone = filt.calibrate_acc if sensor == "acc" else filt.calibrate_gyr
    scale = hp.out_scale_acc if sensor == "acc" else hp.out_scale_gyr
    return backbone(theta, raw_u) + scale * mlp.apply({"params": params}, normalise(raw_u, bounds))


nn_calibrate_acc = functools.partial(nn_calibrate, "acc")  # the accelerometer's :func:`nn_calibrate`
nn_calibrate_gyr = functools.partial(nn_calibrate, "gyr")  # the gyroscope's :func:`nn_calibrate`


def _buffer_mean(err: Float[Array, " B"], wts: Float[Array, " B"]) -> Float[Array, ""]:
    """Mean of per-sequence losses over the filled slots of a replay buffer (weights 0 or 1)."""
    return jnp.sum(wts * err) / jnp.maximum(jnp.sum(wts), 1.0)


def thesis_gyro_loss(a_c: Float[Array, "B N 3"], w_c: Float[Array, "B N 3"], dt, wts: Float[Array, " B"]) -> Float[Array, ""]:
    """Eq. 4.10 in the physical convention, :func:`jaxcal.online_thesis.gyro_loss` per sequence,
    averaged over the buffer's sequences with weights ``wts``.

    Args:
        a_c: (B, N, 3) calibrated specific force of the buffer's sequences (g).
        w_c: (B, N, 3) calibrated rates (rad/s).
        dt: sample period (s).
        wts: (B,) weight per buffer slot (1 filled, 0 empty).
    """
    return _buffer_mean(jax.vmap(lambda w, a: gyro_loss(w, a, dt))(w_c, a_c), wts)


def thesis_acc_loss(a_c: Float[Array, "B N 3"], w_c: Float[Array, "B N 3"], dt, wts: Float[Array, " B"], w: Any) -> Float[Array, ""]:
    """Eq. 4.13 in the physical convention, :func:`jaxcal.online_thesis.acc_loss` per sequence
    (``w MSE(R_tot^T a_c,1, a_c,N) + (1 - w) |1 - |a_c,N||``; gradients reach ``a_c,1`` too),
    averaged over the buffer's sequences with weights ``wts``.

    Args:
        a_c: (B, N, 3) calibrated specific force of the buffer's sequences (g).
        w_c: (B, N, 3) calibrated rates (rad/s).
        dt: sample period (s).
        wts: (B,) weight per buffer slot (1 filled, 0 empty).
        w: weight ``w`` of eq. 4.13 (traced).
    """
    return _buffer_mean(jax.vmap(lambda a1, an, ws: acc_loss(a1, an, ws, dt, w))(a_c[:, 0], a_c[:, -1], w_c), wts)


def online_nn_scan(
    key: jax.Array,
    batch: SequenceBatch,
    dt: float | Float[Array, ""],
    bounds_a: Bounds,
    bounds_g: Bounds,
    hp: OnlineHP,
    nn_hp: NNOnlineHP,
    kind: str,
    buffer_size: int,
) -> tuple[NNState, tuple[Float[Array, "M Q"], Any, Any]]:
    """Stream sequences through backbone filter + NN residuals with a bounded replay buffer.

    For every new sequence: (1) the filter update of the backbone (:attr:`Filter.update`); (2) the
    sequence enters a ring buffer of ``buffer_size`` sequences; (3) ``nn_hp.steps`` Adam steps on
    the accelerometer residual network with eq. 4.13 (gyroscope fixed), then on the gyroscope
    network with eq. 4.10 (accelerometer fixed), over the whole buffer. Unmasked sequences only
    (Dataset 2). Returns the final state and per-sequence histories of theta and both networks.

    Args:
        key: PRNG key of the networks' initial weights.
        batch: the sequences, spec-converted (:func:`spec_sequences`), visited in order.
        dt: sample period (s).
        bounds_a, bounds_g: eq. 3.6 input bounds of the two networks (spec-converted units).
        hp: :class:`OnlineHP` of the backbone (traced).
        nn_hp: :class:`NNOnlineHP` (traced).
        kind: (static) the backbone's layout, ``"diag"`` or ``"affine"``.
        buffer_size: (static) number of sequences in the replay ring.
    """
    filt = make_filter(kind)
    mlp = ZeroLastMLP()
    ka, kg = jax.random.split(key)
    pa0 = mlp.init(ka, jnp.zeros((1, 3), batch.u_acc.dtype))["params"]
    pg0 = mlp.init(kg, jnp.zeros((1, 3), batch.u_acc.dtype))["params"]
    opt = optax.adam(nn_hp.learning_rate)
    n = batch.u_acc.shape[1]
    dtype = batch.u_acc.dtype
    st0 = NNState(
        filt=filt.init(hp, dtype),
        params_a=pa0,
        params_g=pg0,
        opt_a=opt.init(pa0),
        opt_g=opt.init(pg0),
        buf_a=jnp.zeros((buffer_size, n, 3), dtype),
        buf_g=jnp.zeros((buffer_size, n, 3), dtype),
        buf_w=jnp.zeros((buffer_size,), dtype),
        count=jnp.asarray(0),
    )

    def step(st: NNState, seq):
        ua, ug, m = seq
        fs = filt.update(filt.predict(st.filt, hp), ua, ug, m, dt, hp)
        i = st.count % buffer_size
        buf_a = st.buf_a.at[i].set(ua)
        buf_g = st.buf_g.at[i].set(ug)
        buf_w = st.buf_w.at[i].set(1.0)
        theta = jax.lax.stop_gradient(fs.theta)

        def a_loss(pa, pg):
            a_c = nn_calibrate("acc", filt, theta, pa, buf_a, bounds_a, nn_hp, mlp)
            w_c = jax.lax.stop_gradient(nn_calibrate("gyr", filt, theta, pg, buf_g, bounds_g, nn_hp, mlp))
            return thesis_acc_loss(a_c, w_c, dt, buf_w, nn_hp.acc_loss_weight)

        def g_loss(pg, pa):
            a_c = jax.lax.stop_gradient(nn_calibrate("acc", filt, theta, pa, buf_a, bounds_a, nn_hp, mlp))
            w_c = nn_calibrate("gyr", filt, theta, pg, buf_g, bounds_g, nn_hp, mlp)
            return thesis_gyro_loss(a_c, w_c, dt, buf_w)

        def train(_, carry):
            pa, pg, oa, og = carry
            ga = jax.grad(a_loss)(pa, pg)
            upd, oa = opt.update(ga, oa, pa)
            pa = optax.apply_updates(pa, upd)
            gg = jax.grad(g_loss)(pg, pa)
            upd, og = opt.update(gg, og, pg)
            pg = optax.apply_updates(pg, upd)
            return pa, pg, oa, og

        pa, pg, oa, og = jax.lax.fori_loop(0, nn_hp.steps, train, (st.params_a, st.params_g, st.opt_a, st.opt_g))
        new = NNState(fs, pa, pg, oa, og, buf_a, buf_g, buf_w, st.count + 1)
        return new, (fs.theta, pa, pg)

    return jax.lax.scan(step, st0, (batch.u_acc, batch.u_gyr, batch.mask))


online_nn_scan_jit = jax.jit(online_nn_scan, static_argnames=("kind", "buffer_size"))
