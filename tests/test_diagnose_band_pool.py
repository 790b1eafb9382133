"""The band check of diagnose (jaxcal.diagnose.band_pool): per-band estimates and their random-effects pooling.

Independent truth: DerSimonian-Laird's closed form on hand-made numbers, and simulated residuals with
a known coefficient (the same in every band, or a different one per band)."""

from __future__ import annotations

import numpy as np
from scipy import stats

from jaxcal.diagnose import effects as E
from jaxcal.diagnose.band_pool import band_check, candidate_spread, random_effects, widen_information

DT = 0.01


def _signal(rng: np.random.Generator, n: int, freqs: tuple[float, ...]) -> np.ndarray:
    t = np.arange(n) * DT
    return sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in freqs)


def test_random_effects_closed_form():
    # equal estimates: no between-band variance, the fixed-effect pooled value and standard error
    pooled, se, tau2, q = random_effects(np.array([[2.0], [2.0], [2.0]]), np.array([[1.0], [2.0], [2.0]]))
    assert tau2[0] == 0.0 and q[0] == 0.0
    np.testing.assert_allclose(pooled, 2.0)
    np.testing.assert_allclose(se, 1.0 / np.sqrt(1.0 + 0.25 + 0.25))
    # two bands, y = 0 and 10 with unit variances: Q = 50, C = 1, tau2 = 49, pooled 5, se sqrt(50 / 2)
    pooled, se, tau2, q = random_effects(np.array([[0.0], [10.0]]), np.array([[1.0], [1.0]]))
    np.testing.assert_allclose([pooled[0], se[0], tau2[0], q[0]], [5.0, 5.0, 49.0, 50.0])


def _system(rng, n, coef_by_band):
    """Three axes, one effect column (a sum of sines at 0.5-10 Hz) and a constant per axis; the
    residual is the effect times its coefficient (per frequency) plus white noise."""
    freqs = (0.5, 1.5, 3.0, 6.0, 10.0)
    parts = [np.stack([_signal(rng, n, (f,)) for _ in range(3)], 1) for f in freqs]
    x = sum(parts)
    z = sum(c * p for c, p in zip(coef_by_band, parts)) + rng.normal(0.0, 0.5, (n, 3))
    X = np.zeros((n, 3, 4))
    X[:, :, 0] = x
    for k in range(3):
        X[:, k, 1 + k] = 1.0
    block = (np.arange(n) * DT // 2.0).astype(int)
    return X, z, np.ones(n, bool), block


def test_one_effect_agrees_across_bands_and_pools_to_the_truth():
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(20):
        X, z, rows, block = _system(rng, 12000, (0.01,) * 5)
        bc = band_check(X, z, rows, block, DT, [0], np.zeros(1))
        assert bc.est.shape[0] == 5
        hits += abs(bc.pooled[0] - 0.01) <= 1.96 * bc.pooled_se[0]
        assert bc.q[0] < stats.chi2.ppf(0.999, bc.dof)
    assert hits >= 16  # ~95 % coverage of 20 (measured: see the assertion message if it fails)


def test_a_band_dependent_coefficient_widens_the_pooled_interval():
    rng = np.random.default_rng(1)
    X, z, rows, block = _system(rng, 12000, (0.03, 0.02, 0.01, 0.0, -0.01))
    bc = band_check(X, z, rows, block, DT, [0], np.zeros(1))
    assert bc.q[0] > stats.chi2.ppf(0.999, bc.dof)  # the bands disagree, far beyond their noise
    assert bc.tau2[0] > 0
    fixed_se = 1.0 / np.sqrt(np.sum(1.0 / bc.se[:, 0] ** 2))
    assert bc.pooled_se[0] > 3 * fixed_se  # measured 4.1x
    # the pooled value targets the bands' average coefficient (0.01), and its interval says so
    # (measured: pooled 0.0107, se 0.0063, while the fixed-effect se is 0.0015)
    assert abs(bc.pooled[0] - 0.01) <= 2 * bc.pooled_se[0]


def test_widen_information_closed_form():
    # diagonal information: each variance 1/F_jj grows by tau2_j, so the information is 1/(1/F_jj + tau2_j)
    F = np.diag([4.0, 1e6])
    np.testing.assert_allclose(widen_information(F, np.array([0.25, 0.0])), np.diag([1.0 / (0.25 + 0.25), 1e6]), rtol=1e-12)
    # correlated: (F^-1 + D)^-1 against numpy's inverse; no spread leaves F as it is
    F = np.array([[2.0, 0.5], [0.5, 1.0]])
    D = np.diag([0.3, 0.1])
    np.testing.assert_allclose(widen_information(F, np.diag(D)), np.linalg.inv(np.linalg.inv(F) + D), rtol=1e-12)
    assert widen_information(F, np.zeros(2)) is F


def _inputs(n):
    t = np.arange(n) * DT
    z = np.zeros((n, 3))
    return E.Inputs(z, z, z, t - t.mean(), np.zeros(n), np.asarray(DT))


def test_candidate_spread_is_what_the_bands_disagree_by():
    # the candidate (column 0) against the baseline (constants): before it is fitted, its between-band
    # variance is ~0 when one coefficient holds in every band, and about the bands' spread when not
    rng = np.random.default_rng(2)
    X, z, rows, _ = _system(rng, 12000, (0.01,) * 5)
    same = candidate_spread(X, z, rows, _inputs(len(z)), [1, 2, 3], [0])
    X, z, rows, _ = _system(rng, 12000, (0.03, 0.02, 0.01, 0.0, -0.01))
    differ = candidate_spread(X, z, rows, _inputs(len(z)), [1, 2, 3], [0])
    assert same.shape == (1,) and differ.shape == (1,)
    assert same[0] <= 1e-6  # the sampling noise alone (tau2 is truncated at 0; measured 0)
    # the five coefficients' variance is 2.5e-4; DerSimonian-Laird's tau2 estimates it from five bands
    assert 0.25 * 2.5e-4 <= differ[0] <= 4 * 2.5e-4  # measured 2.29e-4
