"""Held-out fold runners for real recordings.

- :func:`stream_segments` / :func:`online_fit` / :func:`online_heldout`: jaxcal ``online`` streamed
  over chosen sample ranges, and scored on interleaved pose folds it never saw.
- :func:`fold_errors`: each pose (rest) scored by the fold's calibration that left it out, each
  transition by the fold that left out the pose it starts at (the one rest-fold loop).
- :func:`fair_data` / :func:`fair_multipos` / :func:`fixed_errors`: a continuous session cut by
  :func:`jaxcal.multipos.time_split` (each static section halved in time), so a peer that needs whole
  sections and jaxcal are scored on the same held-out halves, motions and turns.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal import field
from jaxcal import multipos as mp
from jaxcal import online as onl
from jaxcal.eval.scores import score_cal, summarise
from jaxcal.precision import float64
from jaxcal.sensor import Diag, LinearCal

__all__ = ["stream_segments", "fold_errors", "online_fit", "online_heldout", "fair_data", "fair_multipos", "fixed_errors", "fair_field"]


def stream_segments(acc: np.ndarray, gyr: np.ndarray, segments, dt: float, aspec: Diag | None, gspec: Diag | None,
                    hp: onl.OnlineHP, kind: str) -> tuple[LinearCal, LinearCal]:
    """The ``online`` filter (:func:`jaxcal.online.fit_online_recording`) streamed over the sample
    ranges ``segments`` ``[(a, b), ...)``, one sequence each, visited in order.

    Args:
        acc, gyr: (N, 3) sensor outputs of the whole recording.
        segments: sample ranges, one sequence each.
        dt: sample period (s).
        aspec, gspec: datasheet-like specs, the prior centre of the filter (``None``: from the data).
        hp: the filter's :class:`~jaxcal.online.OnlineHP`.
        kind: ``"affine"`` or ``"diag"``.
    """
    idx = np.concatenate([np.arange(a, b) for a, b in segments])
    seq = np.concatenate([np.full(b - a, k) for k, (a, b) in enumerate(segments)])
    return onl.fit_online_recording(np.asarray(acc, np.float64)[idx], np.asarray(gyr, np.float64)[idx], seq, dt,
                                    aspec, gspec, hp, kind)


def fold_errors(cals, data: mp.MultiposData, pose_fold: np.ndarray,
                scored: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Held-out errors of per-fold calibrations: each pose's ``| |f| - 1 |`` (g) from the fold that
    left it out, each transition's carried-gravity angle (rad) from the fold that left out the pose
    it starts at (:func:`~jaxcal.eval.scores.score_cal`); NaN for poses in no fold (fold id -1),
    unusable transitions and the items of folds not ``scored``.

    Args:
        cals: per fold ``k``, its ``(acc, gyr)`` or ``(acc, gyr, G)`` calibration (e.g. a
            :class:`~jaxcal.field.FieldInit`).
        data: the prepared poses and transitions.
        pose_fold: (P,) fold id of each pose (-1: in every fold's training set).
        scored: (F,) bool, the fold is scored (``None``: all).
    """
    pf = np.asarray(pose_fold)
    P = len(pf)
    ea, eg = np.full(P, np.nan), np.full(P - 1, np.nan)
    for k, cal in enumerate(cals):
        if scored is not None and not scored[k]:
            continue
        a, g = score_cal(cal[0], cal[1], data, *cal[2:])
        ea[pf == k] = a[pf == k]
        eg[pf[:-1] == k] = g[pf[:-1] == k]
    return ea, eg


def online_fit(acc: np.ndarray, gyr: np.ndarray, segments, dt: float, aspec: Diag, gspec: Diag,
               sigma_acc: float) -> tuple[LinearCal, LinearCal]:
    """jaxcal ``online`` (affine, streaming) on the sample ranges ``segments`` ``[(a, b), ...)``.

    Each range is one sequence (rotation about the sensor's centre, free start direction), visited in
    order; 8 Gauss-Newton iterations per sequence (the default 4 diverged on one Xsens fold of
    ``experiments/real_data.py``; the rows it scores are in results/real.md).

    Args:
        acc, gyr: (N, 3) sensor outputs of the whole recording.
        segments: sample ranges, one sequence each.
        dt: sample period (s).
        aspec, gspec: datasheet-like specs, the prior centre of the filter.
        sigma_acc: static accelerometer noise measured on the recording (its unit after ``aspec``).
    """
    return stream_segments(acc, gyr, segments, dt, aspec, gspec, onl.OnlineHP(sigma_acc=sigma_acc, n_iter=8), "affine")


