"""Tests of jaxcal.online (streaming self-calibration), jaxcal.fisher, jaxcal.sequences (padding)
and jaxcal.simulate.drift.

Truth comes from the simulators' hidden parameters, closed forms and invariants.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcal import fisher
from jaxcal import online_thesis as ot
from jaxcal.normalise import Bounds
from jaxcal.online import (
    NNOnlineHP,
    OnlineHP,
    ZeroLastMLP,
    diag_theta,
    fit_online_recording,
    make_filter,
    nn_calibrate,
    online_pass,
    thesis_acc_loss,
    thesis_gyro_loss,
    to_linear_cal,
)
from jaxcal.sensor import Diag, LinearCal
from jaxcal.sequences import pad_with_mask
from jaxcal.simulate import Dataset2Config, dataset2
from jaxcal.simulate.drift import DriftConfig, simulate_drift, temperature


@pytest.fixture(scope="module")
def small_d2():
    # fresh seed, reduced dataset: 100 training sequences. Generated under jit, as the CLI does
    # (eager: 12.9 s on the 2-core machine under load, jit 6.4 s; the two differ in 1-LSB roundings
    # of 0.05 % of the samples, far inside every tolerance below, which come from the quantisation)
    config = Dataset2Config(n_train=100, n_val=4)
    d = jax.jit(dataset2, static_argnums=1)(jax.random.PRNGKey(31337), config)
    return d._replace(dt=1.0 / config.fs)  # a Python float, as eagerly (jit returns it as an array)


@pytest.fixture(scope="module")
def small_pass(small_d2):
    d = small_d2
    return online_pass(d.train.acc, d.train.gyr, d.dt, d.acc_spec, d.gyr_spec, OnlineHP(), "diag")


def _truth_theta(d):
    a, g = d.acc_true_model, d.gyr_true_model
    sa, sg = d.acc_spec.s, d.gyr_spec.s
    return np.concatenate([sa / a.s - 1, a.b / a.s, sg / g.s - 1, g.b / g.s]).astype(np.float64)


def test_recovers_true_parameters_near_quantisation_floor(x64, small_d2, small_pass):
    d = small_d2
    state, hist = small_pass
    am, gm = to_linear_cal(state.theta, "diag", d.acc_spec, d.gyr_spec)
    am = jax.tree.map(np.asarray, am)
    gm = jax.tree.map(np.asarray, gm)
    # Tolerances from the quantisation noise: one LSB of rounding spread over >= 1e4 samples
    # leaves parameter errors far below 1 LSB; the spec starts 3 % / hundreds of LSB away.
    np.testing.assert_allclose(1.0 / np.diag(am.A), np.asarray(d.acc_true_model.s), rtol=2e-5)
    np.testing.assert_allclose(1.0 / np.diag(gm.A), np.asarray(d.gyr_true_model.s), rtol=1e-4)
    np.testing.assert_allclose(am.b, np.asarray(d.acc_true_model.b), atol=0.5)
    np.testing.assert_allclose(gm.b, np.asarray(d.gyr_true_model.b), atol=0.5)
    # off-diagonals of a diag model are zero by construction; test error near the floor
    e_acc = np.mean(np.linalg.norm(am.apply(np.asarray(d.test_acc.raw, np.float64)) - np.asarray(d.test_acc.true), axis=-1))
    e_gyr = np.mean(np.linalg.norm(gm.apply(np.asarray(d.test_gyr.raw, np.float64)) - np.asarray(d.test_gyr.true), axis=-1))
    a, g = d.acc_true_model, d.gyr_true_model
    f_acc = np.mean(np.linalg.norm((np.asarray(d.test_acc.raw) - a.b) / a.s - np.asarray(d.test_acc.true), axis=-1))
    f_gyr = np.mean(np.linalg.norm((np.asarray(d.test_gyr.raw) - g.b) / g.s - np.asarray(d.test_gyr.true), axis=-1))
    assert e_acc < 1.5 * f_acc and e_gyr < 1.5 * f_gyr
    # and far better than the starting point (spec values)
    e_spec = np.mean(np.linalg.norm(np.asarray(d.test_acc.raw) / d.acc_spec.s - np.asarray(d.test_acc.true), axis=-1))
    assert e_acc < e_spec / 100


def test_state_is_fixed_size(small_d2, small_pass):
    """The filter's state does not grow with the sequences seen: 3 sequences (shapes traced, not
    compiled) and 100 (run) give the same state shapes."""
    d = small_d2
    assert jax.tree.map(lambda x: x.shape, make_filter("affine").init(OnlineHP())) == ((21,), (21, 21), ())
    kind = "diag"
    n_params = make_filter(kind).n_params
    s100, h100 = small_pass
    s3, h3 = jax.eval_shape(
        lambda a, g: online_pass(a, g, d.dt, d.acc_spec, d.gyr_spec, OnlineHP(), kind), d.train.acc[:3], d.train.gyr[:3]
    )
    shapes3 = jax.tree.map(lambda x: x.shape, s3)
    assert shapes3 == jax.tree.map(lambda x: x.shape, s100)
    assert shapes3.theta == (n_params,) and shapes3.info == (n_params,) * 2
    assert h3.shape == (3, n_params)
    assert int(s100.count) == 100 and h100.shape == (100, n_params)


def test_make_filter_is_static_and_cached():
    """One Filter per kind (hashable, cached: a static jit argument that compiles once per kind)."""
    assert make_filter("diag") is make_filter("diag")
    assert make_filter("diag") != make_filter("affine")
    assert (make_filter("diag").n_params, make_filter("affine").n_params) == (12, 21)
    hash(make_filter("affine"))
    with pytest.raises(ValueError, match="kind must be one of"):
        make_filter("full")


@pytest.mark.parametrize("kind", ["diag", "affine"])
def test_acc_prior_factor_scales_only_the_accelerometer_prior(kind):
    """``OnlineHP.acc_prior_factor`` f: the prior information of the accelerometer's entries (its
    D_a entries and bias, the first ones of ``theta``) is divided by f^2, every other entry is as
    without it; f = 1 is the default (the thesis's and the seq path's filter unchanged). f = 2 and
    1/2: exact in binary floating point."""
    filt = make_filter(kind)
    base = np.diag(np.asarray(filt.prior_info(OnlineHP())))
    na = {"diag": 6, "affine": 9}[kind]
    for f in (2.0, 0.5):
        got = np.diag(np.asarray(filt.prior_info(OnlineHP(acc_prior_factor=f))))
        np.testing.assert_array_equal(got[:na], base[:na] / f**2)
        np.testing.assert_array_equal(got[na:], base[na:])
    np.testing.assert_array_equal(np.diag(np.asarray(filt.prior_info(OnlineHP(acc_prior_factor=1.0)))), base)


@pytest.mark.parametrize("kind", ["diag", "affine"])
def test_structured_jacobian_is_jacfwd_of_the_residuals(x64, small_d2, kind):
    """The filter's Jacobian by the chain rule through the carried gravity (accelerometer columns
    never pushed through the propagation) equals ``jax.jacfwd`` of the residual function, with and
    without the field's along/across weights. Deviation measured: 2.2e-16 (entries up to ~1)."""
    d = small_d2
    filt = make_filter(kind)
    p = filt.n_params
    s = jnp.asarray(d.acc_spec.s, jnp.float64), jnp.asarray(d.gyr_spec.s, jnp.float64)
    ua = (jnp.asarray(d.train.acc[3], jnp.float64) - d.acc_spec.b) / s[0]
    ug = (jnp.asarray(d.train.gyr[3], jnp.float64) - d.gyr_spec.b) / s[1]
    m = jnp.ones(ua.shape[0])
    z = 0.01 * jax.random.normal(jax.random.PRNGKey(1), (p + 2,), jnp.float64)
    f0 = ua[0] / jnp.linalg.norm(ua[0])
    n = ua.shape[0]
    for w, wt in ((None, None), (jnp.linspace(0.0, 1.0, n), jnp.linspace(1.0, 0.1, n))):
        r, j = jax.jit(lambda z_: filt.residuals_and_jacobian(z_, f0, ua, ug, m, d.dt, w, wt))(z)  # noqa: B023
        res = lambda z_: filt.sequence_residuals(z_[:p], z_[p:], f0, ua, ug, m, d.dt, w, wt)  # noqa: B023, E731
        r2, j2 = jax.jit(lambda z_: (res(z_), jax.jacfwd(res)(z_)))(z)
        np.testing.assert_allclose(np.asarray(r), np.asarray(r2), rtol=0, atol=1e-14)
        np.testing.assert_allclose(np.asarray(j), np.asarray(j2), rtol=0, atol=1e-13)


