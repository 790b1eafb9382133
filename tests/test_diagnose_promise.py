"""The promise of ``diagnose`` (issue 14): a named effect lowers the held-out rms the report prints,
no sensor ends worse than its baseline, and an implausible estimate is a warning, not a name.

``tests/conftest.py`` checks every report of the suite; here the checker itself is tested against
reports that break the promise, and a property test draws effects, sizes and noise at random.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxcal.diagnose as D
from jaxcal.diagnose import diagnose_recording
from jaxcal.diagnose import effects as E
from jaxcal.diagnose.report import promise_violations
from jaxcal.diagnose.simulate import RichConfig, simulate_recording

CFG = RichConfig(n=3000)


def _rep(before, after, final, base, params=None, lim=None, forced=False):
    e = {"name": "lever_arm", "sensor": "acc", "params": params or {"r": [0.01, 0, 0]}, "heldout_rms_before": before,
         "heldout_rms_after": after, "plausible_max_abs": lim, "forced": forced}
    return {"effects": [e], "baseline": {"acc": {"heldout_rms": base}}, "final": {"acc": {"heldout_rms": final}}}


def test_checker_flags_each_broken_promise():
    assert promise_violations(_rep(1.0, 0.9, 0.9, 1.0, lim=1.0)) == []
    assert promise_violations(_rep(1.0, 1.1, 0.9, 1.0))  # the effect raised its held-out rms
    assert promise_violations(_rep(1.0, 1.0, 0.9, 1.0))  # no gain is no name
    assert promise_violations(_rep(1.0, 0.9, 1.2, 1.0))  # final above the baseline
    assert promise_violations(_rep(1.0, 0.9, 0.9, 1.0, params={"r": [0.0, 2.0, 0.0]}, lim=1.0))  # implausible
    assert promise_violations(_rep(1.0, 1.1, 1.2, 1.0, forced=True)) == []  # align's estimates are not names


def test_suite_reports_go_through_the_checker():
    assert getattr(D.diagnose_recording, "__wrapped_by_promise_check__", False)
    assert getattr(diagnose_recording, "__wrapped_by_promise_check__", False)


EFFECTS = [("acc", "lever_arm"), ("acc", "scale_nonlinearity"), ("acc", "misalignment"), ("acc", "bias_drift"),
           ("gyr", "g_sensitivity"), ("gyr", "scale_nonlinearity"), ("gyr", "time_offset"), ("gyr", "misalignment")]
# typical sizes near this recording's detectability (a few x its minimum detectable size)
SIZE = {("acc", "lever_arm"): 0.01, ("acc", "scale_nonlinearity"): 2e-3, ("acc", "misalignment"): 2e-3,
        ("acc", "bias_drift"): 2e-5, ("gyr", "g_sensitivity"): 1e-3, ("gyr", "scale_nonlinearity"): 2e-3,
        ("gyr", "time_offset"): 1.5e-3, ("gyr", "misalignment"): 2e-3}


@pytest.mark.slow
@settings(max_examples=8, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(which=st.integers(0, len(EFFECTS) - 1), scale=st.floats(0.0, 3.0), seed=st.integers(0, 2**16),
       rw=st.booleans(), baseline=st.sampled_from(["diag", "affine"]), reference=st.sampled_from(["motion", "none"]))
def test_promise_holds_on_random_recordings(which, scale, seed, rw, baseline, reference):
    """Any effect at 0-3x a typical detectable size, white or random-walk noise, either baseline,
    against the reference motion or without one (:mod:`jaxcal.diagnose.noref`, the recording's
    own gyro-carried gravity and rests): the report keeps the promise (zero size: the null case).

    Fast cover: tests/test_diagnose_promise.py::test_suite_reports_go_through_the_checker (every
    report the fast tier produces, simulated and real, with and without a reference, is checked
    against the same promise), tests/test_diagnose_promise.py::test_checker_flags_each_broken_promise
    """
    sensor, name = EFFECTS[which]
    if baseline == "affine" and name == "misalignment":
        name = "scale_nonlinearity"
    sl = E.slot(sensor, name)
    rng = np.random.default_rng(seed)
    v = rng.standard_normal(sl.size)
    v = SIZE[(sensor, EFFECTS[which][1])] * scale * v / np.linalg.norm(v)
    cfg = CFG._replace(acc_rw_g_per_sqrt_s=1e-4, gyr_rw_rads_per_sqrt_s=3e-5) if rw else CFG
    rec, _ = simulate_recording(jax.random.PRNGKey(seed), cfg, {(sensor, name): {sl.param: v if sl.shape else v[:1]}})
    rep = diagnose_recording(rec, baseline=baseline, reference=reference)
    assert promise_violations(rep) == []
    assert (rep.get("reference") == "none") == (reference == "none")
