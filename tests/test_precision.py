"""Precision as a checked boundary (:mod:`jaxcal.precision`), in the style of optax's
``float64_test.py``: the public kernels keep their input's dtype (float64 in gives float64 out
under x64, float32 in gives float32 out with or without it); the entry points decorated with
:func:`jaxcal.precision.float64` return float64 when called from outside any x64 context and
leave the flag as they found it; the thesis's NN paths stay float32."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal.multipos as mp
from jaxcal import field, metrics, online, rotation, sensor, static
from jaxcal.eval.scores import score_cal
from jaxcal.linear import fit_affine_closed_form
from jaxcal.methods.base import linear_cal_of_state
from jaxcal.multipos.fit import fit_prepared_numpy
from jaxcal.normalise import Bounds
from jaxcal.online_thesis import acc_loss, gyro_loss
from jaxcal.polynomial import CubicCal, cubic_calibrate, n_params
from jaxcal.precision import float64
from jaxcal.sensor import Affine, Diag, LinearCal
from jaxcal.simulate.multipos import ACC_TRUTH, GYR_TRUTH, simulate_poses

RNG = np.random.default_rng(0)
V = RNG.normal(0.0, 0.7, (5, 3))  # rotation vectors, |v| < pi
Q = RNG.normal(0.0, 1.0, (5, 4))
Q /= np.linalg.norm(Q, axis=1, keepdims=True)
X = RNG.normal(0.0, 1.0, (40, 3))
S = np.eye(3) + RNG.normal(0.0, 0.05, (3, 3))
B = RNG.normal(0.0, 0.1, 3)
W = RNG.normal(0.0, 0.5, (30, 3))
COEF = RNG.normal(0.0, 0.1, (3, n_params(3) // 3))


def _kernels():
    """``name -> fn(cast)``, ``cast`` turning a numpy array into a JAX array of the tested dtype."""
    rm = lambda c: rotation.exp_so3(c(V))  # noqa: E731
    return {
        "exp_so3": lambda c: rotation.exp_so3(c(V)),
        "log_so3": lambda c: rotation.log_so3(rm(c)),
        "hat": lambda c: rotation.hat(c(V)),
        "quat_from_matrix": lambda c: rotation.quat_from_matrix(rm(c)),
        "matrix_from_quat": lambda c: rotation.matrix_from_quat(c(Q)),
        "quat_mul": lambda c: rotation.quat_mul(c(Q), c(Q[::-1])),
        "compose": lambda c: rotation.compose(rm(c)),
        "total_rotation": lambda c: rotation.total_rotation(c(W), 0.01),
        "propagate_specific_force": lambda c: rotation.propagate_specific_force(c(X[0]), c(W), 0.01),
        "diag_forward": lambda c: sensor.diag_forward(Diag(c(np.diag(S)), c(B)), c(X)),
        "diag_inverse": lambda c: sensor.diag_inverse(Diag(c(np.diag(S)), c(B)), c(X)),
        "affine_forward": lambda c: sensor.affine_forward(Affine(c(S), c(B)), c(X)),
        "affine_inverse": lambda c: sensor.affine_inverse(Affine(c(S), c(B)), c(X)),
        "LinearCal.apply": lambda c: LinearCal(c(S), c(B)).apply(c(X)),
        "LinearCal.from_forward": lambda c: LinearCal.from_forward(Affine(c(S), c(B))),
        "LinearCal.to_forward": lambda c: LinearCal(c(S), c(B)).to_forward(),
        "fit_affine_closed_form": lambda c: fit_affine_closed_form(c(X), c(X @ S.T + B)),
        "mse": lambda c: metrics.mse(c(X), c(X[::-1])),
        "euclidean_error": lambda c: metrics.euclidean_error(c(X), c(X[::-1])),
        "moving_mean": lambda c: static.moving_mean(c(X), 3),
        "moving_variance": lambda c: static.moving_variance(c(X), 3),
        "acc_norm_errors": lambda c: mp.acc_norm_errors(LinearCal(c(S), c(B)), c(X[:9])),
        "cubic_calibrate": lambda c: cubic_calibrate(CubicCal(c(COEF), Bounds(c(-np.ones(3)), c(np.ones(3)))), c(X)),
        "gyro_loss (thesis eq. 4.10)": lambda c: gyro_loss(c(W), c(X[: len(W)]), 0.01),
        "acc_loss (thesis eq. 4.13)": lambda c: acc_loss(c(X[0]), c(X[1]), c(W), 0.01),
    }


KERNELS = _kernels()


def _float_dtypes(tree) -> set:
    """The dtypes of the floating-point leaves of ``tree`` (at least one)."""
    dtypes = {np.asarray(x).dtype for x in jax.tree_util.tree_leaves(tree)}  # numpy: keeps a float64 leaf as it is
    floats = {d for d in dtypes if np.issubdtype(d, np.floating)}
    assert floats, "no floating-point output"
    return floats


@pytest.mark.parametrize("name", sorted(KERNELS))
def test_float64_in_float64_out(x64, name):
    assert _float_dtypes(KERNELS[name](lambda a: jnp.asarray(a, jnp.float64))) == {jnp.dtype(jnp.float64)}


@pytest.mark.parametrize("with_x64", [False, True], ids=["default", "x64"])
@pytest.mark.parametrize("name", sorted(KERNELS))
def test_float32_in_float32_out(request, name, with_x64):
    """A kernel follows its input, not the flag: float32 stays float32 even under x64."""
    if with_x64:
        request.getfixturevalue("x64")
    assert _float_dtypes(KERNELS[name](lambda a: jnp.asarray(a, jnp.float32))) == {jnp.dtype(jnp.float32)}


# ----------------------------------------------------------------------------- the boundary


@pytest.fixture(scope="module")
def session():
    """A simulated rest-motion session (raw counts) prepared for multipos, in numpy."""
    t, acc, gyr = simulate_poses(jax.random.PRNGKey(1), n_poses=12, rest=10.0, hold=3.0, move=1.5)
    det = static.detect_static(t, acc, gyr=gyr, init_duration=5.0)
    return det, mp.prepare(t, acc, gyr, det.intervals)


def _cal32(cal: LinearCal) -> LinearCal:
    return LinearCal(np.asarray(cal.A, np.float32), np.asarray(cal.b, np.float32))


def _spec(cal: LinearCal) -> Diag:
    fwd = np.linalg.inv(np.asarray(cal.A))
    return Diag(np.diag(fwd).astype(np.float32), np.asarray(cal.b, np.float32))


ENTRY_POINTS = {
    "static.detect_static": lambda s: s[0].var_mag,
    "field.rest_init": lambda s: field.rest_init(s[1]),
    "multipos fit_prepared_numpy": lambda s: fit_prepared_numpy(s[1]),
    "multipos.leave_poses_out": lambda s: mp.leave_poses_out(s[1], n_folds=3)[:2],
    "eval.score_cal (float32 calibrations)": lambda s: score_cal(_cal32(ACC_TRUTH), _cal32(GYR_TRUTH), s[1]),
    "methods.base.linear_cal_of_state (float32 state)": lambda s: linear_cal_of_state(
        {"S": np.eye(3, dtype=np.float32), "b": np.zeros(3, np.float32)}),
    "online.online_pass (float32 counts)": lambda s: online.online_pass(
        np.asarray(s[1].pose_acc[None, :4], np.float32), np.zeros((1, 4, 3), np.float32), 0.01,
        _spec(ACC_TRUTH), _spec(GYR_TRUTH))[0].theta,
}


@pytest.mark.parametrize("name", sorted(ENTRY_POINTS))
def test_entry_point_returns_float64_from_outside_x64(session, name):
    assert not jax.config.jax_enable_x64, "the suite runs in the default precision"
    assert _float_dtypes(ENTRY_POINTS[name](session)) == {jnp.dtype(jnp.float64)}
    assert not jax.config.jax_enable_x64, "the entry point left x64 on"


def test_decorator_keeps_the_function_and_restores_the_flag():
    def kernel(x):
        """Doc."""
        if x is None:
            raise ValueError("no input")
        return jnp.asarray(x) * 2.0

    wrapped = float64(kernel)
    assert (wrapped.__name__, wrapped.__doc__, wrapped.__wrapped__) == ("kernel", "Doc.", kernel)
    assert wrapped(1.5).dtype == jnp.float64 and kernel(1.5).dtype == jnp.float32
    with jax.enable_x64(False):  # an explicit float32 caller still gets the entry point's float64
        assert wrapped(1.5).dtype == jnp.float64
        assert not jax.config.jax_enable_x64
    with pytest.raises(ValueError, match="no input"):
        wrapped(None)
    assert not jax.config.jax_enable_x64


# ----------------------------------------------------------------------------- thesis paths: float32


def test_thesis_nn_fit_stays_float32():
    """The chapter-3 NN (:func:`jaxcal.nn.fit_nn`) runs as published, in float32: parameters,
    losses and its calibrated output."""
    from jaxcal.nn import MLP, fit_nn, nn_calibrate
    from jaxcal.train import TrainConfig

    y = jnp.asarray(RNG.uniform(-1.0, 1.0, (32, 3)), jnp.float32)
    x = y * 0.9 + 0.01
    b = Bounds(-jnp.ones(3, jnp.float32), jnp.ones(3, jnp.float32))
    cal, res = fit_nn(jax.random.PRNGKey(0), MLP((8,)), b, (y, x, jnp.ones(32)), (y[:8], x[:8]),
                      TrainConfig(1e-2, patience=3), 5)
    assert _float_dtypes((cal.params, res)) == {jnp.dtype(jnp.float32)}
    assert nn_calibrate(MLP((8,)), cal, y).dtype == jnp.float32


def test_thesis_online_stays_float32():
    """The chapter-4 online algorithm (:mod:`jaxcal.online_thesis`) on Dataset 2: float32 models."""
    from jaxcal import online_thesis as ot
    from jaxcal.simulate import Dataset2Config, dataset2

    data = dataset2(jax.random.PRNGKey(5), Dataset2Config(n_train=8, n_val=2, n_test_acc=8, n_test_gyr=8))
    init = ot.initial_training(data, ot.default_hparams(jax.random.PRNGKey(6), init_epochs=5, gyr_steps=1, acc_steps=1), init_every=4)
    assert _float_dtypes(init) == {jnp.dtype(jnp.float32)}