def test_unpack_affine_gauge_and_to_linear_cal_roundtrip(x64):
    filt = make_filter("affine")
    theta = jax.random.normal(jax.random.PRNGKey(2), (21,), jnp.float64) * 0.01
    c = filt.unpack(theta)
    assert np.allclose(np.tril(np.asarray(c.K_a), -1), 0.0)  # upper-triangular gauge fix
    spec = Diag(jnp.array([16000.0, 16500.0, 16300.0]), jnp.array([10.0, -20.0, 5.0]))
    gspec = Diag(jnp.full(3, 7500.0), jnp.zeros(3))
    am, gm = to_linear_cal(theta, "affine", spec, gspec)
    assert isinstance(am, LinearCal) and isinstance(gm, LinearCal)
    y = jax.random.normal(jax.random.PRNGKey(3), (5, 3), jnp.float64) * 1e4
    direct = filt.calibrate_acc(theta, (y - spec.b) / spec.s)
    np.testing.assert_allclose(am.apply(y), direct, rtol=1e-10, atol=1e-12)
    direct_g = filt.calibrate_gyr(theta, (y - gspec.b) / gspec.s)
    np.testing.assert_allclose(gm.apply(y), direct_g, rtol=1e-10, atol=1e-12)


def test_diag_theta_is_the_diag_layout_of_a_true_model(x64):
    """``diag_theta`` inverts ``to_linear_cal`` for the diag layout: the parameters of a true diagonal
    model, run with another datasheet, give back exactly that model (``A = diag(1/s)``, ``b``)."""
    true_a, true_g = Diag(jnp.array([16100.0, 16400.0, 15900.0]), jnp.array([30.0, -12.0, 7.0])), \
        Diag(jnp.array([7400.0, 7600.0, 7550.0]), jnp.array([-40.0, 15.0, 3.0]))
    spec_a, spec_g = Diag(jnp.full(3, 16384.0), jnp.zeros(3)), Diag(jnp.full(3, 7500.0), jnp.zeros(3))
    am, gm = to_linear_cal(diag_theta(true_a, true_g, spec_a, spec_g), "diag", spec_a, spec_g)
    for cal, true in ((am, true_a), (gm, true_g)):
        np.testing.assert_allclose(cal.A, np.diag(1.0 / np.asarray(true.s)), rtol=1e-12)
        np.testing.assert_allclose(cal.b, true.b, rtol=1e-12, atol=1e-9)


