"""Dataset 2 of the thesis (section 4.2): rotation sequences between two static orientations.

Each sequence has ``n_samples`` (101) samples at ``fs`` (100 Hz). The body rate on every axis is
the parabola ``w_k(t) = 4 w_max,k (t - t^2)``, ``t in [0, 1]``, with ``w_max,k ~ U[-0.35, 0.35]``
rad/s (eq. 4.4), so the first and last samples are static. The start orientation is uniform on
SO(3); the specific force starts at ``R0^T (0, 0, 1)`` g and follows the **physical** convention
``f_{n+1} = Exp(w_n dt)^T f_n`` (thesis eq. 4.5 as printed applies ``R_n``, the opposite sign;
see ``CONVENTIONS.md``). Sensor outputs are ``round(s * x + b)`` per axis (eq. 4.6).

Datasheet ("spec") values are those of a +-2 g / +-250 deg/s 16-bit IMU (MPU-6050 class):
16384 LSB/g and 131 LSB/(deg/s) = 7505.75 LSB/(rad/s), zero bias. The true scale of each axis is
within +-3 % of spec and the true bias a few hundred counts (uniform, ``bias_max``). All of
these are arguments of :class:`Dataset2Config`.

Test sets (section 4.2): 500 static orientations uniform on the sphere for the accelerometer,
and ``w_k(t) = 0.35 sin(t)``, ``t in [0, 2 pi]``, 500 samples on every gyroscope axis (eq. 4.7).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.constants import ACC_LSB_PER_G, GYR_LSB_PER_DPS
from jaxcal.rotation import propagate_specific_force, random_unit_vectors
from jaxcal.sensor import Diag, diag_forward
from jaxcal.sequences import Dataset2, Samples, Sequences

__all__ = [
    "ACC_SPEC_LSB_PER_G",
    "Dataset2",
    "Dataset2Config",
    "GYR_SPEC_LSB_PER_DPS",
    "GYR_SPEC_LSB_PER_RADS",
    "Samples",
    "Sequences",
    "dataset2",
    "dataset2_jit",
    "random_truth",
    "rate_profile",
    "simulate_sequences",
    "test_sets",
]

ACC_SPEC_LSB_PER_G = ACC_LSB_PER_G
GYR_SPEC_LSB_PER_DPS = GYR_LSB_PER_DPS
GYR_SPEC_LSB_PER_RADS = GYR_SPEC_LSB_PER_DPS * 180.0 / math.pi  # 7505.747...


class Dataset2Config(NamedTuple):
    """Every parameter of the Dataset 2 simulation (defaults: thesis section 4.2).

    Static: the sizes set shapes, so :func:`dataset2` is jitted with the config static
    (:data:`dataset2_jit`); a new config recompiles.

    Attributes:
        n_train: training sequences.
        n_val: validation sequences.
        n_samples: samples per sequence.
        fs: sampling rate (Hz).
        w_max: bound of ``w_max,k ~ U[-w_max, w_max]`` (rad/s, eq. 4.4).
        n_test_acc: static orientations of the accelerometer test set.
        n_test_gyr: samples of the gyroscope test set.
        test_gyr_amplitude: amplitude of the gyroscope test rate ``A sin(t)`` (rad/s).
        acc_lsb_per_g: datasheet accelerometer scale (LSB per g).
        gyr_lsb_per_rads: datasheet gyroscope scale (LSB per rad/s).
        scale_tol: true scale per axis uniform within ``+-scale_tol`` (relative) of the datasheet.
        acc_bias_max: true accelerometer bias per axis uniform in ``+-acc_bias_max`` (LSB).
        gyr_bias_max: true gyroscope bias per axis uniform in ``+-gyr_bias_max`` (LSB).
        round_counts: round the outputs to whole counts (eq. 4.6).
    """

    n_train: int = 500
    n_val: int = 100
    n_samples: int = 101
    fs: float = 100.0
    w_max: float = 0.35
    n_test_acc: int = 500
    n_test_gyr: int = 500
    test_gyr_amplitude: float = 0.35
    acc_lsb_per_g: float = ACC_SPEC_LSB_PER_G
    gyr_lsb_per_rads: float = GYR_SPEC_LSB_PER_RADS
    scale_tol: float = 0.03
    acc_bias_max: float = 400.0
    gyr_bias_max: float = 300.0
    round_counts: bool = True


def rate_profile(w_max: Float[Array, "3"], n_samples: int) -> Float[Array, "N 3"]:
    """Eq. 4.4: ``w_k(t) = 4 w_max,k (t - t^2)`` on ``n_samples`` points of ``t in [0, 1]``.

    Args:
        w_max: (3,) peak rate per axis (rad/s; traced).
        n_samples: number of points (static: it sets the shape).
    """
    t = jnp.linspace(0.0, 1.0, n_samples)[:, None]
    return 4.0 * w_max[None, :] * (t - t**2)


def _measure(p: Diag, x: Array, round_counts: bool) -> Array:
    y = diag_forward(p, x)
    return jnp.round(y) if round_counts else y


def random_truth(key: jax.Array, lsb_per_unit: float, scale_tol: float, bias_max: float) -> Diag:
    """True per-axis scale within ``+-scale_tol`` of spec and bias uniform in ``+-bias_max`` LSB.

    Args:
        key: PRNG key.
        lsb_per_unit: datasheet scale (LSB per g or per rad/s).
        scale_tol: relative scale tolerance.
        bias_max: bias bound (LSB).
    """
    ks, kb = jax.random.split(key)
    s = lsb_per_unit * (1.0 + jax.random.uniform(ks, (3,), minval=-scale_tol, maxval=scale_tol))
    b = jax.random.uniform(kb, (3,), minval=-bias_max, maxval=bias_max)
    return Diag(s=s, b=b)


def simulate_sequences(
    key: jax.Array, n_seq: int, acc_model: Diag, gyr_model: Diag, config: Dataset2Config
) -> Sequences:
    """``n_seq`` sequences of eq. 4.4 motion from uniform start orientations, measured by eq. 4.6.

    Args:
        key: PRNG key.
        n_seq: number of sequences (static: it sets the shape).
        acc_model: the true accelerometer.
        gyr_model: the true gyroscope.
        config: :class:`Dataset2Config` (static: ``n_samples`` sets the shape).
    """
    kw, kf = jax.random.split(key)
    dt = 1.0 / config.fs
    w_max = jax.random.uniform(kw, (n_seq, 3), minval=-config.w_max, maxval=config.w_max)
    w = jax.vmap(rate_profile, in_axes=(0, None))(w_max, config.n_samples)  # (M, N, 3)
    f0 = random_unit_vectors(kf, n_seq)  # R0^T e_z for R0 uniform on SO(3)
    # f_{n+1} = Exp(w_n dt)^T f_n for n = 0..N-2 -> N samples.
    f = jax.vmap(lambda f0_, w_: propagate_specific_force(f0_, w_[:-1], dt))(f0, w)
    return Sequences(
        acc=_measure(acc_model, f, config.round_counts),
        gyr=_measure(gyr_model, w, config.round_counts),
        acc_true=f,
        gyr_true=w,
    )


def test_sets(key: jax.Array, acc_model: Diag, gyr_model: Diag, config: Dataset2Config) -> tuple[Samples, Samples]:
    """Section 4.2 test sets: static orientations (acc) and ``0.35 sin(t)`` on all axes (gyro).

    Args:
        key: PRNG key.
        acc_model: the true accelerometer.
        gyr_model: the true gyroscope.
        config: :class:`Dataset2Config` (static: the sizes set the shapes).
    """
    f = random_unit_vectors(key, config.n_test_acc)
    t = jnp.linspace(0.0, 2.0 * math.pi, config.n_test_gyr)
    w = jnp.repeat((config.test_gyr_amplitude * jnp.sin(t))[:, None], 3, axis=1)
    return (
        Samples(_measure(acc_model, f, config.round_counts), f),
        Samples(_measure(gyr_model, w, config.round_counts), w),
    )


def dataset2(key: jax.Array, config: Dataset2Config = Dataset2Config()) -> Dataset2:
    """Simulate Dataset 2 (training, validation and test sets) from one PRNG key.

    Args:
        key: PRNG key; the same key gives the same dataset.
        config: all simulation parameters (defaults: thesis section 4.2).

    Returns:
        :class:`Dataset2` with raw counts, truth, the true and the spec sensor models.
    """
    k_acc, k_gyr, k_tr, k_va, k_te = jax.random.split(key, 5)
    acc_model = random_truth(k_acc, config.acc_lsb_per_g, config.scale_tol, config.acc_bias_max)
    gyr_model = random_truth(k_gyr, config.gyr_lsb_per_rads, config.scale_tol, config.gyr_bias_max)
    train = simulate_sequences(k_tr, config.n_train, acc_model, gyr_model, config)
    val = simulate_sequences(k_va, config.n_val, acc_model, gyr_model, config)
    test_acc, test_gyr = test_sets(k_te, acc_model, gyr_model, config)
    zeros = jnp.zeros(3)
    return Dataset2(
        train=train,
        val=val,
        test_acc=test_acc,
        test_gyr=test_gyr,
        acc_true_model=acc_model,
        gyr_true_model=gyr_model,
        acc_spec=Diag(jnp.full(3, config.acc_lsb_per_g), zeros),
        gyr_spec=Diag(jnp.full(3, config.gyr_lsb_per_rads), zeros),
        dt=1.0 / config.fs,
    )


#: :func:`dataset2` compiled, ``config`` static (a new config recompiles).
dataset2_jit = jax.jit(dataset2, static_argnames=("config",))
