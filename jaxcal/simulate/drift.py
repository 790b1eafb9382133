"""Dataset 2 motion over time with temperature drift, white noise and bias random walk.

The thesis claims its online calibration adapts to a changing sensor but never shows it. This
simulator produces ``n_seq`` Dataset 2 sequences (eq. 4.4 motion from uniform start orientations)
spread evenly over ``duration_s`` seconds, while the sensor changes:

* temperature ``T(t) = T0 + rise * (1 - exp(-t / tau))`` (warm-up; ``tau -> inf`` is linear);
* per axis ``s(T) = s0 (1 + k_s (T - T0))`` and a physical-unit bias
  ``beta(t) = k_b (T - T0) + rw(t)`` (CONVENTIONS ``temperature_scale``/``temperature_bias``,
  plus a bias random walk ``rw`` with density ``bias_rw`` unit/sqrt(s));
* white noise of density ``noise_density`` (unit/sqrt(Hz)), per sample ``sigma = density *
  sqrt(fs)`` (the Allan-variance convention);
* output ``y = round(s(T) (x + beta + n) + b0)`` (LSB), i.e. the per-sequence truth is
  ``Diag(s(T), b0 + s(T) beta)``.

Within one 1-s sequence the temperature and the random walk are held constant (their change
over 1 s is 1e-3 of that over the hour). Tempcos are drawn per axis with random sign and
magnitude uniform in ``[0.5, 1] x`` the configured value. Everything is a pure function of the key.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.rotation import propagate_specific_force, random_unit_vectors
from jaxcal.sensor import Diag
from jaxcal.sequences import Sequences
from jaxcal.simulate.dataset2 import Dataset2Config, random_truth, rate_profile

DEG = math.pi / 180.0


class DriftConfig(NamedTuple):
    """Parameters of :func:`simulate_drift` (defaults: one hour, +15 degC warm-up, MPU-6050-class).

    Units: accelerometer g, gyroscope rad/s, temperature degC, time s. Static: :func:`simulate_drift`
    takes the whole config as a static argument, so a new value compiles anew.

    Attributes:
        n_seq: sequences ``M`` spread evenly over the run.
        duration_s: length of the run (s).
        t0_degc: start temperature ``T0``.
        temp_rise: warm-up rise (degC).
        temp_tau_s: warm-up time constant (s).
        acc_bias_tc, gyr_bias_tc: bias tempco magnitude (unit/degC; drawn per axis, see module).
        acc_scale_tc, gyr_scale_tc: scale tempco magnitude (1/degC).
        acc_noise_density, gyr_noise_density: white-noise density (unit/sqrt(Hz)).
        acc_bias_rw, gyr_bias_rw: bias random-walk density (unit/sqrt(s)); 0: none.
        motion: Dataset 2 motion and sensor settings of each sequence.
    """

    n_seq: int = 1000
    duration_s: float = 3600.0
    t0_degc: float = 25.0
    temp_rise: float = 15.0
    temp_tau_s: float = 900.0
    acc_bias_tc: float = 0.5e-3  # g / degC
    gyr_bias_tc: float = 0.01 * DEG  # rad/s / degC
    acc_scale_tc: float = 2e-4  # 1 / degC (0.02 %/degC)
    gyr_scale_tc: float = 2e-4
    acc_noise_density: float = 400e-6  # g / sqrt(Hz)
    gyr_noise_density: float = 0.005 * DEG  # rad/s / sqrt(Hz)
    acc_bias_rw: float = 0.0  # g / sqrt(s)
    gyr_bias_rw: float = 0.0  # rad/s / sqrt(s)
    motion: Dataset2Config = Dataset2Config()


class DriftTruth(NamedTuple):
    """Per-sequence truth: models (arrays (M, 3)), temperature and start time of each sequence."""

    acc_model: Diag
    gyr_model: Diag
    temp: Float[Array, " M"]
    t_start: Float[Array, " M"]
    acc_bias_tc: Float[Array, "3"]
    gyr_bias_tc: Float[Array, "3"]
    acc_scale_tc: Float[Array, "3"]
    gyr_scale_tc: Float[Array, "3"]
    acc_model0: Diag
    gyr_model0: Diag


class DriftData(NamedTuple):
    """Sequences (raw LSB + noise-free truth) and the time-varying truth."""

    seqs: Sequences
    truth: DriftTruth
    acc_spec: Diag
    gyr_spec: Diag
    dt: float


def temperature(t: Float[Array, "..."], config: DriftConfig) -> Float[Array, "..."]:
    """Warm-up profile ``T0 + rise (1 - exp(-t / tau))`` (degC).

    Args:
        t: times since the start (s).
        config: ``t0_degc``, ``temp_rise`` and ``temp_tau_s`` are read.
    """
    return config.t0_degc + config.temp_rise * (1.0 - jnp.exp(-t / config.temp_tau_s))


def _tempco(key: jax.Array, value: float) -> Array:
    ks, km = jax.random.split(key)
    sign = jnp.where(jax.random.bernoulli(ks, 0.5, (3,)), 1.0, -1.0)
    return sign * value * jax.random.uniform(km, (3,), minval=0.5, maxval=1.0)


def drift_models(
    t: Float[Array, " M"],
    temp: Float[Array, " M"],
    model0: Diag,
    bias_tc: Float[Array, "3"],
    scale_tc: Float[Array, "3"],
    rw: Float[Array, "M 3"],
    t0_degc: float,
) -> Diag:
    """Truth at each time: ``s = s0 (1 + k_s dT)``, ``b = b0 + s (k_b dT + rw)`` (LSB).

    Args:
        t: (M,) sequence start times (s).
        temp: (M,) temperature at those times (degC).
        model0: the sensor at ``T0`` (arrays (3,)).
        bias_tc: (3,) bias tempco (unit/degC).
        scale_tc: (3,) scale tempco (1/degC).
        rw: (M, 3) bias random walk (physical unit).
        t0_degc: reference temperature ``T0`` (degC).
    """
    d_t = (temp - t0_degc)[:, None]
    s = model0.s[None, :] * (1.0 + scale_tc[None, :] * d_t)
    b = model0.b[None, :] + s * (bias_tc[None, :] * d_t + rw)
    return Diag(s=s, b=b)


def _random_walk(key: jax.Array, t: Float[Array, " M"], density: float) -> Float[Array, "M 3"]:
    """Brownian motion sampled at times ``t`` (starting at 0 at ``t[0]``)."""
    dtm = jnp.diff(t, prepend=t[:1])
    steps = jax.random.normal(key, (t.shape[0], 3)) * density * jnp.sqrt(dtm)[:, None]
    return jnp.cumsum(steps, axis=0)


def measure(model: Diag, x: Float[Array, "L 3"], beta_noise: Float[Array, "L 3"] | None = None) -> Float[Array, "L 3"]:
    """``round(s x + b)`` for one time's model (arrays (3,)); optional extra physical-unit noise.

    Args:
        model: the sensor at one time (arrays (3,)).
        x: (L, 3) true quantity (g or rad/s).
        beta_noise: optional (L, 3) noise added to ``x`` (physical unit).
    """
    if beta_noise is not None:
        x = x + beta_noise
    return jnp.round(model.s * x + model.b)


@partial(jax.jit, static_argnames=("config",))
def _simulate(key: jax.Array, config: DriftConfig):
    return _simulate_drift(key, config)


def simulate_drift(key: jax.Array, config: DriftConfig = DriftConfig()) -> DriftData:
    """Jitted :func:`_simulate_drift` (``config`` static); see there.

    Args:
        key: PRNG key.
        config: :class:`DriftConfig` (static: a new config compiles anew).
    """
    return _simulate(key, config)


def _simulate_drift(key: jax.Array, config: DriftConfig = DriftConfig()) -> DriftData:
    """Simulate ``config.n_seq`` sequences over ``config.duration_s`` with a drifting, noisy IMU.

    Args:
        key: PRNG key.
        config: :class:`DriftConfig`; set the tempcos to 0 for a constant sensor with noise only,
            and the noise densities to 0 for quantisation only.

    Returns:
        :class:`DriftData`; ``seqs.acc_true`` / ``gyr_true`` are noise-free truth (g, rad/s).
    """
    mc = config.motion
    k_acc, k_gyr, k_tc, k_w, k_f, k_na, k_ng, k_rwa, k_rwg = jax.random.split(key, 9)
    acc0 = random_truth(k_acc, mc.acc_lsb_per_g, mc.scale_tol, mc.acc_bias_max)
    gyr0 = random_truth(k_gyr, mc.gyr_lsb_per_rads, mc.scale_tol, mc.gyr_bias_max)
    kt = jax.random.split(k_tc, 4)
    a_btc = _tempco(kt[0], config.acc_bias_tc)
    g_btc = _tempco(kt[1], config.gyr_bias_tc)
    a_stc = _tempco(kt[2], config.acc_scale_tc)
    g_stc = _tempco(kt[3], config.gyr_scale_tc)

    m, n = config.n_seq, mc.n_samples
    dt = 1.0 / mc.fs
    t_start = jnp.arange(m) * (config.duration_s / m)
    temp = temperature(t_start, config)
    rw_a = _random_walk(k_rwa, t_start, config.acc_bias_rw)
    rw_g = _random_walk(k_rwg, t_start, config.gyr_bias_rw)
    acc_m = drift_models(t_start, temp, acc0, a_btc, a_stc, rw_a, config.t0_degc)
    gyr_m = drift_models(t_start, temp, gyr0, g_btc, g_stc, rw_g, config.t0_degc)

    w_max = jax.random.uniform(k_w, (m, 3), minval=-mc.w_max, maxval=mc.w_max)
    w = jax.vmap(rate_profile, in_axes=(0, None))(w_max, n)
    f0 = random_unit_vectors(k_f, m)
    f = jax.vmap(lambda f0_, w_: propagate_specific_force(f0_, w_[:-1], dt))(f0, w)
    sig_a = config.acc_noise_density * math.sqrt(mc.fs)
    sig_g = config.gyr_noise_density * math.sqrt(mc.fs)
    na = sig_a * jax.random.normal(k_na, f.shape)
    ng = sig_g * jax.random.normal(k_ng, w.shape)
    acc = jnp.round(acc_m.s[:, None, :] * (f + na) + acc_m.b[:, None, :])
    gyr = jnp.round(gyr_m.s[:, None, :] * (w + ng) + gyr_m.b[:, None, :])
    zeros = jnp.zeros(3)
    return DriftData(
        seqs=Sequences(acc=acc, gyr=gyr, acc_true=f, gyr_true=w),
        truth=DriftTruth(acc_m, gyr_m, temp, t_start, a_btc, g_btc, a_stc, g_stc, acc0, gyr0),
        acc_spec=Diag(jnp.full(3, mc.acc_lsb_per_g), zeros),
        gyr_spec=Diag(jnp.full(3, mc.gyr_lsb_per_rads), zeros),
        dt=dt,
    )


__all__ = ["DEG", "DriftConfig", "DriftData", "DriftTruth", "drift_models", "measure", "simulate_drift", "temperature"]
