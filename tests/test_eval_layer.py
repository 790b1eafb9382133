"""The scoring layer's public functions (:mod:`jaxcal.eval`) against independent truth.

Three small simulated sessions with known calibrations, noise-free:

- a multi-pose session (:func:`jaxcal.simulate.multipos.simulate_poses`, 14 random poses, counts
  rounded): fitted rows recover the simulated calibration, fixed rows score the closed form of a
  known error (an accelerometer scale ``1 + e`` gives ``| |f| - 1 g | = e`` at every pose);
- a Ferraris session built here (six faces, then three -360 deg turns about the vertical, each
  between two rests; constant-rate moves, so the midpoint Magnus sums integrate them exactly): the
  time-split runners score known errors in closed form (a gyro scale ``1 + e`` misses a closed
  turn by ``2 pi e`` and the carried gravity of a move by ``alpha``,
  ``cos alpha = c^2 + (1 - c^2) cos(e theta)``, ``c = n . u``), and imucal recovers the simulated
  calibration through :func:`~jaxcal.eval.peers.imucal_ferraris`;
- single turns between two rests for :mod:`jaxcal.eval.checks` (rotation by a known angle about a
  known axis, scipy's rotation as the truth).

Row builders and the paired comparison are checked against plain numpy on hand-made errors; the
published Tedaldi parameters against the upstream repository's own calibrated pose averages.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
from helpers import exp_so3_np
from scipy.spatial.transform import Rotation

from jaxcal import multipos as mp
from jaxcal.constants import G0
from jaxcal.eval import checks, heldout, peers
from jaxcal.eval.heldout import fair_data, fair_field, fair_multipos, fixed_errors, online_fit, online_heldout
from jaxcal.eval.scores import fair_row, paired_with_peer, score_cal, score_fixed, score_heldout, score_insample, summarise
from jaxcal.recording import load_recording
from jaxcal.sensor import Diag, LinearCal
from jaxcal.simulate.multipos import ACC_TRUTH, GYR_TRUTH, simulate_poses

DATA = Path(__file__).resolve().parent.parent / "data"
FS = 100.0
ROUND_G = np.sqrt(3) * 0.5 / 16000  # counts rounded: at most 0.5 LSB per axis (~16000 LSB/g)
GYRO_FLOOR = 2.5e-4  # rad: the gyro's rounding integrated over a move (tests/test_eval.py measured 1.4e-4)
G_SENS = np.array([[4e-3, 0.0, -2e-3], [0.0, 3e-3, 0.0], [2e-3, 0.0, -4e-3]])  # (rad/s)/g


def _raw(cal: LinearCal, x: np.ndarray) -> np.ndarray:
    """Outputs ``y = A^-1 x + b`` of a sensor with the applied calibration ``cal``."""
    return x @ np.linalg.inv(np.asarray(cal.A)).T + np.asarray(cal.b)


def _scaled(cal: LinearCal, e: float) -> LinearCal:
    return LinearCal(np.asarray(cal.A) * (1.0 + e), np.asarray(cal.b))


def _alpha(e: float, rv: np.ndarray, u: np.ndarray) -> float:
    """Carried-gravity angle of a rotation ``rv`` integrated with a gyro scale ``1 + e``, gravity ``u``."""
    theta = np.linalg.norm(rv)
    c = rv @ u / theta
    return float(np.arccos(np.clip(c**2 + (1 - c**2) * np.cos(e * theta), -1, 1)))


# ----------------------------------------------------------------------------- multi-pose session

P = 14


@functools.cache
def _poses(gsens: bool = False):
    """Poses and transitions of a noise-free 14-pose session (inner parts of the holds), and its poses' intervals."""
    rots = Rotation.random(P, random_state=5).as_matrix()
    rots[0] = np.eye(3)
    rest, hold, move = 4.0, 1.0, 1.0
    t, acc, gyr = simulate_poses(None, rots=rots, fs=FS, rest=rest, hold=hold, move=move, noise=False, gsens=G_SENS if gsens else None)
    n0, nh, nm = int(rest * FS), int(hold * FS), int(move * FS)
    starts = [0] + [n0 + nm + j * (nh + nm) for j in range(P - 1)]
    iv = np.array([(s + 10, s + (n0 if j == 0 else nh) - 10) for j, s in enumerate(starts)])
    return mp.prepare(t, acc, gyr, iv), (t, acc, gyr, iv)


# ----------------------------------------------------------------------------- Ferraris session

FACES = {"x_p": [1, 0, 0], "x_a": [-1, 0, 0], "y_p": [0, 1, 0], "y_a": [0, -1, 0], "z_p": [0, 0, 1], "z_a": [0, 0, -1]}
ACC_DIAG = LinearCal(np.diag(np.diag(ACC_TRUTH.A)), ACC_TRUTH.b)  # six faces determine a diagonal A exactly


