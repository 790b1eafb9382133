"""Paired comparison: sign test closed forms, bootstrap intervals against the normal theory."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxcal.compare import paired_comparison, sign_test_p


def test_sign_test_closed_forms():
    assert sign_test_p(0, 8) == pytest.approx(2 / 256)
    assert sign_test_p(1, 7) == pytest.approx(2 * (1 + 8) / 256)
    assert sign_test_p(7, 1) == sign_test_p(1, 7)
    assert sign_test_p(4, 4) == 1.0 and sign_test_p(0, 0) == 1.0


def test_constant_shift_is_exact_and_worse():
    b = np.random.default_rng(0).uniform(0.2, 1.5, 9)
    c = paired_comparison(b + 0.1, b, jax.random.PRNGKey(0), n_boot=2000)
    assert c.mean_diff == pytest.approx(0.1) and c.median_diff == pytest.approx(0.1)
    assert c.ci_mean == pytest.approx((0.1, 0.1)) and c.ci_median == pytest.approx((0.1, 0.1))
    assert (c.wins, c.losses, c.verdict()) == (0, 9, "worse")
    assert paired_comparison(b - 0.1, b, jax.random.PRNGKey(0), n_boot=200).verdict("median") == "better"


def test_bootstrap_interval_matches_normal_theory():
    """Differences ~ N(0.05, 0.2^2), n = 400: the 95 % interval of the mean is 0.05 +- 1.96 s/sqrt(n)
    to within 10 % of its half-width, and contains 0.05."""
    rng = np.random.default_rng(1)
    b = rng.uniform(0, 1, 400)
    d = rng.normal(0.05, 0.2, 400)
    c = paired_comparison(b + d, b, jax.random.PRNGKey(2), n_boot=20000)
    half = 1.96 * d.std(ddof=1) / np.sqrt(len(d))
    lo, hi = c.ci_mean
    assert (hi - lo) / 2 == pytest.approx(half, rel=0.1)
    assert lo < 0.05 < hi and c.verdict() == "worse"


def test_small_noisy_difference_is_a_tie():
    rng = np.random.default_rng(3)
    b = rng.uniform(0.2, 1.5, 8)
    c = paired_comparison(b + rng.normal(0.0, 0.2, 8), b, jax.random.PRNGKey(0))
    assert c.verdict() == "tie" and c.verdict("median") == "tie" and c.sign_p > 0.05


def test_bad_input_is_an_error():
    k = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="same length"):
        paired_comparison(np.ones(3), np.ones(4), k)
    with pytest.raises(ValueError, match="finite"):
        paired_comparison(np.array([1.0, np.nan]), np.ones(2), k)
    with pytest.raises(ValueError, match="level"):
        paired_comparison(np.ones(3), np.ones(3), k, level=1.5)