def online_heldout(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, iv: np.ndarray, data: mp.MultiposData,
                   aspec: Diag, gspec: Diag, sigma_acc: float, n_folds: int | None, pad: int = 100) -> dict:
    """Held-out ``online`` score row with the poses' interleaved folds.

    Fold ``k`` streams the sequences ``pose j -> pose j + 1`` (the last ``pad`` samples of pose ``j``,
    the motion, the first ``pad`` samples of pose ``j + 1``) whose two poses are both outside fold
    ``k`` and whose gyro does not saturate; it is scored on the poses of fold ``k`` and on the
    transitions that start there.

    Args:
        t, acc, gyr: the recording's time (s) and (N, 3) outputs.
        iv: (P, 2) static pose intervals (sample ranges).
        data: the same poses prepared (:func:`jaxcal.multipos.prepare`).
        aspec, gspec, sigma_acc: as in :func:`online_fit`.
        n_folds: interleaved pose folds; ``None`` leaves one pose out at a time.
        pad: samples of each pose streamed with its motion.
    """
    P = len(iv)
    F = P if n_folds is None else n_folds
    pf = mp.fold_ids(P, F)
    ok = np.asarray(data.seg_ok)
    dt = float(np.median(np.diff(t)))
    cals, n_seq = [], []
    for k in range(F):
        train = [j for j in range(P - 1) if pf[j] != k and pf[j + 1] != k and ok[j]]
        segs = [(max(iv[j, 0], iv[j, 1] - pad), min(iv[j + 1, 1], iv[j + 1, 0] + pad)) for j in train]
        n_seq.append(len(segs))
        cals.append(online_fit(acc, gyr, segs, dt, aspec, gspec, sigma_acc))
    ea, eg = fold_errors(cals, data, pf)
    return summarise(ea, eg, f"held out ({'leave-one-pose-out' if n_folds is None else f'{F} interleaved pose folds'}; "
                     f"{min(n_seq)}-{max(n_seq)} sequences per fold)")


def fair_data(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, plan: mp.TimeSplit) -> tuple:
    """Fitted and scored static sections of one time fold (with every span), the turns as closed
    rotations, and the turns about the vertical with their axis rests (the calibration halves).

    Returns ``(fit_data, score_data, known, turns)`` for :func:`fair_multipos` / :func:`fixed_errors`.

    Args:
        t: (N,) times (s).
        acc, gyr: (N, 3) outputs of the whole session.
        plan: the fold (:func:`jaxcal.multipos.time_split`).
    """
    fit_d = mp.prepare(t, acc, gyr, plan.fit_iv, spans=plan.spans)
    score_d = mp.prepare(t, acc, gyr, plan.score_iv, spans=plan.spans)
    known = mp.prepare_known(t, acc, gyr, plan.turns, np.zeros((len(plan.turns), 3)))
    turns = mp.prepare_turns(t, acc, gyr, plan.turns, plan.turn_rests)
    return fit_d, score_d, known, turns


@partial(jax.jit, static_argnames=("config", "mode", "batch"))
def _gyro_fold_errors(d, sd, kn, tv, aw, gw, kw, config: mp.MultiposConfig, mode: str, batch: int) -> tuple:
    """:func:`fair_multipos`'s gyro folds, ``batch`` at a time in one ``vmap`` (``lax.map``; 1: one
    after another, the CPU default of :func:`jaxcal.multipos.fold_batch`), scored: ``(acc_err (F, P),
    gyr_err (F, J), turn_err (F, K))`` on the scored sections ``sd``. The data are arguments, not
    closure constants: one compilation per shape, config, mode and batch, not one per call (a
    closure compiled the imucal session's folds in about 10 s each time)."""

    def one(g, k):
        f = mp.fit_prepared(d, config, acc_w=aw, gyr_w=g, known=kn if mode == "closed" else None, known_w=k,
                            turns=tv if mode == "vertical" else None, turns_w=k)
        return (mp.acc_norm_errors(f.acc, sd.pose_acc), mp.gyro_angle_errors(f.gyr, f.gsens, f.acc, sd),
                mp.known_rotation_errors(f.gyr, f.gsens, f.acc, kn))

    return jax.lax.map(lambda x: one(*x), (gw, kw), batch_size=batch if batch > 1 else None)