def _face_rot(d) -> np.ndarray:
    """A body-to-world rotation with body axis ``d`` up (``R d = z``): its third row is ``d``."""
    d = np.asarray(d, float)
    r1 = np.cross(d, [0.3, 0.5, 0.8])
    r1 /= np.linalg.norm(r1)
    return np.stack([r1, np.cross(d, r1), d])


@functools.cache
def _ferraris(hold=150, move=100, rest=100, turn=200):
    """Specific force ``f`` (g) and body rate ``w`` (rad/s) of a Ferraris session: the six faces, then
    per axis a move to its ``_p`` face, a rest, a clockwise 360 deg turn about it (imucal's
    ``expected_angle=-360``) and a rest. Returns ``(t, f, w, bounds, moves)``: imucal's section
    bounds and, per move between two static sections, its sample range and rotation vector."""
    R = _face_rot(FACES["x_p"])
    fl, wl, bounds, moves = [], [], {}, []
    n = lambda: sum(len(x) for x in fl)  # noqa: E731

    def hold_(k):
        fl.append(np.tile(R.T @ [0, 0, 1.0], (k, 1)))
        wl.append(np.zeros((k, 3)))

    def rate_(w, k):  # sample i holds the rate of the step ending at it (as simulate_poses)
        nonlocal R
        step = exp_so3_np(w / FS)
        for _ in range(k):
            R = R @ step
            fl.append((R.T @ [0, 0, 1.0])[None])
            wl.append(w[None])

    def move_(R1, k):
        rv = Rotation.from_matrix(R.T @ R1).as_rotvec()
        moves.append(((n(), n() + k), rv))
        rate_(rv * FS / k, k)

    for i, (name, d) in enumerate(FACES.items()):
        if i:
            move_(_face_rot(d), move)
        a = n()
        hold_(hold)
        bounds[name] = (a + 10, a + hold - 10)
    for name, d in (("x_rot", [1, 0, 0]), ("y_rot", [0, 1, 0]), ("z_rot", [0, 0, 1])):
        move_(_face_rot(d), move)
        hold_(rest)
        m0 = n()
        rate_(-2 * np.pi * FS / turn * np.asarray(d, float), turn)
        bounds[name] = (m0 - 2, n() + 2)
        hold_(rest)
    f, w = np.concatenate(fl), np.concatenate(wl)
    return np.arange(len(f)) / FS, f, w, bounds, moves


def _plan(fold: int = 0) -> mp.TimeSplit:
    return mp.time_split(_ferraris()[3], fold, rest_n=50, rest_gap=5)


# ----------------------------------------------------------------------------- scores


def test_summarise_is_numpy_statistics_of_the_scored_items():
    ea = np.array([1e-3, 4e-3, 2e-3])
    eg = np.radians([1.0, np.nan, 3.0, 2.5])
    r = summarise(ea, eg, "what")
    assert r["acc_mean_mg"] == pytest.approx(7.0 / 3)  # (1 + 4 + 2) / 3
    assert r["acc_rms_mg"] == pytest.approx(np.sqrt(21.0 / 3))  # (1 + 16 + 4) / 3
    assert r["acc_max_mg"] == pytest.approx(4.0)
    assert r["gyr_mean_deg"] == pytest.approx(6.5 / 3) and r["gyr_median_deg"] == pytest.approx(2.5)
    assert (r["n_poses"], r["n_transitions"], r["scored"]) == (3, 3, "what")
    assert r["_acc_err"] is ea and r["_gyr_err"] is eg
    none = summarise(ea, np.full(2, np.nan), "x")
    assert none["gyr_mean_deg"] is None and none["gyr_median_deg"] is None and none["n_transitions"] == 0


def test_score_fixed_scores_a_known_accelerometer_error_on_every_pose():
    data, _ = _poses()
    e = 3e-3
    r = score_fixed(_scaled(ACC_TRUTH, e), GYR_TRUTH, data)
    for k in ("acc_mean_mg", "acc_rms_mg", "acc_max_mg"):
        assert r[k] == pytest.approx(1e3 * e, abs=1.1e3 * ROUND_G)  # every pose scores e (+- rounding): measured 0.016 mg off
    assert r["gyr_median_deg"] < np.degrees(GYRO_FLOOR)  # the true gyro: measured 0.0034 deg
    assert (r["n_poses"], r["n_transitions"]) == (P, P - 1) and "nothing fitted" in r["scored"]
    # an unusable transition (saturated gyro) is not scored
    cut = score_fixed(ACC_TRUTH, _scaled(GYR_TRUTH, 0.02), data._replace(seg_ok=np.arange(P - 1) != 4))
    assert cut["n_transitions"] == P - 2 and np.isnan(cut["_gyr_err"][4])


def _bent_pose(data: mp.MultiposData, i: int, e: float) -> mp.MultiposData:
    """Pose ``i``'s accelerometer mean moved to ``|f| = 1 + e`` (its direction kept), the rest exact."""
    pa = np.array(data.pose_acc)
    pa[i] = ACC_TRUTH.b + (1 + e) * (pa[i] - ACC_TRUTH.b)
    return data._replace(pose_acc=pa)


