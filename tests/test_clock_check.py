"""``jaxcal.diagnose.clock_check.line_check``: is one offset line enough for a recording's windows
(issue 29)? Checked against numpy's weighted polyfit and the chi-square's own distribution."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import fake_align

from jaxcal.diagnose import clock_check
from jaxcal.diagnose.clock_check import line_check
from jaxcal.recording import Recording


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


def _still(seconds: float = 200.0, fs: float = 100.0) -> Recording:
    """A recording whose gyro norm is 0.5 rad/s everywhere and whose reference is missing on every
    fourth row of the first half (``ref_valid``)."""
    n = int(seconds * fs)
    return Recording(t=np.arange(n) / fs, acc=np.tile([0.0, 0.0, 1.0], (n, 1)), gyr=np.tile([0.3, -0.4, 0.0], (n, 1)),
                     acc_unit="g", gyr_unit="rad/s", ref_valid=(np.arange(n) % 4 != 0) | (np.arange(n) >= n // 2))


def test_windows_cover_the_recording_once_and_a_steady_clock_holds(monkeypatch):
    monkeypatch.setattr(clock_check, "align_recording", fake_align(4e-3, -1.5))
    rec = _still()
    out = clock_check.clock_windows(rec, 4)
    w = out["windows"]
    assert len(w) == 4 and w[0]["t0_s"] == rec.t[0] and w[-1]["t1_s"] == rec.t[-1]
    assert all(np.isclose(a["t1_s"] + 0.01, b["t0_s"]) for a, b in zip(w[:-1], w[1:]))  # consecutive, every row once
    assert out["line"]["slope_ppm"] == pytest.approx(-1.5, abs=1e-6) and out["line"]["chi2"] < 1e-9  # measured 2e-16, 0
    assert out["line"]["p"] > 0.99
    assert [x["ref_valid_frac"] for x in w] == [0.75, 0.75, 1.0, 1.0]
    assert all(x["gyr_rms"] == pytest.approx(0.5, rel=1e-12) for x in w)  # measured 1e-16


def test_a_stepped_offset_is_not_held_by_one_line(monkeypatch):
    monkeypatch.setattr(clock_check, "align_recording", fake_align(4e-3, 0.0, step=-1e-3))
    out = clock_check.clock_windows(_still(), 4)
    assert out["line"]["p"] < 1e-6
    with pytest.raises(ValueError, match="at least 3 windows"):
        clock_check.clock_windows(_still(), 2)


@pytest.mark.parametrize("k,lo,hi", [(1.0, 0.93, 0.985), (3.0, 0.92, 0.97), (10.0, 0.93, 0.97)])
def test_the_scaled_interval_covers_lines_whose_offsets_scatter_more_than_stated(k, lo, hi):
    """Offsets that scatter ``k`` times their stated standard errors (4 windows, dof 2): the 95 %
    interval with the scatter taken in (Birge's scale factor, Student's t on dof) covers the true
    slope; measured on 4000 lines: 0.971, 0.939, 0.950 (binomial sd 0.0035). The unscaled one
    covered 0.487 and 0.154 at k = 3 and 10, the scaled one with 1.96 instead of t 0.839 and 0.824."""
    rng = np.random.default_rng(0)
    t, se = np.array([23.0, 70.0, 117.0, 164.0]), np.array([1e-4, 4e-5, 7e-5, 7e-5])
    c = [line_check(t, 4e-3 - 1e-6 * t + rng.normal(0, k * se), se) for _ in range(4000)]
    cover = np.mean([abs(x.slope_ppm + 1.0) <= x.slope_half95_ppm for x in c])
    assert lo < cover < hi
    x = c[0]  # the closed forms
    assert x.scale == pytest.approx(max(1.0, np.sqrt(x.chi2 / 2)), rel=1e-12)
    assert x.slope_se_scaled_ppm == pytest.approx(x.slope_se_ppm * x.scale, rel=1e-12)
    q = 4.302652729911275 if x.scale > 1 else 1.959963984540054  # t(0.975, 2 dof), normal
    assert clock_check.scaled_half95(0.5, x) == pytest.approx(0.5 * q * x.scale, rel=1e-9)
