"""Chapter 3 (offline calibration): Dataset 1 surrogate, linear fit optimality, NN vs linear."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcal.linear import fit_affine
from jaxcal.metrics import euclidean_error
from jaxcal.nn import MLP
from jaxcal.normalise import bounds_from_spec
from jaxcal.offline import ADAM_FROM_RANDOM, NNTrainSpec, linear_calibrate_subsets, nn_calibrate_subsets
from jaxcal.simulate import Dataset1Config, dataset1
from jaxcal.simulate.dataset1 import (
    ACC_RANGE_G,
    nested_subset_weights,
    nonlinear_forward,
    nonlinear_inverse,
)

ZERO3 = (0.0, 0.0, 0.0)
LINEAR_CFG = Dataset1Config(k2=ZERO3, k3=ZERO3, cross=(ZERO3, ZERO3, ZERO3), label_err_deg=0.0)


@pytest.fixture(scope="module")
def d1():
    return dataset1(jax.random.PRNGKey(0))


def test_shapes_splits_and_labels(d1):
    for split, n in ((d1.train, 1000), (d1.val, 184), (d1.test, 184)):
        for a in split:
            assert a.shape == (n, 3)
        np.testing.assert_allclose(np.linalg.norm(split.acc_ref, axis=1), 1.0, atol=1e-5)
        np.testing.assert_allclose(np.linalg.norm(split.acc_true, axis=1), 1.0, atol=1e-5)
    # Splits are distinct orientations.
    allx = np.concatenate([d1.train.acc_true, d1.val.acc_true, d1.test.acc_true])
    assert len(np.unique(np.round(allx, 6), axis=0)) == 1368
    # Robot pointing error: only the 2 components perpendicular to the vector move it, so the
    # angle between label and truth is Rayleigh with mean sigma * sqrt(pi / 2).
    cfg = Dataset1Config()
    ref, true = np.asarray(d1.train.acc_ref, np.float64), np.asarray(d1.train.acc_true, np.float64)
    ang = np.arctan2(np.linalg.norm(np.cross(ref, true), axis=1), np.sum(ref * true, axis=1))  # no arccos: ~1e-4 rad
    expected = math.radians(cfg.label_err_deg) * math.sqrt(math.pi / 2)
    assert abs(ang.mean() / expected - 1) < 0.1
    # Same key, same data; another key, other data.
    again = dataset1(jax.random.PRNGKey(0))
    np.testing.assert_array_equal(again.train.acc, d1.train.acc)
    assert not np.allclose(dataset1(jax.random.PRNGKey(1)).train.acc_true, d1.train.acc_true)


def test_noise_rounding_and_oracle_inverse(d1):
    cfg = Dataset1Config()
    # Averaged read noise has the datasheet size sigma_read / sqrt(n_oversample) (LSB).
    resid = np.asarray(d1.train.acc - nonlinear_forward(d1.model, d1.train.acc_true))
    sigma = cfg.sigma_read_g * cfg.lsb_per_g / math.sqrt(cfg.n_oversample)
    assert abs(resid.std() / sigma - 1) < 0.05
    assert abs(resid.mean()) < 4 * sigma / math.sqrt(resid.size)
    # Each read is rounded: a single read is an integer count; the average of 32 is not.
    one = dataset1(jax.random.PRNGKey(3), cfg._replace(n_oversample=1, n_train=50, n_val=5, n_test=5))
    np.testing.assert_array_equal(one.train.acc, np.round(one.train.acc))
    assert np.mean(np.asarray(d1.train.acc) != np.round(d1.train.acc)) > 0.5
    # Oracle inverse undoes the nonlinear forward model.
    x = d1.test.acc_true
    np.testing.assert_allclose(nonlinear_inverse(d1.model, nonlinear_forward(d1.model, x)), x, atol=1e-6)
    # The nonlinearity is a few mg at 1 g (the size the surrogate is built around).
    lin_only = nonlinear_forward(d1.model._replace(k2=0 * d1.model.k2, k3=0 * d1.model.k3, cross=0 * d1.model.cross), x)
    dev_mg = 1e3 * np.abs(np.asarray(nonlinear_forward(d1.model, x) - lin_only)) / cfg.lsb_per_g
    assert 1.0 < dev_mg.max() < 15.0


def test_nested_subset_weights():
    sizes = (18, 50, 100, 1000)
    w = np.asarray(nested_subset_weights(jax.random.PRNGKey(5), 1000, sizes))
    assert w.shape == (4, 1000)
    np.testing.assert_array_equal(w.sum(1), sizes)
    assert np.all(np.diff(w, axis=0) >= 0)  # nested: every smaller subset inside the next
    w2 = np.asarray(nested_subset_weights(jax.random.PRNGKey(6), 1000, sizes))
    assert not np.array_equal(w[0], w2[0])


def _design(x):
    return np.concatenate([x, np.ones((len(x), 1))], axis=1)


def test_linear_fit_recovers_linear_sensor_within_noise():
    d = dataset1(jax.random.PRNGKey(11), LINEAR_CFG)
    fit = fit_affine(d.train.acc_ref, d.train.acc)
    m_hat = np.concatenate([np.asarray(fit.S), np.asarray(fit.b)[:, None]], axis=1).astype(np.float64)
    m_true = np.concatenate([np.asarray(d.model.affine.S), np.asarray(d.model.affine.b)[:, None]], axis=1)
    # Analytic standard errors of least squares: cov(row) = sigma^2 (A^T A)^-1, sigma the averaged
    # read noise (+ rounding of each read, 1/12 LSB^2, averaged too).
    sig2 = ((LINEAR_CFG.sigma_read_g * LINEAR_CFG.lsb_per_g) ** 2 + 1 / 12) / LINEAR_CFG.n_oversample
    a = _design(np.asarray(d.train.acc_ref, dtype=np.float64))
    se = np.sqrt(sig2 * np.diag(np.linalg.inv(a.T @ a)))[None, :].repeat(3, 0)
    z = (m_hat - m_true) / se
    assert np.abs(z).max() < 5.0
    # chi-square of 12 standardised errors: outside [3.07, 28.3] with probability 1 %.
    assert 3.07 < np.sum(z**2) < 28.3


def test_linear_fit_is_the_least_squares_optimum():
    d = dataset1(jax.random.PRNGKey(12), LINEAR_CFG._replace(n_train=300))
    x, y = np.asarray(d.train.acc_ref, np.float64), np.asarray(d.train.acc, np.float64)
    fit = fit_affine(d.train.acc_ref, d.train.acc)
    m_hat = np.concatenate([np.asarray(fit.S), np.asarray(fit.b)[:, None]], axis=1).astype(np.float64)
    a = _design(x)

    def ssr(m):
        return np.sum((y - a @ m.T) ** 2)

    m_ls, *_ = np.linalg.lstsq(a, y, rcond=None)
    assert ssr(m_hat) == pytest.approx(ssr(m_ls.T), rel=1e-5)
    rng = np.random.default_rng(0)
    sig = LINEAR_CFG.sigma_read_g * LINEAR_CFG.lsb_per_g / math.sqrt(LINEAR_CFG.n_oversample)
    se = sig / math.sqrt(len(x) / 3)
    for _ in range(10):
        assert ssr(m_hat + 0.5 * se * rng.standard_normal((3, 4))) > ssr(m_hat)


def test_linear_error_is_in_the_thesis_regime(d1):
    """On the nonlinear surrogate the linear model is limited by the nonlinearity (~2 mg), well
    above the oracle floor (~1 mg), and roughly flat in l."""
    w = nested_subset_weights(jax.random.PRNGKey(2), 1000, (100, 1000))
    e = 1e3 * np.asarray(euclidean_error(d1.test.acc_ref, linear_calibrate_subsets(d1.train.acc, d1.train.acc_ref, w, d1.test.acc)))
    floor = 1e3 * np.asarray(euclidean_error(d1.test.acc_ref, nonlinear_inverse(d1.model, d1.test.acc))).mean()
    assert 0.7 < floor < 1.2
    assert 1.5 < e[1].mean() < 3.0
    assert e[1].mean() > 1.8 * floor
    assert abs(e[0].mean() - e[1].mean()) < 0.3


def _nn_vs_linear(d1, widths, spec):
    mlp = MLP(widths)
    bounds = bounds_from_spec(d1.spec, ACC_RANGE_G)
    w = jnp.ones((1, 1000))
    cal, _, _ = jax.jit(
        lambda k: nn_calibrate_subsets(k, mlp, bounds, (d1.train.acc, d1.train.acc_ref), w,
                                       (d1.val.acc, d1.val.acc_ref), d1.test.acc, spec)
    )(jax.random.PRNGKey(4))
    nn = float(euclidean_error(d1.test.acc_ref, cal[0]).mean())
    lin = float(euclidean_error(d1.test.acc_ref, linear_calibrate_subsets(d1.train.acc, d1.train.acc_ref, w, d1.test.acc)[0]).mean())
    return nn, lin


def test_narrow_nn_learns_the_nonlinearity_fast(d1):
    """Fast stand-in for the thesis's shape at l = 1000: a 1024-unit NN with the default recipe (ridge
    warm start, Adam, early stopping) beats the linear model by the thesis's margin (NN <= 0.6 x
    linear) on the nonlinear surrogate (measured 0.48-0.50x over init keys 0-4, early-stopped after
    1758-3535 epochs; 256 units reach 0.54-0.57x only at the 5000-epoch cap, too close to call)."""
    nn, lin = _nn_vs_linear(d1, (1024,), NNTrainSpec())
    assert nn <= 0.6 * lin


@pytest.mark.slow
def test_thesis_nn_from_random_init_halves_linear_error_at_l1000(d1):
    """The previous recipe (Adam 2e-2 from the random initialisation, ~18000 epochs: 6 min on 2 CPU
    cores) still reaches the thesis's halving at l = 1000: NN <= 0.6 x linear (measured 0.45x).

    Fast cover: tests/test_offline.py::test_narrow_nn_learns_the_nonlinearity_fast (the same
    nn_calibrate_subsets path and bound at l = 1000, with the current recipe),
    tests/test_offline.py::test_exact_rows_train_as_the_padded_weight_rows (Adam from the random
    initialisation on this path, warm_start=False)
    """
    nn, lin = _nn_vs_linear(d1, (7500,), ADAM_FROM_RANDOM)
    assert nn <= 0.6 * lin


def test_exact_rows_train_as_the_padded_weight_rows(x64, d1):
    """Training on exactly the l rows (the fast path) is the same optimisation as the old padded path
    (1000 rows, 0/1 weights): identical Adam trajectories in float64 (measured 1e-13 relative)."""
    from jaxcal.offline import nn_calibrate_rows

    mlp = MLP((32,))
    bounds = bounds_from_spec(d1.spec, ACC_RANGE_G)
    f64 = lambda a: jnp.asarray(a, jnp.float64)  # noqa: E731
    y, x = f64(d1.train.acc), f64(d1.train.acc_ref)
    val, y_te = (f64(d1.val.acc), f64(d1.val.acc_ref)), f64(d1.test.acc)
    spec = NNTrainSpec(lr_init=1e-3, lr_final=1e-3, patience=31, max_epochs=30, min_rel_delta=0.0, warm_start=False,
                       row_chunk=None)
    w = jnp.zeros((1, 1000), jnp.float64).at[0, :50].set(1.0)
    padded, ep_p, _ = nn_calibrate_subsets(jax.random.PRNGKey(3), mlp, bounds, (y, x), w, val, y_te, spec)
    exact, ep_e, _ = nn_calibrate_rows(jax.random.PRNGKey(3), mlp, bounds, (y[:50], x[:50]), val, y_te, spec)
    assert int(ep_p[0]) == int(ep_e) == 30
    np.testing.assert_allclose(exact, padded[0], rtol=1e-9, atol=1e-12)


def test_residual_nn_falls_back_to_the_linear_model_on_a_linear_sensor(d1):
    """On a purely affine sensor there is nothing for the residual network to learn: the affine + NN
    residual model scores as the linear model does (measured within 1 %), at l = 18 and 400."""
    from jaxcal.offline import residual_nn_calibrate_rows

    cfg = Dataset1Config(k2=(0.0, 0.0, 0.0), k3=(0.0, 0.0, 0.0), cross=((0.0,) * 3,) * 3)
    d = dataset1(jax.random.PRNGKey(5), cfg)
    bounds = bounds_from_spec(d.spec, ACC_RANGE_G)
    for l in (18, 400):
        y, x = d.train.acc[:l], d.train.acc_ref[:l]
        res, _, _ = jax.jit(lambda k, y, x: residual_nn_calibrate_rows(
            k, MLP((64,)), bounds, (y, x), (d.val.acc, d.val.acc_ref), d.test.acc, NNTrainSpec()))(jax.random.PRNGKey(0), y, x)
        lin = linear_calibrate_subsets(y, x, jnp.ones((1, l)), d.test.acc)[0]
        e_res = float(euclidean_error(d.test.acc_ref, res).mean())
        e_lin = float(euclidean_error(d.test.acc_ref, lin).mean())
        assert e_res <= 1.05 * e_lin, (l, e_res, e_lin)