def test_score_heldout_scores_each_pose_by_a_fit_that_never_saw_it():
    """One pose off by ``e`` in ``|f|``, the other 13 exact: leaving it out recovers the simulated
    calibration, so it scores ``e`` held out (a fit that used it would absorb part of it);
    ``n_folds=P`` is the same split as ``None``."""
    data, _ = _poses()
    i, e = 6, 0.01
    r = score_heldout(_bent_pose(data, i, e), mp.MultiposConfig(), None)
    assert r["scored"] == "held out (leave-one-pose-out)" and (r["n_poses"], r["n_transitions"]) == (P, P - 1)
    assert r["_acc_err"][i] == pytest.approx(e, abs=2e-4)  # measured 6.3e-5 off (rounding, extrapolated); in-sample 5.0e-4
    r14 = score_heldout(_bent_pose(data, i, e), mp.MultiposConfig(), P)
    assert r14["scored"] == f"held out ({P} interleaved folds)"
    np.testing.assert_array_equal(r14["_acc_err"], r["_acc_err"])  # same folds, same compiled fit


def test_score_insample_scores_with_the_fitted_g_sensitivity():
    """A gyro with g-sensitivity: the in-sample row of a fit that models it scores the floor, on
    items the simulated calibration without ``G`` misses by the ``G f`` term."""
    data, _ = _poses(gsens=True)
    r = score_insample(data, mp.MultiposConfig(g_sensitivity=True))
    assert r["scored"].startswith("IN-SAMPLE") and (r["n_poses"], r["n_transitions"]) == (P, P - 1)
    assert r["acc_max_mg"] < 1e3 * ROUND_G  # measured 0.015 mg
    assert np.max(r["_gyr_err"]) < GYRO_FLOOR  # measured 5.8e-5 rad
    _, without_g = score_cal(ACC_TRUTH, GYR_TRUTH, data)
    assert np.median(without_g) > 5 * GYRO_FLOOR  # measured 2.2e-3 rad


def test_fair_row_pools_the_folds_and_adds_the_turns():
    parts = [
        (np.array([1e-3, 2e-3]), np.radians([1.0, np.nan]), np.radians([0.5, 1.5])),
        (np.array([3e-3]), np.radians([2.0, 4.0]), np.radians([1.0])),
    ]
    r = fair_row(parts, "two folds")
    assert r["acc_mean_mg"] == pytest.approx(2.0) and r["acc_max_mg"] == pytest.approx(3.0)
    assert r["gyr_median_deg"] == pytest.approx(2.0) and r["n_transitions"] == 3 and r["n_poses"] == 3
    assert r["turn_mean_deg"] == pytest.approx(1.0) and r["turn_max_deg"] == pytest.approx(1.5) and r["n_turns"] == 3
    np.testing.assert_array_equal(r["_turn_err"], np.radians([0.5, 1.5, 1.0]))
    assert r["scored"] == "two folds"


def test_paired_with_peer_compares_held_out_multipos_rows_item_by_item():
    """Only held-out ``jaxcal multipos`` rows are compared; the differences, wins and the verdict are
    numpy's on the items both rows scored (NaN dropped), gyro items in degrees."""
    rng = np.random.default_rng(0)
    peer_a, peer_g = rng.uniform(2e-3, 4e-3, 10), np.radians(rng.uniform(1.0, 2.0, 12))
    peer_g[3] = np.nan
    mine_g = peer_g - np.radians(0.5)
    mine_g[7] = np.nan
    rows = {
        "peer": {"_acc_err": peer_a, "_gyr_err": peer_g},
        "jaxcal multipos 9-param": {"_acc_err": peer_a - 1e-3, "_gyr_err": mine_g},
        "jaxcal multipos 9-param, in-sample": {"_acc_err": peer_a * 0, "_gyr_err": peer_g * 0},
        "another method": {"_acc_err": peer_a * 0, "_gyr_err": peer_g * 0},
        "jaxcal multipos worse": {"_acc_err": peer_a + 2e-3, "_gyr_err": mine_g + np.radians(1.0)},
    }
    out = paired_with_peer(rows, "peer")
    assert list(out) == ["jaxcal multipos 9-param", "jaxcal multipos worse"]
    a, g = out["jaxcal multipos 9-param"]["acc"], out["jaxcal multipos 9-param"]["gyr"]
    assert a["n"] == 10 and a["mean_diff"] == pytest.approx(-1e-3) and (a["wins"], a["losses"]) == (10, 0)
    both = np.isfinite(peer_g) & np.isfinite(mine_g)
    assert g["n"] == both.sum() == 10
    assert g["mean_diff"] == pytest.approx(np.mean(np.degrees(mine_g[both]) - np.degrees(peer_g[both])))  # -0.5 deg
    assert g["median_diff"] == pytest.approx(np.median(np.degrees(mine_g[both])) - np.median(np.degrees(peer_g[both])))
    assert a["verdict"] == g["verdict"] == g["verdict_median"] == "better"  # every item better: interval below 0
    w = out["jaxcal multipos worse"]
    assert w["acc"]["verdict"] == w["gyr"]["verdict"] == "worse" and w["gyr"]["mean_diff"] == pytest.approx(0.5)
    # gyr_items maps the errors to the items compared (two folds averaged: 12 -> 6 items, NaN where either was)
    pair = lambda e: np.degrees(np.mean(np.reshape(e, (2, 6)), 0))  # noqa: E731
    two = paired_with_peer(rows, "peer", pair)["jaxcal multipos 9-param"]["gyr"]
    assert two["n"] == 4 and two["mean_diff"] == pytest.approx(-0.5)  # items 3 and 7 pair with 9 and 1
    # ``also`` adds named rows after the multipos ones, whose bootstrap draws stay as they were
    more = paired_with_peer(rows, "peer", also=("another method", "not a row"))
    assert list(more) == ["jaxcal multipos 9-param", "jaxcal multipos worse", "another method"]
    assert all(more[n] == out[n] for n in out) and more["another method"]["acc"]["verdict"] == "better"


