"""Core: sensor models, normalisation, metrics, optimistix least squares, training loop."""

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxcal import linear, metrics, nn, normalise, sensor, train
from jaxcal.rotation import random_unit_vectors

settings.register_profile("jaxcal", deadline=None, max_examples=60, derandomize=True)
settings.load_profile("jaxcal")


def _random_affine(key, dtype=jnp.float32):
    k1, k2 = jax.random.split(key)
    s = jnp.diag(jnp.array([16384.0, 16100.0, 16700.0], dtype)) + 50.0 * jax.random.normal(k1, (3, 3), dtype)
    return sensor.Affine(S=s, b=300.0 * jax.random.normal(k2, (3,), dtype))


@given(st.integers(0, 2**31 - 1))
def test_affine_inverse_round_trip(seed):
    with jax.enable_x64(True):
        k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
        p = _random_affine(k1, jnp.float64)
        x = jax.random.normal(k2, (7, 3), jnp.float64)
        np.testing.assert_allclose(np.asarray(sensor.affine_inverse(p, sensor.affine_forward(p, x))), np.asarray(x), atol=1e-12)
        # Single sample and diagonal model agree with the affine one.
        d = sensor.Diag(s=jnp.diag(p.S), b=p.b)
        np.testing.assert_allclose(
            np.asarray(sensor.diag_inverse(d, sensor.diag_forward(d, x[0]))), np.asarray(x[0]), atol=1e-12
        )
        a = sensor.affine_from_diag(d)
        np.testing.assert_allclose(np.asarray(sensor.affine_forward(a, x)), np.asarray(sensor.diag_forward(d, x)), atol=1e-9)


def test_normalisation_maps_spec_range_onto_unit_interval():
    spec = sensor.spec_diag(16384.0, 120.0)
    b = normalise.bounds_from_spec(spec, 2.0)
    y = jnp.array([[-2 * 16384.0 + 120.0] * 3, [120.0] * 3, [2 * 16384.0 + 120.0] * 3])
    np.testing.assert_allclose(np.asarray(normalise.normalise(y, b)), [[-1.0] * 3, [0.0] * 3, [1.0] * 3], atol=1e-6)
    np.testing.assert_allclose(np.asarray(normalise.denormalise(normalise.normalise(y, b), b)), np.asarray(y), rtol=1e-6)
    # Spec conversion (eq. 4.8) inverts the spec forward model.
    np.testing.assert_allclose(np.asarray(sensor.spec_convert(y, spec)), [[-2.0] * 3, [0.0] * 3, [2.0] * 3], atol=1e-6)