def test_nn_calibrate_with_a_zero_last_layer_is_the_backbone(x64):
    """The residual network's last layer starts at zero, so ``nn_calibrate`` is the backbone's
    calibration of either sensor at initialisation."""
    filt, mlp = make_filter("diag"), ZeroLastMLP()
    theta = jax.random.normal(jax.random.PRNGKey(4), (12,), jnp.float64) * 0.01
    u = jax.random.normal(jax.random.PRNGKey(5), (7, 3), jnp.float64)
    params = mlp.init(jax.random.PRNGKey(6), u)["params"]
    bounds = Bounds(jnp.full(3, -2.0), jnp.full(3, 2.0))
    hp = NNOnlineHP()
    np.testing.assert_array_equal(nn_calibrate("acc", filt, theta, params, u, bounds, hp, mlp), filt.calibrate_acc(theta, u))
    np.testing.assert_array_equal(nn_calibrate("gyr", filt, theta, params, u, bounds, hp, mlp), filt.calibrate_gyr(theta, u))


def test_fit_online_recording_flat_arrays(small_d2):
    d = small_d2
    m, n = 60, d.train.acc.shape[1]
    acc = np.asarray(d.train.acc[:m]).reshape(-1, 3)
    gyr = np.asarray(d.train.gyr[:m]).reshape(-1, 3)
    seq = np.repeat(np.arange(m), n)
    t = np.arange(m * n) * d.dt
    am, gm = fit_online_recording(acc, gyr, seq, t, d.acc_spec, d.gyr_spec, OnlineHP(), kind="affine")
    assert isinstance(am, LinearCal) and isinstance(gm, LinearCal)
    e = np.linalg.norm(am.apply(np.asarray(d.test_acc.raw, np.float64)) - np.asarray(d.test_acc.true), axis=-1).mean()
    eg = np.linalg.norm(gm.apply(np.asarray(d.test_gyr.raw, np.float64)) - np.asarray(d.test_gyr.true), axis=-1).mean()
    assert e < 1e-4 and eg < 2e-4  # g, rad/s: ~3 x the quantisation floor with 60 sequences
    # no datasheet values: initialised from the data (median norm, static-end medians)
    am, gm = fit_online_recording(acc, gyr, seq, d.dt, None, None, OnlineHP(), kind="affine")
    e = np.linalg.norm(am.apply(np.asarray(d.test_acc.raw, np.float64)) - np.asarray(d.test_acc.true), axis=-1).mean()
    eg = np.linalg.norm(gm.apply(np.asarray(d.test_gyr.raw, np.float64)) - np.asarray(d.test_gyr.true), axis=-1).mean()
    assert e < 1e-4 and eg < 2e-4


