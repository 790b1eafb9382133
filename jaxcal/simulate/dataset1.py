"""Dataset 1 surrogate (thesis section 3.4): labelled static orientations of an accelerometer.

The thesis's Dataset 1 is a real recording (not public): 1368 static orientations set by a
positioning robot, each labelled with the gravity direction in the sensor frame that the robot
*believes* it set, and each raw value the average of oversampled reads. It is split 1000 training
/ 184 validation / 184 test samples. This module simulates a physically plausible stand-in.

Geometry
    The true gravity directions (specific force at rest, body frame, ``|f| = 1`` g) are uniform on
    the sphere (thesis Fig. 3.4 shows the 1000 training orientations spread over the whole
    sphere; uniform is the simplest reading of it, no robot grid is assumed).

Labels (``acc_ref``, g)
    The robot's pointing error: the label is the true direction rotated by a small random rotation
    with i.i.d. Gaussian rotation-vector components of ``label_err_deg`` (default 0.02 deg per
    axis, i.e. about 0.35 mrad = 0.35 mg perpendicular to gravity; industrial arms repeat to
    ~0.01-0.05 deg in orientation). Label error enters the test ground truth too, as in the thesis,
    where ground truth *is* the robot's label.

Sensor (forward model, raw LSB)
    With ``x`` the true specific force (g)::

        x_nl_i = x_i + k2_i x_i^2 + k3_i x_i^3 + sum_{j<k} c_i,(jk) x_j x_k      (nonlinearity, g)
        y      = diag(s) (I + m) x_nl + b                                       (affine, LSB)
        read   = round(y + n),   n ~ N(0, sigma_read^2) per axis (LSB)
        a_l    = mean of n_oversample reads

    Defaults and why:

    - ``s`` = 16384 LSB/g x (1 + [+1.8 %, -1.2 %, +2.5 %]): MPU-6050-class +-2 g range, datasheet
      initial sensitivity tolerance +-3 %.
    - ``m`` off-diagonal, a few mrad (|m| <= 6 mrad): non-orthogonality plus mounting
      misalignment; datasheet cross-axis sensitivity is +-2 % so this is well inside it.
    - ``b`` = [+250, -180, +420] LSB (15, -11, 26 mg): datasheet zero-g offset +-50-80 mg.
    - ``k2`` = [+3.0, -2.5, +4.0] mg/g^2, ``k3`` = [+1.5, -1.0, +2.0] mg/g^3 and cross-axis
      products ``c`` of 1-2.5 mg/g^2: a few mg at 1 g. The datasheet bounds nonlinearity by 0.5 %
      of full scale (best-fit straight line), i.e. up to ~10-20 mg at the +-2 g ends; a few mg at
      +-1 g is the expected size inside that bound. These unmodelled terms are what limits the
      12-parameter linear model; they were sized to put its test error in the thesis's Table 3.1
      regime (the measured error is in ``results/offline.md``).
    - ``noise_density_ug`` = 400 ug/sqrt(Hz) (MPU-6050 datasheet), ``bandwidth_hz`` = 44 Hz
      (its DLPF setting 3), so ``sigma_read`` = 400 ug x sqrt(44) = 2.65 mg = 43 LSB per read.
    - ``n_oversample`` = 32 reads averaged per orientation: 0.47 mg per axis after averaging.
      Each read is rounded to integer LSB before averaging, so ``acc`` is not integer-valued.

    Noise + label error together give an irreducible test error (eq. 3.8, vs the labels) for a
    perfect calibration, the floor the thesis's NN approaches (measured: ``results/offline.md``,
    "Floor").

All parameters are fields of :class:`Dataset1Config`; the PRNG key drives only the orientations,
label errors and noise, so one config is one sensor and different keys are different recordings
of it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.constants import ACC_LSB_PER_G, ACC_RANGE_G  # ACC_RANGE_G re-exported (eq. 3.6 bounds of this sensor)
from jaxcal.rotation import exp_so3, random_unit_vectors
from jaxcal.sensor import Affine, Diag, affine_inverse

__all__ = [
    "ACC_RANGE_G",
    "ACC_SPEC_LSB_PER_G",
    "CROSS_PAIRS",
    "Dataset1",
    "Dataset1Config",
    "NonlinearAccModel",
    "Split",
    "dataset1",
    "measure",
    "nested_subset_weights",
    "nonlinear_forward",
    "nonlinear_inverse",
    "robot_labels",
    "sensor_model",
]

ACC_SPEC_LSB_PER_G = ACC_LSB_PER_G
# Index pairs (j, k), j < k, of the cross-axis product terms x_j x_k.
CROSS_PAIRS = ((0, 1), (0, 2), (1, 2))


class Dataset1Config(NamedTuple):
    """Every parameter of the Dataset 1 surrogate (module docstring gives sources).

    Static: a plain Python value (hashable tuples). ``n_train``/``n_val``/``n_test`` and
    ``n_oversample`` set array shapes, so under ``jit`` pass the config as a static argument or
    close over it; the others become constants of the compiled function.

    Attributes:
        n_train, n_val, n_test: split sizes (thesis: 1000 / 184 / 184).
        lsb_per_g: datasheet sensitivity (LSB/g).
        scale_err: true scale = ``lsb_per_g * (1 + scale_err)`` per axis.
        misalignment: (3, 3) with zero diagonal, rad: ``S = diag(s) (I + m)``.
        bias_lsb: (3,) bias in LSB.
        k2: (3,) quadratic scale-factor nonlinearity, 1/g (``x + k2 x^2``).
        k3: (3,) cubic scale-factor nonlinearity, 1/g^2.
        cross: (3, 3) cross-axis products, 1/g: row ``i`` holds the coefficients of
            ``x_0 x_1, x_0 x_2, x_1 x_2`` added to axis ``i``.
        noise_density_ug: white-noise density, ug/sqrt(Hz).
        bandwidth_hz: noise bandwidth of one read, Hz.
        n_oversample: reads averaged per orientation.
        label_err_deg: std of each rotation-vector component of the robot pointing error, deg.
        round_reads: round every read to integer LSB before averaging.
    """

    n_train: int = 1000
    n_val: int = 184
    n_test: int = 184
    lsb_per_g: float = ACC_SPEC_LSB_PER_G
    scale_err: tuple[float, float, float] = (0.018, -0.012, 0.025)
    misalignment: tuple[tuple[float, ...], ...] = (
        (0.0, 0.004, -0.003),
        (-0.002, 0.0, 0.006),
        (0.005, -0.004, 0.0),
    )
    bias_lsb: tuple[float, float, float] = (250.0, -180.0, 420.0)
    k2: tuple[float, float, float] = (3.0e-3, -2.5e-3, 4.0e-3)
    k3: tuple[float, float, float] = (1.5e-3, -1.0e-3, 2.0e-3)
    cross: tuple[tuple[float, ...], ...] = (
        (1.5e-3, -1.0e-3, 2.0e-3),
        (-2.0e-3, 1.0e-3, 1.5e-3),
        (1.0e-3, 2.5e-3, -1.5e-3),
    )
    noise_density_ug: float = 400.0
    bandwidth_hz: float = 44.0
    n_oversample: int = 32
    label_err_deg: float = 0.02
    round_reads: bool = True

    @property
    def sigma_read_g(self) -> float:
        """Per-axis noise of one read, g: ``density * sqrt(bandwidth)``."""
        return self.noise_density_ug * 1e-6 * math.sqrt(self.bandwidth_hz)


class NonlinearAccModel(NamedTuple):
    """The simulated accelerometer: nonlinearity terms then an affine map (module docstring)."""

    affine: Affine
    k2: Float[Array, "3"]
    k3: Float[Array, "3"]
    cross: Float[Array, "3 3"]


class Split(NamedTuple):
    """One split: averaged raw counts, robot labels and the (hidden) true specific force."""

    acc: Float[Array, "L 3"]
    acc_ref: Float[Array, "L 3"]
    acc_true: Float[Array, "L 3"]


class Dataset1(NamedTuple):
    """Dataset 1 surrogate: splits, the true sensor and the datasheet model."""

    train: Split
    val: Split
    test: Split
    model: NonlinearAccModel
    spec: Diag


def sensor_model(config: Dataset1Config) -> NonlinearAccModel:
    """The true sensor of ``config`` as arrays."""
    s = config.lsb_per_g * (1.0 + jnp.asarray(config.scale_err, dtype=jnp.float32))
    m = jnp.asarray(config.misalignment, dtype=jnp.float32)
    big_s = s[:, None] * (jnp.eye(3) + m)
    return NonlinearAccModel(
        affine=Affine(S=big_s, b=jnp.asarray(config.bias_lsb, dtype=jnp.float32)),
        k2=jnp.asarray(config.k2, dtype=jnp.float32),
        k3=jnp.asarray(config.k3, dtype=jnp.float32),
        cross=jnp.asarray(config.cross, dtype=jnp.float32),
    )


def nonlinear_forward(model: NonlinearAccModel, x: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """Noise-free sensor output (LSB, not rounded) for true specific force ``x`` (g).

    Args:
        model: the simulated sensor.
        x: (..., 3) true specific force (g).
    """
    prods = jnp.stack([x[..., j] * x[..., k] for j, k in CROSS_PAIRS], axis=-1)
    x_nl = x + model.k2 * x**2 + model.k3 * x**3 + prods @ model.cross.T
    return x_nl @ model.affine.S.T + model.affine.b


def nonlinear_inverse(
    model: NonlinearAccModel, y: Float[Array, "... 3"], iters: int = 6
) -> Float[Array, "... 3"]:
    """Exact inverse of :func:`nonlinear_forward` (the oracle calibration), by fixed-point iteration.

    ``x = u - nl(x)`` with ``u = S^{-1} (y - b)``; the nonlinear terms are ~1e-3 of ``x``, so each
    iteration gains three digits and ``iters = 6`` is at float32 precision.

    Args:
        model: the simulated sensor.
        y: (..., 3) noise-free outputs (LSB).
        iters: fixed-point iterations (static: the loop is unrolled).
    """
    u = affine_inverse(model.affine, y)

    def nl(x):
        prods = jnp.stack([x[..., j] * x[..., k] for j, k in CROSS_PAIRS], axis=-1)
        return model.k2 * x**2 + model.k3 * x**3 + prods @ model.cross.T

    x = u
    for _ in range(iters):
        x = u - nl(x)
    return x


def measure(
    key: jax.Array, model: NonlinearAccModel, x: Float[Array, "L 3"], config: Dataset1Config
) -> Float[Array, "L 3"]:
    """Average of ``n_oversample`` noisy (and, if configured, rounded) reads per sample, LSB.

    Args:
        key: PRNG key of the read noise.
        model: the simulated sensor.
        x: (L, 3) true specific force (g).
        config: ``sigma_read_g``, ``lsb_per_g``, ``n_oversample`` and ``round_reads`` are read.
    """
    y = nonlinear_forward(model, x)
    sigma_lsb = config.sigma_read_g * config.lsb_per_g
    n = sigma_lsb * jax.random.normal(key, (config.n_oversample,) + y.shape)
    reads = y[None] + n
    reads = jnp.round(reads) if config.round_reads else reads
    return jnp.mean(reads, axis=0)


def robot_labels(key: jax.Array, x_true: Float[Array, "L 3"], label_err_deg: float) -> Float[Array, "L 3"]:
    """Labels: ``x_true`` rotated by a random small rotation (the robot's pointing error).

    Args:
        key: PRNG key of the pointing errors.
        x_true: (L, 3) true directions (g).
        label_err_deg: std of each rotation-vector component (deg).
    """
    v = jnp.deg2rad(label_err_deg) * jax.random.normal(key, x_true.shape)
    return jnp.einsum("lij,lj->li", exp_so3(v), x_true)


def dataset1(key: jax.Array, config: Dataset1Config = Dataset1Config()) -> Dataset1:
    """Simulate the Dataset 1 surrogate from one PRNG key.

    Args:
        key: PRNG key; drives orientations, label errors and read noise only.
        config: all sensor and recording parameters (module docstring).

    Returns:
        :class:`Dataset1` with ``train``/``val``/``test`` splits (``acc`` in LSB, ``acc_ref`` and
        ``acc_true`` in g, unit-norm), the true sensor model and the datasheet (spec) model.
    """
    k_dir, k_lab, k_noise = jax.random.split(key, 3)
    n = config.n_train + config.n_val + config.n_test
    x_true = random_unit_vectors(k_dir, n)
    x_ref = robot_labels(k_lab, x_true, config.label_err_deg)
    model = sensor_model(config)
    acc = measure(k_noise, model, x_true, config)
    i1, i2 = config.n_train, config.n_train + config.n_val

    def split(a: int, b: int) -> Split:
        return Split(acc=acc[a:b], acc_ref=x_ref[a:b], acc_true=x_true[a:b])

    return Dataset1(
        train=split(0, i1),
        val=split(i1, i2),
        test=split(i2, n),
        model=model,
        spec=Diag(s=jnp.full(3, config.lsb_per_g), b=jnp.zeros(3)),
    )


def nested_subset_weights(key: jax.Array, n_train: int, sizes: tuple[int, ...]) -> Float[Array, "K n_train"]:
    """0/1 weights selecting the first ``l`` of one random permutation of the training set, per ``l``.

    The subsets are nested (the 18 are inside the 50, ...), and a weight row per size lets fits for
    all sizes run as one ``vmap`` over a padded training set.

    Args:
        key: PRNG key of the permutation.
        n_train: training-set size (static: it sets the shape).
        sizes: subset sizes ``l``, one row each.
    """
    rank = jnp.argsort(jax.random.permutation(key, n_train))  # rank of each sample in the permutation
    return (rank[None, :] < jnp.asarray(sizes)[:, None]).astype(jnp.float32)
