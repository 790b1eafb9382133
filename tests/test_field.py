"""Field calibration (``online`` between rests, :mod:`jaxcal.field`): against known simulated
parameters, closed forms and invariants; the refusal of a contradicted model through the CLI."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxcal import field
from jaxcal.eval.heldout import fold_errors
from jaxcal.methods import online as mo
from jaxcal.methods.summary import contradiction
from jaxcal.online import HOLD, OnlineHP
from jaxcal.recording import Recording
from jaxcal.sensor import LinearCal
from jaxcal.simulate.multipos import ACC_TRUTH, GYR_TRUTH, simulate_poses

FS = 100.0


def _session(n_poses: int = 14, seed: int = 0, trans_g: float = 0.0):
    """A simulated rest-motion session (raw counts, the package's ACC_TRUTH / GYR_TRUTH) and, when
    ``trans_g`` > 0, a translational acceleration of that amplitude (g) during every motion, as a
    hand adds: half a sine per motion along a fixed body direction (zero at rest)."""
    import jax

    rots = None
    t, acc, gyr = simulate_poses(jax.random.PRNGKey(seed), n_poses=n_poses, fs=FS, rest=10.0, hold=3.0, move=1.5,
                                 noise_seed=seed, rots=rots)
    if trans_g:
        w = (gyr - np.asarray(GYR_TRUTH.b)) @ np.asarray(GYR_TRUTH.A).T
        moving = np.linalg.norm(w, axis=1) > 1e-2
        starts = np.flatnonzero(np.diff(moving.astype(int)) == 1) + 1
        ends = np.flatnonzero(np.diff(moving.astype(int)) == -1) + 1
        a = np.zeros_like(acc)
        for s0, e0 in zip(starts, ends):
            ph = np.linspace(0, np.pi, e0 - s0)
            a[s0:e0] = trans_g * np.sin(ph)[:, None] * np.array([0.6, -0.48, 0.64])
        acc = np.round(acc + a @ np.linalg.inv(np.asarray(ACC_TRUTH.A)).T)
    return Recording(t=t, acc=acc, gyr=gyr, fs=FS, acc_unit="LSB", gyr_unit="LSB")


@pytest.fixture(scope="module")
def hand_session():
    return _session(trans_g=0.3)


def _rel_err(cal: LinearCal, truth: LinearCal) -> float:
    """Largest entry of ``A_est A_true^-1 - I`` (relative scale and cross-axis error)."""
    return float(np.abs(np.asarray(cal.A) @ np.linalg.inv(np.asarray(truth.A)) - np.eye(3)).max())


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_compose_is_applying_one_after_the_other(seed):
    rng = np.random.default_rng(seed)
    inner = LinearCal(np.eye(3) * 1e-3 + rng.normal(0, 1e-5, (3, 3)), rng.normal(0, 100, 3))
    outer = LinearCal(np.eye(3) + rng.normal(0, 0.02, (3, 3)), rng.normal(0, 0.01, 3))
    y = rng.normal(0, 2000, (5, 3))
    two = (((y - inner.b) @ inner.A.T) - outer.b) @ outer.A.T
    one = field.compose(outer, inner)
    np.testing.assert_allclose((y - one.b) @ np.asarray(one.A).T, two, rtol=1e-10, atol=1e-12)


def _toy_batch(usable):
    P = len(usable) + 1
    iv = np.array([(100 * j, 100 * j + 40 + j) for j in range(P)])
    acc = np.ones((100 * P, 3))
    return field.field_batch(acc, acc, iv, np.asarray(usable, bool)), iv


@settings(max_examples=60, deadline=None)
@given(st.lists(st.booleans(), min_size=2, max_size=9), st.integers(0, 2**31 - 1))
def test_every_streamed_rest_counts_its_norm_exactly_once(usable, seed):
    """Invariant of :func:`jaxcal.field.sequence_weights`: over the streamed sequences, each rest's
    ``|f|`` row (weight along the direction) is its sample count, once, whatever sequences a fold
    skips; an unusable motion carries no direction."""
    batch, iv = _toy_batch(usable)
    on = np.random.default_rng(seed).random(len(usable)) < 0.7
    w, wt = field.sequence_weights(batch, on.astype(float), "rests", 1e-3, 1e-2)
    n = iv[:, 1] - iv[:, 0]
    counted = np.zeros(len(iv))
    for j in range(len(usable)):
        counted[j] += w[j, 0]
        if batch.usable[j]:
            counted[j + 1] += w[j, batch.last[j]]
        else:
            assert batch.last[j] == 0
        assert np.all(w[j, 1:batch.last[j]] == 0)  # motion rows out of the fit ("rests")
    streamed = np.zeros(len(iv), bool)
    for j in np.flatnonzero(on):
        streamed[j] = True
        streamed[j + 1] |= bool(batch.usable[j])
    np.testing.assert_array_equal(counted, np.where(streamed, n, 0))
    assert np.all(wt[~on] == 0) and np.all(w[~on] == 0)


def test_field_recovers_the_simulated_calibration_despite_hand_accelerations(hand_session, x64):
    """On a simulated session whose motions carry 0.3 g of translational acceleration (the
    model has none), the rest-anchored filter recovers the true accelerometer and gyroscope
    (relative error of ``A``: measured 3e-4 / 6e-4 over seeds 0-2, against 4 / 2 LSB of noise) and
    stays at its initial guess's level, while streaming every sample (the simulation's recipe)
    is pulled off by the accelerations (measured 2e-2 and more). With the accelerometer held at its
    fit to the rests (``acc_prior_factor=HOLD``, ``online``'s default between rests) the
    accelerometer is the initial guess's (measured over seeds 0-2: A within 7e-11 and b within 3e-9
    relative; its prior information is 1e12 times the default's) and the gyroscope
    is still corrected to the truth (7e-5 here)."""
    rec = hand_session
    rests = mo.rest_sequences(rec, mo.OnlineOptions())
    init = field.rest_init(rests.data)
    batch = field.field_batch(rec.acc, rec.gyr, rests.intervals, rests.usable)
    hp = OnlineHP(sigma_acc=4.0 * float(np.asarray(ACC_TRUTH.A)[0, 0]), n_iter=8)
    sd = field.carried_sigma(init, rests.data, rests.usable.astype(float))
    rest_fit = field.fit_field(batch, init, 1 / FS, hp, "diag", "rests", sigma_dir=sd)
    all_fit = field.fit_field(batch, init, 1 / FS, hp, "diag", "all", sigma_dir=sd)
    assert _rel_err(rest_fit.acc, ACC_TRUTH) < 2e-3 and _rel_err(rest_fit.gyr, GYR_TRUTH) < 3e-3
    assert _rel_err(all_fit.acc, ACC_TRUTH) > 5 * _rel_err(rest_fit.acc, ACC_TRUTH)
    held = field.fit_field(batch, init, 1 / FS, hp._replace(acc_prior_factor=HOLD), "diag", "rests", sigma_dir=sd)
    assert _rel_err(held.acc, init.acc) < 1e-9 and _rel_err(held.gyr, GYR_TRUTH) < 3e-3
    np.testing.assert_allclose(held.acc.b, init.acc.b, rtol=1e-8)


def test_fold_fits_hold_out_their_rests_and_score_the_initial_guess_too(hand_session, x64):
    rec = hand_session
    rests = mo.rest_sequences(rec, mo.OnlineOptions())
    batch = field.field_batch(rec.acc, rec.gyr, rests.intervals, rests.usable)
    hp = OnlineHP(sigma_acc=4.0 * float(np.asarray(ACC_TRUTH.A)[0, 0]), n_iter=8)
    folds = field.fold_fits(rests.data, batch, 1 / FS, hp, 4, "diag", "rests")
    assert len(folds.final) == len(folds.init) == 4 and folds.determined.all()
    P = len(rests.intervals)
    assert folds.rest_fold[0] == -1 and set(folds.rest_fold[1:]) == set(range(4))
    ea, eg = fold_errors(folds.final, rests.data, folds.rest_fold, folds.determined)
    ea0, _ = fold_errors(folds.init, rests.data, folds.rest_fold, folds.determined)
    assert np.isnan(ea[0]) and np.isfinite(ea[1:]).all() and len(eg) == P - 1
    # 4 LSB of noise at ~16000 LSB/g over 300-sample rests: ~0.03 mg per rest mean; measured RMS 0.1 mg
    assert 1e3 * np.sqrt(np.mean(ea[1:] ** 2)) < 0.5 and 1e3 * np.sqrt(np.mean(ea0[1:] ** 2)) < 0.5


def test_contradiction_closed_forms():
    ok = {"held_out": {"acc_rms_mg": 1.0, "gyr_median_deg": 0.5,
                       "initial_guess": {"acc_rms_mg": 0.9, "gyr_median_deg": 0.5, "how": "x"}}}
    assert contradiction(ok) is None
    worse = {"held_out": {**ok["held_out"], "acc_rms_mg": 1.25 * 0.9 + 0.06}}
    assert "worse than its own starting point" in contradiction(worse)
    assert contradiction({"held_out": {**ok["held_out"], "acc_rms_mg": float("nan")}}) is not None
    assert "datasheet" in contradiction({"parameters": {"acc": {"scale_pct": [0.1, 0.2, 170000.0]}}})
    assert contradiction({"parameters": {"acc": {"scale_pct": [0.1, -49.0, 3.0]}}}) is None


def test_calibrate_refuses_a_contradicted_model_unless_forced(tmp_path, capsys, monkeypatch):
    """The CLI's wiring: exit 2 and nothing written when :func:`contradiction` objects; written,
    with a warning and the reason in the metadata, under ``--force``. The gate is the same for every
    method (``jaxcal.cli.calibrate``), so a cheap one runs it: ``linear`` on a small labelled
    recording (before: ``multipos`` on a simulated 12-pose session, 10 s of compiles on the 2-core
    machine for the same wiring)."""
    from jaxcal.cli import main
    from jaxcal.methods import summary
    from jaxcal.model_file import load_model
    from jaxcal.recording import save_recording

    rng = np.random.default_rng(1)
    f = rng.normal(size=(200, 3))
    f /= np.linalg.norm(f, axis=1, keepdims=True)
    rec = Recording(t=np.arange(200) / FS, acc=np.round(f * 16384.0 + 100.0), acc_ref=f, acc_unit="LSB")
    save_recording(rec, tmp_path / "r.npz")
    monkeypatch.setattr(summary, "contradiction", lambda desc: "made up for the test")
    out = tmp_path / "m.npz"
    code = main(["calibrate", "--method", "linear", str(tmp_path / "r.npz"), "--out", str(out), "-q",
                 "--no-held-out"])
    err = capsys.readouterr().err
    assert code == 2 and "not written: made up for the test" in err and not out.exists()
    code = main(["calibrate", "--method", "linear", str(tmp_path / "r.npz"), "--out", str(out), "-q",
                 "--no-held-out", "--force"])
    err = capsys.readouterr().err
    assert code == 0 and "warning" in err and load_model(out).meta["contradiction"] == "made up for the test"


def test_rest_seq_recording_is_the_thesis_layout(hand_session):
    """online-thesis between rests: equal, contiguous sequences, each from a rest to a rest, and
    datasheet values from the rests when the recording has none (within 1 % of the truth)."""
    rec = hand_session
    s = mo.rest_seq_recording(rec)
    ids, counts = np.unique(s.seq, return_counts=True)
    assert len(set(counts)) == 1 and np.all(np.diff(s.seq) >= 0)
    assert np.allclose(np.diff(s.t), 1 / FS)
    np.testing.assert_allclose(np.asarray(s.acc_lsb_per_g), 1 / np.diag(np.asarray(ACC_TRUTH.A)), rtol=1e-2)
    rests = mo.rest_sequences(rec, mo.OnlineOptions())
    assert len(ids) == int(rests.usable.sum())
    w = (s.gyr - np.asarray(GYR_TRUTH.b)) @ np.asarray(GYR_TRUTH.A).T
    first, last = (np.flatnonzero(np.r_[True, np.diff(s.seq) != 0]), np.flatnonzero(np.r_[np.diff(s.seq) != 0, True]))
    assert np.all(np.linalg.norm(w[first], axis=1) < 1e-2) and np.all(np.linalg.norm(w[last], axis=1) < 1e-2)


def _rest_means(seed: int, H: np.ndarray, P: int = 20):
    """P rests in random directions (identity accelerometer): gyro means ``b + H f`` plus the noise of
    a mean over 200-400 samples of unit noise."""
    from jaxcal.multipos.data import MultiposData

    rng = np.random.default_rng(seed)
    f = rng.normal(size=(P, 3))
    f /= np.linalg.norm(f, axis=1, keepdims=True)
    n = rng.integers(200, 400, P).astype(float)
    y = np.array([0.3, -0.2, 0.1]) + f @ H.T + rng.normal(size=(P, 3)) / np.sqrt(n)[:, None]
    z = np.zeros((P - 1, 1, 3))
    return MultiposData(f, y, n, z, np.zeros((P - 1, 1)), z, z, z, z, np.ones(P - 1, bool))


H_SHAPE = np.array([[0.2, 1.0, -0.5], [0.7, 0.1, 0.4], [-0.3, 0.6, -0.2]])
IDENTITY = LinearCal(np.eye(3), np.zeros(3))


def test_the_rests_choose_the_g_sensitivity_only_where_it_is():
    """Against the simulated truth: with no g-sensitivity the one-standard-error rule leaves it out
    (1 of 300 seeds chose it when measured: 0.3 %), with one of 0.2 x ``H_SHAPE`` (entries up to 3.4x a
    rest mean's noise) it takes it on every seed (300 of 300; 0.1 x: 93 %)."""
    null = [field.choose_gsens(_rest_means(s, 0 * H_SHAPE), IDENTITY).chosen for s in range(40)]
    there = [field.choose_gsens(_rest_means(s, 0.2 * H_SHAPE), IDENTITY).chosen for s in range(40)]
    assert sum(null) <= 1 and all(there)


def test_a_rest_left_out_takes_no_part_in_the_choice():
    d = _rest_means(3, 0.1 * H_SHAPE)
    keep = np.ones(20)
    keep[[2, 7, 11]] = 0
    kept = d._replace(pose_acc=d.pose_acc[keep > 0], pose_gyr=d.pose_gyr[keep > 0], pose_n=d.pose_n[keep > 0])
    assert field.choose_gsens(d, IDENTITY, keep) == field.choose_gsens(kept, IDENTITY)
    few = field.choose_gsens(d, IDENTITY, np.r_[np.ones(field.GSENS_MIN_RESTS - 1), np.zeros(21 - field.GSENS_MIN_RESTS)])
    assert not few.chosen and few.n_rests == field.GSENS_MIN_RESTS - 1