# ----------------------------------------------------------------------------- held-out runners


def test_online_heldout_leaves_each_pose_out_exactly_once(monkeypatch):
    """The fold loop with a stand-in for ``online_fit`` whose fold ``k`` returns an accelerometer scale
    error ``e_k``: each pose scores its own fold's ``e_k`` (so was scored by the fold that left it
    out, exactly once), no fold streams a sample of its left-out poses, a saturated transition is
    never streamed, and each sequence is ``pad`` samples of a pose, the motion, ``pad`` of the next."""
    data, (t, acc, gyr, iv) = _poses()
    data = data._replace(seg_ok=np.arange(P - 1) != 5)
    calls = []

    def fake(acc_, gyr_, segments, dt, aspec, gspec, sigma_acc):
        calls.append(list(segments))
        assert dt == pytest.approx(1 / FS) and sigma_acc == 1e-4
        return _scaled(ACC_TRUTH, 1e-3 * len(calls)), GYR_TRUTH

    monkeypatch.setattr(heldout, "online_fit", fake)
    pad = 30
    r = online_heldout(t, acc, gyr, iv, data, Diag(np.ones(3), np.zeros(3)), Diag(np.ones(3), np.zeros(3)), 1e-4, 3, pad=pad)
    pf = np.arange(P) % 3
    assert len(calls) == 3
    np.testing.assert_allclose(r["_acc_err"], 1e-3 * (pf + 1), atol=1.1 * ROUND_G)
    for k, segs in enumerate(calls):
        left_out = set().union(*(range(*iv[j]) for j in np.flatnonzero(pf == k)))
        assert not any(left_out & set(range(a, b)) for a, b in segs)
        starts = [int(np.flatnonzero((iv[:, 0] <= a) & (a < iv[:, 1]))[0]) for a, _ in segs]
        assert starts == [j for j in range(P - 1) if pf[j] != k and pf[j + 1] != k and j != 5]
        for j, (a, b) in zip(starts, segs):
            assert (a, b) == (iv[j, 1] - pad, iv[j + 1, 0] + pad)
    n = [len(s) for s in calls]
    assert r["scored"] == f"held out (3 interleaved pose folds; {min(n)}-{max(n)} sequences per fold)"
    assert np.isnan(r["_gyr_err"][5]) and r["n_transitions"] == P - 2
    calls.clear()
    loo = online_heldout(t, acc, gyr, iv, data, Diag(np.ones(3), np.zeros(3)), Diag(np.ones(3), np.zeros(3)), 1e-4, None)
    assert len(calls) == P and "leave-one-pose-out" in loo["scored"]
    np.testing.assert_allclose(loo["_acc_err"], 1e-3 * (np.arange(P) + 1), atol=1.1 * ROUND_G)


def test_online_fit_reads_only_its_segments_and_moves_towards_the_truth():
    """``online`` on eight pose-to-pose sequences of the simulated session: samples outside the segments
    do not change the result (bit for bit), and the fitted pair scores far below the prior centre."""
    data, (t, acc, gyr, iv) = _poses()
    segs = [(iv[j, 1] - 50, iv[j + 1, 0] + 50) for j in range(1, 9)]
    aspec = Diag(np.full(3, 16300.0), np.zeros(3))
    gspec = Diag(np.full(3, 7500.0), np.asarray(data.pose_gyr[0]))
    ca, cg = online_fit(acc, gyr, segs, 1 / FS, aspec, gspec, 1e-4)
    inside = np.zeros(len(t), bool)
    for a, b in segs:
        inside[a:b] = True
    junk = np.random.default_rng(1).normal(0, 3e4, acc.shape)
    ca2, cg2 = online_fit(np.where(inside[:, None], acc, junk), np.where(inside[:, None], gyr, junk), segs, 1 / FS, aspec, gspec, 1e-4)
    for x, y in zip((*ca, *cg), (*ca2, *cg2)):
        np.testing.assert_array_equal(x, y)
    ea, eg = score_cal(ca, cg, data)
    ea0, eg0 = score_cal(LinearCal(np.diag(1 / aspec.s), aspec.b), LinearCal(np.diag(1 / gspec.s), gspec.b), data)
    assert np.sqrt(np.mean(ea**2)) < 0.1 * np.sqrt(np.mean(ea0**2))  # measured 0.060 (2.1 mg against 35 mg)
    assert np.median(eg) < 0.2 * np.median(eg0)  # measured 0.025