def test_metrics_closed_forms():
    t = jnp.zeros((2, 3))
    c = jnp.array([[3.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(np.asarray(metrics.euclidean_error(t, c)), [5.0, 1.0])
    st_ = metrics.error_stats(t, c)
    assert float(st_.mean) == 3.0 and float(st_.std) == 2.0
    assert float(metrics.mse(t, c)) == np.mean(np.asarray(c) ** 2)
    seq_true = jnp.zeros((2, 4, 3))
    assert float(metrics.sequence_gyro_error(seq_true, seq_true + jnp.array([0.0, 3.0, 4.0]))) == 5.0
    assert float(metrics.sequence_acc_error(t, c)) == 3.0


def _linear_problem(key, n, noise, dtype):
    k1, k2, k3 = jax.random.split(key, 3)
    p = _random_affine(k1, dtype)
    x = random_unit_vectors(k2, n).astype(dtype)
    y = sensor.affine_forward(p, x) + noise * jax.random.normal(k3, (n, 3), dtype)
    return p, x, y


def test_optimistix_equals_closed_form_to_float64_precision():
    with jax.enable_x64(True):
        _, x, y = _linear_problem(jax.random.PRNGKey(0), 200, 5.0, jnp.float64)
        a = linear.fit_affine(x, y)
        b = linear.fit_affine_closed_form(x, y)
        np.testing.assert_allclose(np.asarray(a.S), np.asarray(b.S), rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(np.asarray(a.b), np.asarray(b.b), rtol=1e-12, atol=1e-9)
        # And numpy's lstsq, an independent implementation.
        m, *_ = np.linalg.lstsq(np.c_[np.asarray(x), np.ones(200)], np.asarray(y), rcond=None)
        np.testing.assert_allclose(np.asarray(a.S), m[:3].T, rtol=1e-12, atol=1e-9)


def test_linear_fit_exact_without_noise_and_vmaps_over_datasets():
    with jax.enable_x64(True):
        keys = jax.random.split(jax.random.PRNGKey(1), 16)
        ps, xs, ys = jax.vmap(lambda k: _linear_problem(k, 30, 0.0, jnp.float64))(keys)
        fits = jax.jit(jax.vmap(linear.fit_affine))(xs, ys)
        np.testing.assert_allclose(np.asarray(fits.S), np.asarray(ps.S), rtol=1e-10)
        np.testing.assert_allclose(np.asarray(fits.b), np.asarray(ps.b), atol=1e-7)
        one = linear.fit_affine(xs[3], ys[3])
        np.testing.assert_allclose(np.asarray(fits.S[3]), np.asarray(one.S), rtol=1e-12)


def test_zero_weights_drop_samples():
    with jax.enable_x64(True):
        _, x, y = _linear_problem(jax.random.PRNGKey(2), 50, 10.0, jnp.float64)
        w = jnp.concatenate([jnp.ones(20), jnp.zeros(30)])
        a = linear.fit_affine(x, y, w)
        b = linear.fit_affine(x[:20], y[:20])
        np.testing.assert_allclose(np.asarray(a.S), np.asarray(b.S), rtol=1e-10)


def test_float32_fit_is_accurate_for_counts():
    """The default float32 path keeps parameters to ~1e-5 relative on realistic counts."""
    p, x, y = _linear_problem(jax.random.PRNGKey(4), 1000, 0.0, jnp.float32)
    fit = linear.fit_affine(x, y)
    np.testing.assert_allclose(np.asarray(fit.S), np.asarray(p.S), rtol=0, atol=0.2)  # 0.2 LSB/g of 16384
    x_back = sensor.affine_inverse(fit, y)
    assert float(jnp.max(jnp.abs(x_back - x))) < 2e-5


def test_full_batch_training_reaches_least_squares_and_stops_early():
    """A linear model trained by fit_full_batch converges to the lstsq optimum; patience stops it."""
    key = jax.random.PRNGKey(5)
    x = jax.random.normal(key, (64, 3))
    w_true = jnp.array([[1.0, -2.0, 0.5]]).T
    y = x @ w_true + 0.3

    def loss(p, d):
        xx, yy = d
        return jnp.mean((xx @ p["w"] + p["b"] - yy) ** 2)

    p0 = {"w": jnp.zeros((3, 1)), "b": jnp.zeros(())}
    cfg = train.TrainConfig(learning_rate=0.01, patience=20, min_delta=0.0)
    res = jax.jit(train.fit_full_batch, static_argnums=(0, 5))(loss, p0, (x, y), (x, y), cfg, 20000)
    np.testing.assert_allclose(np.asarray(res.params["w"]), np.asarray(w_true), atol=1e-3)
    assert float(res.best_val) < 1e-6
    assert int(res.epochs) < 20000  # stopped by patience, not by the cap
    assert int(res.epochs) - int(res.best_epoch) - 1 == 20
    hist = np.asarray(res.val_loss)
    assert np.all(np.isnan(hist[int(res.epochs):])) and np.all(np.isfinite(hist[: int(res.epochs)]))


def test_nn_fit_is_reproducible_and_vmaps_over_seeds():
    mlp = nn.MLP(widths=(32,), slope=0.1)
    spec = sensor.spec_diag(16384.0)
    bounds = normalise.bounds_from_spec(spec, 2.0)
    x = random_unit_vectors(jax.random.PRNGKey(6), 200)
    p = sensor.Affine(S=jnp.diag(jnp.array([16000.0, 16500.0, 16384.0])), b=jnp.array([200.0, -100.0, 50.0]))
    y = sensor.affine_forward(p, x)
    cfg = train.TrainConfig(learning_rate=3e-3, patience=100)

    def fit(key):
        cal, res = nn.fit_nn(key, mlp, bounds, (y[:150], x[:150], jnp.ones(150)), (y[150:], x[150:]), cfg, 3000)
        return cal, res.best_val

    keys = jax.random.split(jax.random.PRNGKey(7), 2)
    cals, vals = jax.jit(jax.vmap(fit))(keys)
    cal0, val0 = jax.jit(fit)(keys[0])
    np.testing.assert_allclose(float(vals[0]), float(val0), rtol=1e-4)
    # Better than doing nothing (spec conversion) on held-out samples.
    pred = nn.nn_calibrate(mlp, cal0, y[150:])
    spec_err = metrics.error_stats(x[150:], sensor.spec_convert(y[150:], spec)).mean
    assert float(metrics.error_stats(x[150:], pred).mean) < 0.8 * float(spec_err)
    # Leaky slope is honoured: the hidden pre-activation sign pattern changes the output.
    out = nn.MLP(widths=(4,), slope=0.0).apply({"params": nn.init_mlp(keys[0], nn.MLP(widths=(4,)))}, -10 * jnp.ones((1, 3)))
    assert out.shape == (1, 3)
