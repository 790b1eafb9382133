"""The scoring layer (:mod:`jaxcal.eval`) against closed forms on simulated rests.

A noise-free multi-pose session (:func:`jaxcal.simulate.multipos.simulate_poses`, counts rounded)
with known calibrations: the true calibration scores ~0; a calibration with a known error scores
its closed form (an accelerometer scale ``1 + e`` gives ``| |f| - 1 g | = e`` at every pose; a
gyroscope scale ``1 + e`` turns a rotation by ``theta`` about ``n`` into ``(1 + e) theta``, so the
carried gravity misses by ``alpha``, ``cos alpha = c^2 + (1 - c^2) cos(e theta)``, ``c = n . f``).
The row builders, the fold loop and the time split are checked against hand-computed answers.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxcal import multipos as mp
from jaxcal.eval import seqsplit
from jaxcal.eval.heldout import fold_errors
from jaxcal.eval.scores import quality_row, score_cal
from jaxcal.recording import Recording
from jaxcal.sensor import LinearCal
from jaxcal.simulate.multipos import ACC_TRUTH, GYR_TRUTH, simulate_poses

FS, REST, HOLD, MOVE, P = 100.0, 10.0, 2.0, 1.5, 8
ROUND_G = np.sqrt(3) * 0.5 / 16000  # noise-free counts rounded: at most 0.5 LSB per axis (~16000 LSB/g)
# and the gyro's: 0.5 LSB per axis at 7500 LSB/(rad/s) integrated over a ~1.9 s transition (measured max 1.4e-4)
GYRO_FLOOR = 2.5e-4  # rad
G_SENS = np.array([[4e-3, 0.0, -2e-3], [0.0, 3e-3, 0.0], [2e-3, 0.0, -4e-3]])  # (rad/s)/g


def _rots() -> np.ndarray:
    rots = Rotation.random(P, random_state=11).as_matrix()
    rots[0] = np.eye(3)
    return rots


@functools.cache
def _session(gsens: bool = False):
    """The poses and transitions of a noise-free session (inner parts of the holds), and its rotations."""
    rots = _rots()
    t, acc, gyr = simulate_poses(None, rots=rots, fs=FS, rest=REST, hold=HOLD, move=MOVE, noise=False,
                                 gsens=G_SENS if gsens else None)
    n0, nh, nm = int(REST * FS), int(HOLD * FS), int(MOVE * FS)
    starts = [0] + [n0 + nm + j * (nh + nm) for j in range(P - 1)]
    iv = np.array([(s + 20, s + (n0 if j == 0 else nh) - 20) for j, s in enumerate(starts)])
    return mp.prepare(t, acc, gyr, iv), rots


def _scaled(cal: LinearCal, e: float) -> LinearCal:
    return LinearCal(np.asarray(cal.A) * (1.0 + e), np.asarray(cal.b))


def test_the_true_calibration_scores_zero():
    data, _ = _session()
    ea, eg = score_cal(ACC_TRUTH, GYR_TRUTH, data)
    assert ea.shape == (P,) and eg.shape == (P - 1,)
    assert np.max(np.abs(ea)) < ROUND_G
    assert np.max(eg) < GYRO_FLOOR


def test_an_accelerometer_scale_error_scores_its_size_and_leaves_the_gyro_alone():
    data, _ = _session()
    e = 2e-3
    ea, eg = score_cal(_scaled(ACC_TRUTH, e), GYR_TRUTH, data)
    np.testing.assert_allclose(ea, e, atol=1.1 * ROUND_G)
    _, eg0 = score_cal(ACC_TRUTH, GYR_TRUTH, data)
    np.testing.assert_allclose(eg, eg0, atol=1e-9)  # directions unchanged


def test_a_gyro_scale_error_scores_the_closed_form_angle():
    data, rots = _session()
    e = 0.02
    _, eg = score_cal(ACC_TRUTH, _scaled(GYR_TRUTH, e), data)
    want = []
    for j in range(P - 1):
        rv = Rotation.from_matrix(rots[j].T @ rots[j + 1]).as_rotvec()
        theta = np.linalg.norm(rv)
        f = rots[j].T @ [0.0, 0.0, 1.0]  # gravity direction in pose j's body frame
        c = rv @ f / theta
        want.append(np.arccos(np.clip(c**2 + (1 - c**2) * np.cos(e * theta), -1, 1)))
    np.testing.assert_allclose(eg, want, rtol=1e-2, atol=GYRO_FLOOR)
    assert np.min(want) > 4 * GYRO_FLOOR  # every transition's error is well above the floor


def test_the_gyro_g_sensitivity_is_scored_when_given():
    data, _ = _session(gsens=True)
    _, with_g = score_cal(ACC_TRUTH, GYR_TRUTH, data, G_SENS)
    _, without = score_cal(ACC_TRUTH, GYR_TRUTH, data)
    assert np.max(with_g) < GYRO_FLOOR and np.median(without) > 5 * GYRO_FLOOR  # measured 11x
    _, folded = fold_errors([(ACC_TRUTH, GYR_TRUTH, G_SENS)], data, np.zeros(P, int))  # (acc, gyr, G) per fold
    np.testing.assert_array_equal(folded, with_g)


def test_quality_row_is_the_rms_and_median_of_the_scored_items():
    row = quality_row(np.array([3e-3, 4e-3]), np.radians([1.0, np.nan, 3.0, 2.0]), "x")
    assert row == {"acc_rms_mg": pytest.approx(1e3 * np.sqrt(12.5e-6)), "gyr_median_deg": pytest.approx(2.0),
                   "how": "x"}
    empty = quality_row(np.array([]), np.array([np.nan]), "none")
    assert empty["acc_rms_mg"] is None and empty["gyr_median_deg"] is None


def test_fold_errors_score_each_pose_by_the_fold_that_left_it_out():
    """Fold k's calibration has the accelerometer scale error e_k: each pose scores the e of its own
    fold; the pose in no fold (-1) and the poses of an unscored fold are NaN, and each transition
    takes the fold of the pose it starts at."""
    data, _ = _session()
    es = [1e-3, 2e-3, 3e-3]
    cals = [(_scaled(ACC_TRUTH, e), _scaled(GYR_TRUTH, 0.01 * (k + 1))) for k, e in enumerate(es)]
    pf = np.array([-1, 0, 1, 2, 0, 1, 2, 0])
    ea, eg = fold_errors(cals, data, pf, scored=np.array([True, True, False]))
    want = np.array([np.nan, 1e-3, 2e-3, np.nan, 1e-3, 2e-3, np.nan, 1e-3])
    np.testing.assert_allclose(ea, want, atol=1.1 * ROUND_G)
    for j in range(P - 1):
        k = pf[j]
        if k in (0, 1):
            np.testing.assert_allclose(eg[j], score_cal(*cals[k], data)[1][j])
        else:
            assert np.isnan(eg[j])


def test_time_split_rows_fit_on_the_first_sequences_and_score_the_last():
    """12 sequences: the last round(0.2 * 12) = 2 are held out; the scorers see exactly those ranges."""
    n = 10
    seq = np.repeat(np.arange(12), n)
    rec = Recording(t=np.arange(12 * n) / FS, acc=np.tile([0.0, 0.0, 1.0], (12 * n, 1)), gyr=np.zeros((12 * n, 3)),
                    seq=seq, acc_unit="g", gyr_unit="rad/s")
    seen = {}

    def score(bounds):
        seen["all"] = list(bounds)
        return np.full(2 * len(bounds), 1e-3), np.full(2 * len(bounds), np.radians(0.5))

    def fit_score(train, test):
        seen["train"], seen["test"] = list(train), list(test)
        return np.full(2 * len(test), 2e-3), np.full(2 * len(test), np.radians(1.5))

    ins, ho = seqsplit.time_split_rows(rec, True, score, fit_score, "fitted")
    assert seen["all"] == [(k * n, (k + 1) * n) for k in range(12)]
    assert seen["train"] == seen["all"][:10] and seen["test"] == seen["all"][10:]
    assert ins["acc_rms_mg"] == pytest.approx(1.0) and ins["gyr_median_deg"] == pytest.approx(0.5)
    assert ho["acc_rms_mg"] == pytest.approx(2.0) and ho["gyr_median_deg"] == pytest.approx(1.5)
    assert "first 10 sequences, scored on the last 2" in ho["how"] and "initial_guess" not in ho
    _, too_few = seqsplit.time_split_rows(rec.replace(seq=np.repeat(np.arange(2), 6 * n)), True, score, fit_score, "x")
    assert "too few" in too_few["error"]


def test_applied_errors_equal_the_calibration_scored_on_raw_counts():
    """A second route to the same score: the calibrated outputs scored with the identity equal the
    raw counts scored with the calibration (sequences = each pose's inner hold)."""
    rots = _rots()
    t, acc, gyr = simulate_poses(None, rots=rots, fs=FS, rest=REST, hold=HOLD, move=MOVE, noise=False)
    rec = Recording(t=t, acc=acc, gyr=gyr, seq=np.zeros(len(t), int))
    bounds = [(0, 900), (1160, 1340)]  # rest 0 ... rest 1 (the move between them inside)
    acc_c, gyr_c = np.asarray(ACC_TRUTH.apply(acc)), np.asarray(GYR_TRUTH.apply(gyr))
    a1, g1 = seqsplit.applied_errors(acc_c, gyr_c, rec, bounds)
    a2, g2 = score_cal(ACC_TRUTH, GYR_TRUTH, seqsplit.ends_data(rec, bounds))
    np.testing.assert_allclose(a1, a2, atol=1e-12)
    np.testing.assert_allclose(g1, g2, atol=1e-9, equal_nan=True)