def test_fair_data_cuts_each_static_section_in_halves_and_keeps_the_whole_motions():
    """Pose means over the fitted and scored halves, transitions over the whole motion between two
    sections (the same in both), turns as closed rotations, turn axes from the rests' fitted halves:
    each against numpy sums of the samples."""
    t, f, w, bounds, _ = _ferraris()
    rng = np.random.default_rng(2)
    acc, gyr = _raw(ACC_TRUTH, f) + rng.normal(0, 4, f.shape), _raw(GYR_TRUTH, w) + rng.normal(0, 2, w.shape)
    plan = _plan(1)
    fit_d, score_d, known, turns = fair_data(t, acc, gyr, plan)
    mean = lambda x, ivs: np.stack([x[a:b].mean(0) for a, b in ivs])  # noqa: E731
    np.testing.assert_allclose(fit_d.pose_acc, mean(acc, plan.fit_iv), rtol=1e-12)  # measured 0
    np.testing.assert_allclose(score_d.pose_acc, mean(acc, plan.score_iv), rtol=1e-12)
    np.testing.assert_allclose(score_d.pose_gyr, mean(gyr, plan.score_iv), rtol=1e-12)
    assert plan.fit_iv[0, 0] > plan.score_iv[0, 0]  # fold 1 fits the second halves
    np.testing.assert_array_equal(fit_d.sy, score_d.sy)  # the motions do not depend on the halves

    def integral(a, b):  # midpoint rate times dt from sample a to sample b
        return (0.5 * (gyr[a:b] + gyr[a + 1 : b + 1]) * np.diff(t[a : b + 1])[:, None]).sum(0)

    for j, (a, b) in enumerate(plan.spans):
        np.testing.assert_allclose(fit_d.sy[j].sum(0), integral(a, b), rtol=1e-12, atol=1e-9)  # measured 2.2e-11 LSB s
    assert known.R.shape == (3, 3, 3) and np.all(known.R == np.eye(3))
    for k, (a, b) in enumerate(plan.turns):
        np.testing.assert_allclose(known.sy[k].sum(0), integral(a, b), rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(turns.y_int[k], integral(a, b), rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(turns.rest_acc[k], acc[np.r_[tuple(slice(*x) for x in plan.turn_rests[k])]].mean(0), rtol=1e-12)
    np.testing.assert_allclose(turns.angle, 2 * np.pi)


def test_fixed_errors_score_known_errors_on_the_faces_motions_and_turns():
    t, f, w, bounds, moves = _ferraris()
    acc, gyr = _raw(ACC_TRUTH, f), _raw(GYR_TRUTH, w)
    plan = _plan(0)
    _, score_d, known, _ = fair_data(t, acc, gyr, plan)
    ea, eg, ek = fixed_errors(ACC_TRUTH, GYR_TRUTH, score_d, known, plan)
    assert ea.shape == (6,) and eg.shape == (11,) and ek.shape == (3,)  # faces only; every span; every turn
    assert np.max(ea) < 1e-12 and np.nanmax(eg) < 1e-12 and np.max(ek) < 1e-12  # measured 1.3e-14, 0, 1.9e-15
    np.testing.assert_array_equal(np.isnan(eg), plan.across_turn)
    e = 0.01
    ea, _, _ = fixed_errors(_scaled(ACC_TRUTH, e), GYR_TRUTH, score_d, known, plan)
    np.testing.assert_allclose(ea, e, atol=1e-12)  # measured 1.3e-14
    _, eg, ek = fixed_errors(ACC_TRUTH, _scaled(GYR_TRUTH, e), score_d, known, plan)
    np.testing.assert_allclose(ek, 2 * np.pi * e, rtol=1e-9)  # a 360 deg turn read 1 % long; measured 3.8e-14
    u = f[plan.score_iv[:, 0]]  # gravity direction of each static section (body frame)
    motions = np.flatnonzero(~plan.across_turn)
    want = [_alpha(e, rv, u[j]) for j, (_, rv) in zip(motions, moves)]
    np.testing.assert_allclose(eg[motions], want, rtol=1e-9)  # measured 6.3e-13


@functools.cache
def _corrupted_ferraris(span: int = 9, e: float = 0.04):
    """The Ferraris session whose gyro reads ``1 + e`` times the rate during the move of ``span``
    (the rest of the session exact): a fit that never used that move recovers the truth and
    scores it ``alpha(e)``."""
    t, f, w, bounds, moves = _ferraris()
    plan = _plan(0)
    i = list(np.flatnonzero(~plan.across_turn)).index(span)
    (a, b), rv = moves[i]
    w = w.copy()
    w[a:b] *= 1 + e
    acc, gyr = _raw(ACC_DIAG, f), _raw(GYR_TRUTH, w)
    return fair_data(t, acc, gyr, plan), plan, _alpha(e, rv, f[plan.score_iv[span, 0]])


def test_fair_multipos_scores_each_motion_by_the_fold_that_left_it_out():
    """Leave-one-motion-out on a session with one bad move (span 9, the 8th motion: a row/span index
    mix-up would show): its held-out error is the truth's closed-form ``alpha``; the faces score
    the truth; spans across a turn are NaN."""
    (fit_d, score_d, known, turns), plan, alpha = _corrupted_ferraris()
    ea, eg, ek = fair_multipos(fit_d, score_d, known, turns, plan, mp.MultiposConfig(), "vertical")
    assert ea.shape == (6,) and eg.shape == (11,) and ek.shape == (3,)
    np.testing.assert_array_equal(np.isnan(eg), plan.across_turn)
    assert np.max(ea) < 1e-9  # measured 5.6e-16
    assert eg[9] == pytest.approx(alpha, rel=1e-6)  # measured 1.2e-13 relative
    others = np.delete(np.flatnonzero(~plan.across_turn), 7)
    assert np.all(eg[others] > 1e-3) and np.all(ek > 1e-4)  # their folds fitted the bad move: measured >= 1.5e-3, 6.0e-3


def test_fair_multipos_on_turns_alone_holds_every_motion_out():
    """``motions=False``: one fit on the three (exact) turns recovers the truth, so every motion is
    held out at once: the bad move scores ``alpha``, the others and the (in-sample) turns ~0."""
    (fit_d, score_d, known, turns), plan, alpha = _corrupted_ferraris()
    ea, eg, ek = fair_multipos(fit_d, score_d, known, turns, plan, mp.MultiposConfig(), "vertical", motions=False)
    np.testing.assert_array_equal(np.isnan(eg), plan.across_turn)
    assert eg[9] == pytest.approx(alpha, rel=1e-6)  # measured 1.2e-13 relative
    assert np.nanmax(np.delete(eg, 9)) < 1e-6 and np.max(ek) < 1e-6 and np.max(ea) < 1e-9  # measured 1.5e-8 (arccos at 1), 2.0e-15, 5.6e-16


def test_fair_field_recovers_the_simulated_calibration_and_scores_like_fixed_errors():
    """The field path on one time fold of a simulated Ferraris session (known calibration, white
    noise 4 / 2 LSB, seed 5) recovers the calibration: scored on the held-out halves, motions and
    turns it never fitted (turns: never used), its errors stay near those of the truth itself on
    the same noisy items. Measured (max): faces 0.061 mg (truth 0.036), motions 0.0087 deg
    (truth 0.0089), turns 0.023 deg (truth 0.0052); the bounds are about 3x those. Spans across
    a turn are NaN, as ``fixed_errors`` scores them."""
    from jaxcal.methods.online import OnlineOptions, field_hp

    t, f, w, bounds, _ = _ferraris()
    rng = np.random.default_rng(5)
    acc = _raw(ACC_DIAG, f) + rng.normal(0, 4, f.shape)
    gyr = _raw(GYR_TRUTH, w) + rng.normal(0, 2, w.shape)
    plan = _plan(0)
    fit_d, score_d, known, _ = fair_data(t, acc, gyr, plan)
    ea, eg, ek = fair_field(acc, gyr, fit_d, score_d, known, plan, 1 / FS, field_hp(OnlineOptions(), None))
    ta, tg, tk = fixed_errors(ACC_DIAG, GYR_TRUTH, score_d, known, plan)
    assert ea.shape == (6,) and eg.shape == (11,) and ek.shape == (3,)
    np.testing.assert_array_equal(np.isnan(eg), plan.across_turn)
    assert np.max(ta) * 1e3 < 0.05 and np.degrees(np.nanmax(tg)) < 0.01 and np.degrees(np.max(tk)) < 0.01  # the items' noise
    assert np.max(ea) * 1e3 < 0.2 and np.degrees(np.nanmax(eg)) < 0.03 and np.degrees(np.max(ek)) < 0.07


def test_fair_multipos_with_closed_turns_does_not_start_at_a_wrong_revolution_count():
    """Known closed turns (``R_known = I``) are closed by any whole number of revolutions; the gyro
    scale's start is picked without them where motions are fitted, so on the exact session every
    motion scores ~0 held out (before, one fold started at ten revolutions and scored 99.99 deg)."""
    t, f, w, _, _ = _ferraris()
    plan = _plan(0)
    d = fair_data(t, _raw(ACC_DIAG, f), _raw(GYR_TRUTH, w), plan)
    ea, eg, ek = fair_multipos(*d, plan, mp.MultiposConfig(), "closed")
    assert np.nanmax(eg) < 1e-6 and np.max(ek) < 1e-6 and np.max(ea) < 1e-9  # measured 1.5e-8 rad (arccos at 1), 1e-14, 5.6e-16


# ----------------------------------------------------------------------------- checks


def _turn(axis, angle_deg: float, rest: int = 400, n_turn: int = 200, back: bool = False):
    """Outputs (g, rad/s) of a rest, a constant-rate turn by ``angle_deg`` about the body ``axis``
    (optionally followed by the turn back) and a rest, from the identity pose."""
    rv = np.radians(angle_deg) * np.asarray(axis, float) / np.linalg.norm(axis)
    rates = [rv * FS / n_turn] * n_turn + ([-rv * FS / n_turn] * n_turn if back else [])
    R, fl, wl = np.eye(3), [np.tile([0, 0, 1.0], (rest, 1))], [np.zeros((rest, 3))]
    for wi in rates:
        R = R @ exp_so3_np(wi / FS)
        fl.append((R.T @ [0, 0, 1.0])[None])
        wl.append(wi[None])
    fl.append(np.tile(R.T @ [0, 0, 1.0], (rest, 1)))
    wl.append(np.zeros((rest, 3)))
    f, w = np.concatenate(fl), np.concatenate(wl)
    return np.arange(len(f)) / FS, f, w, rv


def test_carried_rotation_is_the_turn_scipy_integrates():
    t, f, w, rv = _turn([1.0, 2.0, -0.5], 70.0)
    rot = checks.carried_rotation(t, _raw(ACC_TRUTH, f), _raw(GYR_TRUTH, w), GYR_TRUTH.A, GYR_TRUTH.b, rest=100, block=4)
    np.testing.assert_allclose(rot, Rotation.from_rotvec(rv).as_matrix(), atol=1e-12)  # measured 2e-15


def test_rotation_check_reads_the_angle_axis_and_carried_gravity_of_a_turn():
    beta = 20.0  # axis in the horizontal plane, 20 deg off x
    axis = [np.cos(np.radians(beta)), np.sin(np.radians(beta)), 0.0]
    t, f, w, _ = _turn(axis, 90.0)
    acc, gyr = _raw(ACC_TRUTH, f), _raw(GYR_TRUTH, w)
    r = checks.rotation_check(ACC_TRUTH, GYR_TRUTH, t, acc, gyr, block=4)
    assert r["angle_deg"] == pytest.approx(90.0, abs=1e-9) and r["off_axis_deg"] == pytest.approx(beta, abs=1e-6)  # measured 3e-14, 3e-14
    np.testing.assert_allclose(r["rotation_deg"], np.round(90.0 * np.asarray(axis), 2))
    assert r["carried_gravity_err_deg"] < 1e-5  # measured 0 (arccos at 1 resolves ~1e-6 deg)
    e = 0.02  # gyro scale 2 % high: the turn reads 91.8 deg; about a horizontal axis gravity misses by e * 90 deg
    r = checks.rotation_check(ACC_TRUTH, _scaled(GYR_TRUTH, e), t, acc, gyr, block=4)
    assert r["angle_deg"] == pytest.approx(90.0 * (1 + e), abs=1e-9)  # measured 9e-14
    assert r["carried_gravity_err_deg"] == pytest.approx(90.0 * e, abs=1e-6)  # measured 3e-12
    # the bias is the first rest's mean, whatever the calibration says
    r0 = checks.rotation_check(ACC_TRUTH, LinearCal(GYR_TRUTH.A, np.zeros(3)), t, acc, gyr, block=4)
    assert r0["angle_deg"] == pytest.approx(90.0, abs=1e-9)


def test_loop_closure_is_zero_back_at_the_start_and_the_integrated_bias_otherwise():
    t, f, w, _ = _turn([0.3, -1.0, 0.2], 120.0, n_turn=100, back=True)  # 1000 samples, as every recording here
    assert checks.loop_closure_deg(t, f, w, np.zeros(3)) < 1e-9  # measured 5.8e-15
    t1, f1, w1, _ = _turn([0.3, -1.0, 0.2], 120.0)
    assert checks.loop_closure_deg(t1, f1, w1, np.zeros(3)) == pytest.approx(120.0, abs=1e-9)
    b = np.array([2e-3, -1e-3, 3e-3])  # rad/s: a static recording integrates b from sample rest - 1 to N - rest
    n, rest = 1000, 100
    ts = np.arange(n) / FS
    still = np.tile([0, 0, 1.0], (n, 1))
    want = np.degrees(np.linalg.norm(b) * (n - 2 * rest + 1) / FS)
    assert checks.loop_closure_deg(ts, still, np.tile(b, (n, 1)), np.zeros(3), rest=rest) == pytest.approx(want, rel=1e-9)
    assert checks.loop_closure_deg(ts, still, np.tile(b, (n, 1)), b, rest=rest) < 1e-9


def test_static_norm_error_is_the_norm_of_the_mean_force():
    f = np.tile(np.array([0.2, -0.6, 0.7]) / np.linalg.norm([0.2, -0.6, 0.7]), (200, 1))
    assert checks.static_norm_error_mg(ACC_TRUTH, _raw(ACC_TRUTH, f)) < 1e-9
    assert checks.static_norm_error_mg(_scaled(ACC_TRUTH, 4e-3), _raw(ACC_TRUTH, f)) == pytest.approx(4.0, abs=1e-9)
    # noise of zero mean across the axis does not count (|mean f|, not mean |f|)
    wobble = np.tile([[0.05, 0, 0], [-0.05, 0, 0]], (100, 1))
    assert checks.static_norm_error_mg(ACC_TRUTH, _raw(ACC_TRUTH, f + wobble)) < 1e-9


# ----------------------------------------------------------------------------- peers


def test_datasheet_and_factory_calibrations_invert_their_equations():
    x = np.array([[0.1, -0.7, 0.7], [1.0, 0.0, 0.0]])
    ds = peers.datasheet(16384.0, 12.0)
    np.testing.assert_allclose(ds.apply(16384.0 * x + 12.0), x, atol=1e-15)
    np.testing.assert_array_equal(ds.b, [12.0, 12.0, 12.0])
    k = np.diag([415.0, 413.0, 418.0])
    m = np.array([[1.0, 0.0, -0.01], [0.01, 1.0, 0.01], [0.02, 0.01, 1.0]])
    off, g_local = np.array([33123.0, 33276.0, 32360.0]), 9.81744
    raw = (k @ m @ (x * g_local).T).T + off  # the factory's raw = K M f + offset, f in m/s^2
    np.testing.assert_allclose(peers.imu_tk_factory(k, m, off, g_local).apply(raw), x, atol=1e-12)  # measured 6.7e-16
    np.testing.assert_allclose(peers.imu_tk_factory(k, None, off).apply(k @ x[1] + off), x[1], atol=1e-12)


def test_tedaldi_published_reproduces_the_upstream_calibrated_pose_averages():
    """tomisuarez2/ImuCalibration's own calibrated accelerometer means of its 10 static intervals
    (m/s^2) from the raw session and its published parameters; the gyro against its README model
    ``w = T K (raw - bias)``."""
    d = DATA / "tomisuarez_mpu6050"
    pa = np.loadtxt(d / "optimization_result_data" / "params_acc.csv")
    pg = np.loadtxt(d / "optimization_result_data" / "params_gyro.csv")
    iv = np.loadtxt(d / "optimization_result_data" / "static_intervals.csv", delimiter=",").astype(int).T
    want = np.loadtxt(d / "optimization_result_data" / "calibrated_accel_avg_data.csv", delimiter=",")
    rec = load_recording(d / "calibration.npz")
    a_cal, g_cal = peers.tedaldi_published(pa, pg)
    means = np.stack([rec.acc[a:b].mean(0) for a, b in iv])
    np.testing.assert_allclose(G0 * np.asarray(a_cal.apply(means)), want, atol=1e-6)  # m/s^2; measured 4.3e-7
    m, s, b = pg[:6], pg[6:9], pg[9:]
    raw = np.array([120.0, -3400.0, 560.0])
    w = np.array([[1, -m[0], m[1]], [m[2], 1, -m[3]], [-m[4], m[5], 1]]) @ (s * (raw - b))
    np.testing.assert_allclose(g_cal.apply(raw), w, rtol=1e-12)


def test_imucal_ferraris_recovers_the_simulated_calibration():
    """imucal's Ferraris calibration on the simulated session (data in g and rad/s, a full
    misaligned accelerometer and gyroscope): converted back, it is the simulated calibration."""
    pytest.importorskip("imucal")
    _, f, w, bounds, _ = _ferraris()
    acc_cal = LinearCal(np.array([[1.02, 0.01, -0.015], [0.008, 0.98, 0.012], [-0.01, 0.02, 1.01]]), np.array([0.03, -0.02, 0.05]))
    gyr_cal = LinearCal(np.asarray(GYR_TRUTH.A) * 7500, np.array([0.02, -0.01, 0.015]))
    sec = {n: bounds[n] for n in (*mp.FERRARIS_FACES, *mp.FERRARIS_TURNS)}
    ia, ig = peers.imucal_ferraris(_raw(acc_cal, f), _raw(gyr_cal, w), sec, FS)
    np.testing.assert_allclose(ia.A, acc_cal.A, atol=1e-12)  # measured 1e-14 (imucal's grav 9.81 converted back)
    np.testing.assert_allclose(ia.b, acc_cal.b, atol=1e-12)  # measured 3e-15 g
    np.testing.assert_allclose(ig.A, gyr_cal.A, atol=1e-12)  # measured 4e-16
    np.testing.assert_allclose(ig.b, gyr_cal.b, atol=1e-12)  # measured 3e-18 rad/s
