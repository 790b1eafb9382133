"""The ``online`` filter with a small NN residual (``experiments/online_beyond.py``): the affine
backbone of :mod:`jaxcal.online` plus the thesis's network (Fig. 4.5), trained with the thesis's own
losses (eq. 4.10, 4.13) on a replay buffer, one ``lax.scan`` over sequences (:func:`online_nn_scan`).

Split from :mod:`jaxcal.online` (one concept per module): the parametric filter there, the NN
residual on top of it here. :class:`NNOnlineHP` and the states are traced (vmappable); ``kind`` and
``buffer_size`` are static.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from jaxtyping import Float, Int

from jaxcal.arrays import Array
from jaxcal.nn import THESIS_LEAKY_SLOPE, THESIS_ONLINE_WIDTHS
from jaxcal.normalise import Bounds, normalise
from jaxcal.online.filter import Filter, OnlineHP, OnlineState, make_filter
from jaxcal.online.passes import SequenceBatch
from jaxcal.online_thesis import acc_loss, gyro_loss

__all__ = [
    "NNOnlineHP",
    "NNState",
    "ZeroLastMLP",
    "nn_calibrate",
    "nn_calibrate_acc",
    "nn_calibrate_gyr",
    "online_nn_scan",
    "online_nn_scan_jit",
    "thesis_acc_loss",
    "thesis_gyro_loss",
]

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