def test_pad_with_mask_unequal_sequences():
    x = np.arange(7 * 3, dtype=np.float32).reshape(7, 3)
    seq = np.array([4, 4, 4, 1, 1, 9, 9])
    padded, mask = pad_with_mask(x, seq)
    assert padded.shape == (3, 3, 3) and padded.dtype == np.float64
    np.testing.assert_array_equal(mask, [[1, 1, 1], [1, 1, 0], [1, 1, 0]])
    np.testing.assert_array_equal(padded[1, :2], x[3:5])
    np.testing.assert_array_equal(padded[1, 2], x[4])  # padding repeats the last sample
    p1, m1 = pad_with_mask(x[:, 0], seq)  # any trailing shape
    assert p1.shape == (3, 3)
    np.testing.assert_array_equal(m1, mask)


def test_buffer_losses_are_weighted_means_of_the_thesis_losses():
    """The NN variant's losses are eq. 4.10 / 4.13 of :mod:`jaxcal.online_thesis`, per sequence,
    averaged over the filled buffer slots (weight 0 slots ignored)."""
    d = dataset2(jax.random.PRNGKey(9), Dataset2Config(n_train=3, n_val=1))
    a_c, w_c = d.train.acc_true * 1.01, d.train.gyr_true * 0.99
    wts = jnp.array([1.0, 0.0, 1.0])
    g = [ot.gyro_loss(w_c[i], a_c[i], d.dt) for i in (0, 2)]
    a = [ot.acc_loss(a_c[i, 0], a_c[i, -1], w_c[i], d.dt, 0.9) for i in (0, 2)]
    np.testing.assert_allclose(thesis_gyro_loss(a_c, w_c, d.dt, wts), (g[0] + g[1]) / 2, rtol=1e-6)
    np.testing.assert_allclose(thesis_acc_loss(a_c, w_c, d.dt, wts, 0.9), (a[0] + a[1]) / 2, rtol=1e-6)


def test_drift_truth_follows_temperature_model():
    cfg = DriftConfig(n_seq=50, duration_s=3600.0, acc_noise_density=0.0, gyr_noise_density=0.0)
    dd = simulate_drift(jax.random.PRNGKey(4), cfg)
    tr = dd.truth
    t = np.asarray(tr.t_start)
    temp = np.asarray(tr.temp)
    np.testing.assert_allclose(temp, 25.0 + 15.0 * (1 - np.exp(-t / 900.0)), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(temperature(jnp.asarray(1e9), cfg)), 40.0, rtol=1e-6)
    dT = (temp - 25.0)[:, None]
    s = np.asarray(tr.acc_model0.s) * (1 + np.asarray(tr.acc_scale_tc) * dT)
    b = np.asarray(tr.acc_model0.b) + s * (np.asarray(tr.acc_bias_tc) * dT)
    np.testing.assert_allclose(np.asarray(tr.acc_model.s), s, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(tr.acc_model.b), b, rtol=1e-5, atol=1e-3)
    # tempco magnitudes in [0.5, 1] x configured
    assert np.all((np.abs(tr.gyr_bias_tc) >= 0.5 * cfg.gyr_bias_tc - 1e-12) & (np.abs(tr.gyr_bias_tc) <= cfg.gyr_bias_tc + 1e-12))
    # with zero noise the raw output is exactly round(s x + b) with the per-sequence truth
    acc = np.asarray(dd.seqs.acc)
    pred = np.round(np.asarray(tr.acc_model.s)[:, None] * np.asarray(dd.seqs.acc_true) + np.asarray(tr.acc_model.b)[:, None])
    assert np.mean(acc == pred) > 0.999  # float32 ties aside


