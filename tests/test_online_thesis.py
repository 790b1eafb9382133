"""Tests of the thesis's online adaptive algorithm (jaxcal.online_thesis), chapter 4."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcal import online_thesis as ot
from jaxcal.metrics import euclidean_error
from jaxcal.sensor import diag_inverse, spec_convert
from jaxcal.sequences import first_repeated_run, split_equal
from jaxcal.simulate import Dataset2Config, dataset2

# Small Dataset 2: 200 training sequences, every fourth (50, as in the thesis's 500 / 10) used for
# the initial training; 20 validation sequences; 5 Adam steps per sequence to converge faster.
SMALL = Dataset2Config(n_train=200, n_val=20, n_test_acc=200, n_test_gyr=200)
INIT_EVERY = 4
FAST_HP = dict(gyr_steps=5, acc_steps=5)


@pytest.fixture(scope="module")
def small_data():
    return dataset2(jax.random.PRNGKey(3), SMALL)


@pytest.fixture(scope="module")
def exact_data():
    """Unrounded outputs, so that the true inverse model recovers the truth to float precision; 8
    training sequences. Simulated at SMALL's sizes (then cut), so that it and small_data share one
    compiled simulation (a new n_train compiles the sequence simulator anew: 6 s)."""
    data = dataset2(jax.random.PRNGKey(4), SMALL._replace(round_counts=False))
    return data._replace(train=jax.tree.map(lambda x: x[:8], data.train))


def _true_calibration(data):
    a_c = diag_inverse(data.acc_true_model, data.train.acc)
    phi_c = diag_inverse(data.gyr_true_model, data.train.gyr)
    return a_c, phi_c


def test_gyro_loss_zero_for_true_calibration_physical_only(x64, exact_data):
    """Eq. 4.10 with the true inverse model: float noise in the physical convention, not printed."""
    a_c, phi_c = _true_calibration(exact_data)
    dt = exact_data.dt
    a64, p64 = jnp.asarray(a_c, jnp.float64), jnp.asarray(phi_c, jnp.float64)
    phys = jax.vmap(lambda p, a: ot.gyro_loss(p, a, dt, "physical"))(p64, a64)
    printed = jax.vmap(lambda p, a: ot.gyro_loss(p, a, dt, "printed"))(p64, a64)
    # Truth was simulated in float32: residuals ~1e-7 g, squared ~1e-14.
    assert float(jnp.max(phys)) < 1e-12
    # Printed sign: residual ~ 2 |w dt| ~ 1e-3 g per step on these sequences.
    assert float(jnp.min(printed)) > 1e3 * float(jnp.max(phys))
    assert float(jnp.mean(printed)) > 1e-8


def test_gyro_loss_detects_miscalibration(exact_data):
    """The eq. 4.10 loss grows when the gyroscope scale is off by 3 %: it carries information."""
    a_c, phi_c = _true_calibration(exact_data)
    dt = exact_data.dt
    good = jax.vmap(lambda p, a: ot.gyro_loss(p, a, dt))(phi_c, a_c)
    bad = jax.vmap(lambda p, a: ot.gyro_loss(p, a, dt))(1.03 * phi_c, a_c)
    assert bool(jnp.all(bad > 100.0 * good))


def test_acc_loss_zero_for_true_calibration_physical_only(exact_data):
    """Eq. 4.13 vanishes (to float32 noise) for perfect calibrations in the physical convention."""
    a_c, phi_c = _true_calibration(exact_data)
    dt = exact_data.dt
    phys = jax.vmap(lambda a, p: ot.acc_loss(a[0], a[-1], p, dt, 0.9, "physical"))(a_c, phi_c)
    printed = jax.vmap(lambda a, p: ot.acc_loss(a[0], a[-1], p, dt, 0.9, "printed"))(a_c, phi_c)
    assert float(jnp.max(phys)) < 1e-6
    # |R a - R^T a| over a whole sequence (|rotation| up to ~0.4 rad) is far from zero.
    assert float(jnp.mean(printed)) > 1e-4


def test_scan_is_one_scan_over_sequences(small_data):
    """The adaptive loop is a single lax.scan of length n_train inside the jitted function."""
    hp = ot.default_hparams(jax.random.PRNGKey(0), **FAST_HP)
    jaxpr = jax.make_jaxpr(partial(ot.run_dataset, init_every=INIT_EVERY))(small_data, hp).jaxpr
    scans = [e for e in jaxpr.eqns if e.primitive.name == "scan"]
    assert [int(e.params["length"]) for e in scans] == [SMALL.n_train]


@pytest.fixture(scope="module")
def small_run(small_data):
    hp = ot.default_hparams(jax.random.PRNGKey(0), **FAST_HP)
    return ot.run_online_thesis(small_data, hp, init_every=INIT_EVERY)


def test_run_improves_on_spec_conversion(small_data, small_run):
    """After 200 sequences both sensors beat spec conversion on the test sets and on validation.

    The gyroscope is scored where the test rate stays inside the training range (|w| < 0.3 rad/s):
    the test profile puts 0.35 rad/s on all three axes at once (|w| = 0.61 rad/s), a corner that
    Dataset 2's training sequences barely visit and where the small network extrapolates (the
    thesis's "samples 80-160" in Fig. 4.17).
    """
    r = small_run
    assert r.e_g.shape == (SMALL.n_train + 1,) and r.e_a.shape == (SMALL.n_train + 1,)
    assert bool(jnp.all(jnp.isfinite(r.e_g))) and bool(jnp.all(jnp.isfinite(r.e_a)))
    e_acc, e_gyr = ot.test_set_errors((r.acc_params, r.gyr_params), small_data)
    spec_acc = euclidean_error(small_data.test_acc.true, spec_convert(small_data.test_acc.raw, small_data.acc_spec))
    spec_gyr = euclidean_error(small_data.test_gyr.true, spec_convert(small_data.test_gyr.raw, small_data.gyr_spec))
    inside = jnp.linalg.norm(small_data.test_gyr.true, axis=-1) < 0.3
    assert float(jnp.mean(e_gyr[inside])) < 0.7 * float(jnp.mean(spec_gyr[inside]))
    assert float(jnp.mean(e_acc)) < 0.7 * float(jnp.mean(spec_acc))
    # Validation errors at the end are below those after the initial training. Over hparam seeds 0-5
    # the ratios measured 0.10-0.21 (gyro) and 0.13-0.69 (acc; 0.27 for seed 0, used here), and the
    # test errors 0.04-0.10 (gyro) and 0.19-0.39 (acc) x spec conversion's.
    assert float(r.e_g[-10:].mean()) < 0.7 * float(r.e_g[0])
    assert float(r.e_a[-10:].mean()) < 0.9 * float(r.e_a[0])


def test_initial_training_matches_spec_conversion(small_data, small_run):
    """Initial training (4.3) reproduces eq. 4.8 on the data it was trained on: the mean deviation
    from spec conversion is under 5 % of the targets' mean magnitude (an untrained network is off by
    about 100 %: its outputs are near 0).

    How far the fixed epoch budget gets depends on the initial weights: over seeds 0-4 the relative
    deviation measured 0.15-1.6 % (acc) and 0.008-1.1 % (gyro), so 5 % holds with a 3x margin for
    every seed, where an absolute 4 mg / 2 mrad/s bound failed on seeds 2 and 4 (acc 6.1 and 16 mg)
    and, for seed 0's gyro (2.4 mrad/s), on some machines and not others.
    """
    r = small_run
    acc_i = small_data.train.acc[::INIT_EVERY]
    gyr_i = small_data.train.gyr[::INIT_EVERY]
    mean_norm = lambda x: float(jnp.mean(jnp.linalg.norm(x, axis=-1)))  # noqa: E731
    spec_a, spec_g = spec_convert(acc_i, small_data.acc_spec), spec_convert(gyr_i, small_data.gyr_spec)
    da = ot.calibrate_acc(r.acc_params0, acc_i, small_data.acc_spec) - spec_a
    dg = ot.calibrate_gyr(r.gyr_params0, gyr_i, small_data.gyr_spec) - spec_g
    assert mean_norm(da) < 0.05 * mean_norm(spec_a)
    assert mean_norm(dg) < 0.05 * mean_norm(spec_g)


@pytest.mark.slow
def test_vmap_over_hparams_equals_separate_runs(x64, small_data):
    """Two trainings (different seeds and learning rates) vmapped == the two run separately.

    Compared where the invariant is exact: float64 and a 24-sequence horizon. (In float32 over 200
    sequences, batched reductions round differently and Adam amplifies the last bits: one curve
    point of 804 drifted 3.1 % on a 2-core machine, a verdict that hung on reduction order.)
    Measured deviation in float64: 0.0 (bit-identical) in the five normal runs of the near-threshold
    scan; with XLA's fast math (reassociated sums, approximate transcendentals) at most 1.8e-7
    absolute and 6.5e-6 relative. Tolerance 1e-6 + 1e-4 relative keeps a 5x margin there, while a
    wrong batching axis moves the curves by > 10 %.

    Fast cover: tests/test_sweep.py::test_vmapped_group_equals_each_configuration_alone (the adaptive
    loop, run_from_initial, vmapped over w, learning rates and seeds == each configuration run alone by
    run_online_thesis, float32, 2.1e-7 relative), tests/test_sweep.py::test_a_row_does_not_depend_on_the_batch_it_ran_in
    (the same at batch sizes 2, 4 and 8, initial trainings of different init_lr)
    """
    m = 24
    f64 = lambda x: jnp.asarray(x, jnp.float64) if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating) else x  # noqa: E731
    short = small_data._replace(train=jax.tree.map(lambda x: x[:m], small_data.train),
                                val=jax.tree.map(lambda x: x[:4], small_data.val))
    data = jax.tree.map(f64, short)
    hps = [
        ot.default_hparams(jax.random.PRNGKey(1), init_epochs=50, gyr_steps=5, acc_steps=5),
        ot.default_hparams(jax.random.PRNGKey(2), init_epochs=33, gyr_lr=3e-4, acc_lr=3e-5, w=0.8,
                           gyr_steps=2, acc_steps=5),
    ]
    run = partial(ot.run_dataset, init_every=INIT_EVERY)
    batched = jax.jit(jax.vmap(run, in_axes=(None, 0)))(data, ot.stack_hparams(hps))
    singles = [ot.run_online_thesis(data, hp, init_every=INIT_EVERY) for hp in hps]
    assert batched.e_g.dtype == jnp.float64 and batched.e_g.shape == (2, m + 1)
    for i, single in enumerate(singles):
        for b, s in zip(jax.tree.leaves(batched), jax.tree.leaves(single)):
            np.testing.assert_allclose(np.asarray(b)[i], np.asarray(s), rtol=1e-4, atol=1e-6)
    # The two configurations really differ, so equality above is not vacuous.
    other = np.abs(np.asarray(batched.e_g)[0] - np.asarray(singles[1].e_g)) / np.asarray(singles[1].e_g)
    assert float(np.mean(other)) > 0.05


def test_split_equal_round_trip_and_errors():
    x = np.arange(4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3)
    seq = np.repeat(np.array([7, 3, 9, 1]), 5)
    np.testing.assert_array_equal(split_equal(x.reshape(-1, 3), seq), x)
    assert first_repeated_run(seq) is None
    with pytest.raises(ValueError, match="equal length"):
        split_equal(x.reshape(-1, 3)[:-1], seq[:-1])
    bad = seq.copy()
    bad[-5:] = 7  # id 7 appears again later: not contiguous
    assert first_repeated_run(bad) == 15
    with pytest.raises(ValueError, match="seq id 7 is not contiguous"):
        split_equal(x.reshape(-1, 3), bad)


def test_recording_entry_point_equals_dataset_run(small_data, small_run):
    """The CLI entry point on the flattened training recording gives the same calibration."""
    tr = small_data.train
    m, n, _ = tr.acc.shape
    seq = np.repeat(np.arange(m), n)
    hp = ot.default_hparams(jax.random.PRNGKey(123), **FAST_HP)
    r = ot.fit_online_thesis_recording(
        np.asarray(tr.acc).reshape(-1, 3), np.asarray(tr.gyr).reshape(-1, 3), seq, small_data.dt,
        small_data.acc_spec, small_data.gyr_spec, jax.random.PRNGKey(0), hp, init_every=INIT_EVERY,
    )
    assert bool(jnp.all(jnp.isnan(r.e_g)))  # no labels
    a_rec = ot.calibrate_acc(r.acc_params, small_data.test_acc.raw, small_data.acc_spec)
    a_run = ot.calibrate_acc(small_run.acc_params, small_data.test_acc.raw, small_data.acc_spec)
    g_rec = ot.calibrate_gyr(r.gyr_params, small_data.test_gyr.raw, small_data.gyr_spec)
    g_run = ot.calibrate_gyr(small_run.gyr_params, small_data.test_gyr.raw, small_data.gyr_spec)
    np.testing.assert_allclose(a_rec, a_run, atol=1e-4)
    np.testing.assert_allclose(g_rec, g_run, atol=1e-4)

