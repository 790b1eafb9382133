"""``jaxcal.diagnose.clock_check.line_check``: is one offset line enough for a recording's windows
(issue 29)? Checked against numpy's weighted polyfit and the chi-square's own distribution."""

from __future__ import annotations

import numpy as np
import pytest

from jaxcal.diagnose.clock_check import line_check


def test_offsets_on_a_line_give_its_slope_and_no_misfit():
    t = np.array([20.0, 60.0, 100.0, 140.0])
    c = line_check(t, 4e-3 + 2.5e-6 * t, np.full(4, 3e-5))
    assert c.slope_ppm == pytest.approx(2.5, abs=1e-9)  # measured 9e-15
    assert c.chi2 < 1e-12 and c.dof == 2 and c.p == pytest.approx(1.0)


def test_the_line_is_numpys_weighted_fit_and_a_step_is_refused():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 180, 5))
    se = rng.uniform(1e-5, 8e-5, 5)
    y = 4e-3 + rng.normal(0, se)
    c = line_check(t, y, se)
    slope, icpt = np.polyfit(t, y, 1, w=1 / se)  # polyfit weighs the residuals by w = 1 / sigma
    assert c.slope_ppm == pytest.approx(slope * 1e6, rel=1e-9)  # measured 7e-14 relative (chi2: 2e-14)
    assert c.chi2 == pytest.approx(np.sum(((y - (slope * t + icpt)) / se) ** 2), rel=1e-9)
    stepped = line_check(t, y + np.where(t > 90, 1.5e-3, 0.0), se)  # a 1.5 ms step: BROAD 21's size
    assert stepped.p < 1e-6 < c.p


def test_p_values_of_true_lines_are_uniform():
    rng = np.random.default_rng(0)
    t, se = np.array([23.0, 70.0, 117.0, 164.0]), np.array([1e-4, 4e-5, 7e-5, 7e-5])
    p = np.array([line_check(t, 4e-3 - 1e-6 * t + rng.normal(0, se), se).p for _ in range(4000)])
    assert abs(np.mean(p < 0.05) - 0.05) < 0.012  # binomial sd 0.0034 at 4000 draws; measured 0.052


@pytest.mark.parametrize("args", [([1.0], [0.0], [1.0]), ([1.0, 2.0], [0.0, 0.0], [1.0, 0.0]), ([1.0, 2.0, 3.0], [0.0, 0.0], [1.0, 1.0])])
def test_bad_input_is_refused(args):
    with pytest.raises(ValueError, match="line_check"):
        line_check(*(np.array(a) for a in args))