def test_drift_noise_level():
    cfg = DriftConfig(n_seq=20, temp_rise=0.0)
    dd = simulate_drift(jax.random.PRNGKey(5), cfg)
    s = np.asarray(dd.truth.acc_model.s)[:, None]
    x = (np.asarray(dd.seqs.acc) - np.asarray(dd.truth.acc_model.b)[:, None]) / s - np.asarray(dd.seqs.acc_true)
    expected = cfg.acc_noise_density * math.sqrt(cfg.motion.fs)
    assert abs(np.std(x) / expected - 1) < 0.05


def test_fisher_linear_toy_equals_closed_form(x64):
    a = jax.random.normal(jax.random.PRNGKey(6), (40, 3), jnp.float64)
    sigma = 0.3
    model = lambda p: a @ p  # noqa: E731
    j = jax.jacfwd(model)(jnp.zeros(3, jnp.float64))
    np.testing.assert_allclose(fisher.gaussian_fisher(j, sigma=sigma), a.T @ a / sigma**2, rtol=1e-12)
    cov = jnp.diag(jnp.linspace(0.1, 1.0, 40))
    np.testing.assert_allclose(fisher.gaussian_fisher(j, cov), a.T @ jnp.linalg.inv(cov) @ a, rtol=1e-10)
    # Schur complement = inverse of the (theta, theta) block of the full inverse
    f = fisher.gaussian_fisher(j, sigma=sigma)
    np.testing.assert_allclose(fisher.schur_marginal(f, 2), jnp.linalg.inv(jnp.linalg.inv(f)[:2, :2]), rtol=1e-10)


def test_expected_error_closed_form(x64):
    # isotropic 3-D Gaussian: E|e| = sigma * 2 sqrt(2 / pi)
    sigma = 0.2
    cov = sigma**2 * jnp.eye(3, dtype=jnp.float64)
    e = fisher.expected_error(jax.random.PRNGKey(7), cov, lambda th: th[None, :], jnp.zeros(3, jnp.float64), n_draws=40000)
    assert abs(float(e) / (sigma * 2 * math.sqrt(2 / math.pi)) - 1) < 0.01


def test_protocol_crb_consistent_with_filter_scatter(x64):
    """The filter's parameter scatter over seeds is of the order of the Cramer-Rao bound."""
    cfg = DriftConfig(n_seq=30, duration_s=30.0, temp_rise=0.0, gyr_noise_density=0.0)
    errs = []
    pf = jax.jit(fisher.protocol_fisher, static_argnames=("kind", "batch_size"))
    for seed in range(2):
        dd = simulate_drift(jax.random.PRNGKey(100 + seed), cfg)
        sig = cfg.acc_noise_density * math.sqrt(cfg.motion.fs)
        st, _ = online_pass(dd.seqs.acc, dd.seqs.gyr, dd.dt, dd.acc_spec, dd.gyr_spec, OnlineHP(sigma_acc=sig), "diag")
        a0, g0 = dd.truth.acc_model0, dd.truth.gyr_model0
        sa, sg = dd.acc_spec.s, dd.gyr_spec.s
        th = jnp.concatenate([sa / a0.s - 1, a0.b / a0.s, sg / g0.s - 1, g0.b / g0.s]).astype(jnp.float64)
        ug = (jnp.asarray(dd.seqs.gyr_true, jnp.float64) * g0.s + g0.b) / sg
        f = pf(th, jnp.asarray(dd.seqs.acc_true[:, 0], jnp.float64), ug, dd.dt, sig, 0.0, kind="diag", batch_size=30)
        sd = np.sqrt(np.diag(np.linalg.inv(np.asarray(f))))
        errs.append(np.asarray(st.theta - th) / sd)
    z = np.concatenate(errs)
    assert np.sqrt(np.mean(z**2)) < 3.0  # normalised errors: ~1 for an efficient estimator