@float64
def fair_multipos(fit_d, score_d, known, turns, plan: mp.TimeSplit, config: mp.MultiposConfig, mode: str,
                  motions: bool = True) -> tuple:
    """Held-out errors ``(acc_err, gyr_err, turn_err)`` of jaxcal multipos on one time fold.

    Accelerometer on the faces' scored halves, the carried-gravity angle of each left-out motion
    (NaN for spans across a turn), the closure error of each left-out turn. The accelerometer is
    fitted on the faces only (the rests repeat three of their directions). All gyro folds are one
    compiled fold loop.

    Args:
        fit_d, score_d, known, turns: from :func:`fair_data`.
        plan: the time fold (:func:`jaxcal.multipos.time_split`).
        config: multipos configuration (static).
        mode: ``"closed"`` (turns as known closed rotations), ``"vertical"`` (turns about the
            measured vertical; :class:`~jaxcal.multipos.VerticalTurns`) or ``"none"``.
        motions: ``False`` fits the gyro on the turns alone (imucal's information, no labels); every
            motion is then held out, and the turns' closure is in-sample (two turns cannot determine
            the 9 gyro parameters, so none is left out).
    """
    gw, kw, scored = mp.gyro_folds(plan.across_turn, known.R.shape[0])
    M = int((scored >= 0).sum())
    if not motions:  # one fit on every turn and no motion holds out every motion at once
        gw, kw = np.zeros((1, gw.shape[1])), np.ones((1, kw.shape[1]))
    d, sd, kn, tv = (jax.tree_util.tree_map(jnp.asarray, x) for x in (fit_d, score_d, known, turns))
    aw = jnp.asarray(plan.is_face.astype(float))
    errs = _gyro_fold_errors(d, sd, kn, tv, aw, jnp.asarray(gw), jnp.asarray(kw), config, mode, mp.fold_batch(gw.shape[0]))
    ea, eg, ek = (np.asarray(x) for x in errs)
    eg_out = np.full(len(plan.spans), np.nan)
    if not motions:
        eg_out[scored[:M]] = eg[0, scored[:M]]
        return ea[0][plan.is_face], eg_out, ek[0]
    eg_out[scored[:M]] = eg[np.arange(M), scored[:M]]
    K = known.R.shape[0]
    return ea[0][plan.is_face], eg_out, ek[M + np.arange(K), np.arange(K)]


@float64
def fixed_errors(a_cal: LinearCal, g_cal: LinearCal, score_d, known, plan: mp.TimeSplit,
                 gsens: np.ndarray | None = None) -> tuple:
    """Errors ``(acc_err, gyr_err, turn_err)`` of a given calibration on a fold's scored sections:
    faces (acc), motions between poses (gyro; NaN for spans across a turn) and the turns' closure.

    Args:
        a_cal, g_cal: the calibration pair (applied form).
        score_d: the fold's scored sections (second item of :func:`fair_data`).
        known: the turns as closed rotations (third item of :func:`fair_data`).
        plan: the fold (:func:`jaxcal.multipos.time_split`).
        gsens: the gyroscope's g-sensitivity ``G`` ((rad/s)/g), or ``None`` (zero).
    """
    ea, eg = score_cal(a_cal, g_cal, score_d, gsens)
    G = jnp.zeros((3, 3)) if gsens is None else jnp.asarray(gsens)
    ek = np.asarray(mp.known_rotation_errors(jax.tree_util.tree_map(jnp.asarray, g_cal), G,
                                             jax.tree_util.tree_map(jnp.asarray, a_cal), jax.tree_util.tree_map(jnp.asarray, known)))
    return ea[plan.is_face], np.where(plan.across_turn, np.nan, eg), ek


@float64
def fair_field(acc: np.ndarray, gyr: np.ndarray, fit_d, score_d, known, plan: mp.TimeSplit, dt: float,
               hp: onl.OnlineHP, kind: str = "diag", gsens_auto: bool = True) -> tuple:
    """Held-out errors ``(acc_err, gyr_err, turn_err)`` of the field path (``online`` between rests,
    :mod:`jaxcal.field`) on one time fold, scored as :func:`fixed_errors` scores a given calibration.

    The fitted halves are the rests: the accelerometer from the faces' halves (the turns' rests repeat
    their directions, as in :func:`fair_multipos`), the gyroscope from the gravity carried over every
    motion between two halves that is not a turn; with ``gsens_auto`` the halves choose the gyro's
    g-sensitivity (:func:`jaxcal.field.choose_gsens`); the filter then streams those motions with the
    accelerometer residuals at the halves, its noise measured there. The scored halves lie inside the
    streamed spans (a hold is still: their gyro integrates to nothing); their accelerometer is never
    a residual.

    Args:
        acc, gyr: (N, 3) outputs of the whole session.
        fit_d, score_d, known: from :func:`fair_data`.
        plan: the time fold (:func:`jaxcal.multipos.time_split`).
        dt: sample period (s).
        hp: the filter's :class:`~jaxcal.online.OnlineHP` (e.g. ``methods.online.field_hp``); its
            ``sigma_acc`` is replaced by the noise measured at the fitted halves.
        kind: the filter's layout (``online``'s default between rests: ``"diag"``).
        gsens_auto: let the fitted halves choose the gyro's g-sensitivity (``online``'s default).
    """
    use = (~np.asarray(plan.across_turn, bool)).astype(np.float64)
    aw = np.asarray(plan.is_face, np.float64)
    init, _ = field.rest_init_chosen(fit_d, aw, use, mp.MultiposConfig(), gsens_auto, choose_w=np.ones(len(aw)))  # every half chooses
    hp = hp._replace(sigma_acc=field.rest_noise(acc, plan.fit_iv, init.acc))
    cal = field.fit_field(field.field_batch(acc, gyr, plan.fit_iv, use > 0), init, dt, hp, kind, "rests",
                          sigma_dir=field.carried_sigma(init, fit_d, use))
    return fixed_errors(cal.acc, cal.gyr, score_d, known, plan, cal.G)
