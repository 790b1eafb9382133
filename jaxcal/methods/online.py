"""Method ``online``: jaxcal's streaming self-calibration (an affine model per sensor, estimated
by an information filter over rotation sequences, :func:`jaxcal.online.fit_online_recording`);
no labels, datasheet values optional. Stored and applied as the linear methods are."""

from __future__ import annotations

import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal import multipos as mp
from jaxcal.constants import SENSORS
from jaxcal.methods.base import (
    Fitted,
    Log,
    Method,
    ModelError,
    affine_state,
    apply_linear_state,
    check_linear_state,
    linear_state,
    recording_dt,
    recording_spec,
    require_both,
    sequences_of,
    units,
)
from jaxcal.multipos.acc import ellipsoid_init
from jaxcal.online import OnlineHP, fit_online_recording
from jaxcal.recording import Recording, sequence_slices, take_rows
from jaxcal.sensor import Diag, LinearCal
from jaxcal.sequences import sequence_bounds
from jaxcal.static import detect_static

__all__ = ["METHOD", "OnlineOptions", "RestSequences", "fit", "quality", "rest_sequences", "seq_split_quality"]


class OnlineOptions(NamedTuple):
    """Options of ``online`` (static: plain Python values). The filter's other hyperparameters are
    :class:`jaxcal.online.OnlineHP`'s defaults (the prior widened where a datasheet value is
    estimated from the data).

    Args:
        kind: ``"affine"`` (scale, cross-axis, bias) or ``"diag"`` (scale and bias).
        sigma_acc: accelerometer noise std (g) of the filter; ``None``: measured at the rests of a
            rest-segmented recording, else :class:`~jaxcal.online.OnlineHP`'s.
        n_iter: Gauss-Newton iterations per sequence; ``None``: 4, or 8 on a rest-segmented recording
            (4 diverged on one real fold, results/real.md).
        forgetting: information forgetting factor per sequence, in ``(0, 1]``.
        prior_scale: prior std of the relative scale around the datasheet value.
        prior_cross: prior std of the cross-axis terms.
        init_duration: seconds of initial rest (rest detection, recordings without ``seq``);
            ``None``: the first 10 % of the recording, at most 30 s.
        min_rest: shortest rest kept, seconds.
        rest_window: moving-variance window of the rest detector, seconds.
        rest_pad: seconds of each rest streamed with the motions before and after it.
        folds: interleaved rest (pose) folds of the held-out score (the initial rest is in none).
    """

    kind: str = "affine"
    sigma_acc: float | None = None
    n_iter: int | None = None
    forgetting: float = 1.0
    prior_scale: float = 0.03
    prior_cross: float = 0.02
    init_duration: float | None = None
    min_rest: float = 1.0
    rest_window: float = 1.0
    rest_pad: float = 1.0
    folds: int = 10


class RestSequences(NamedTuple):
    """A recording without ``seq`` cut into sequences between rests.

    Args:
        intervals: (P, 2) rest sample ranges ``[start, stop)``.
        segments: (J, 2) sample range of each sequence ``j`` (the end of rest ``j``, the motion, the
            start of rest ``j + 1``); only the usable ones (``usable``).
        usable: (P - 1,) bool, the motion between rests ``j`` and ``j + 1`` is a sequence (its gyro
            does not saturate).
        data: the rests prepared as poses (:func:`jaxcal.multipos.prepare`), for scoring.
        sigma_acc: accelerometer noise std at the rests (recorded unit).
    """

    intervals: np.ndarray
    segments: np.ndarray
    usable: np.ndarray
    data: Any
    sigma_acc: float


def rest_sequences(rec: Recording, options: OnlineOptions) -> RestSequences:
    """Cut a recording without ``seq`` into sequences between rests: detect the rests as
    ``multipos`` does (:func:`jaxcal.multipos.detect_and_fit`'s threshold scan; with fewer than 9
    rests, :func:`jaxcal.static.detect_static` with ``k = 3``, gyro gate on), then each motion
    between two consecutive rests, with ``rest_pad`` seconds of each rest, is one sequence.

    Args:
        rec: a recording with ``acc`` and ``gyr``.
        options: :class:`OnlineOptions` (the rest options).
    """
    t = np.asarray(rec.t, np.float64)
    det = mp.DetectOptions.for_recording(rec)._replace(
        init_duration=options.init_duration, min_duration=float(options.min_rest), window=float(options.rest_window))
    try:
        _, iv, _ = mp.detect_and_fit(t, rec.acc, rec.gyr, detect=det, check=False)
    except ValueError:
        init = options.init_duration if options.init_duration is not None else min(30.0, 0.1 * (t[-1] - t[0]))
        try:
            iv = detect_static(t, rec.acc, k=3.0, init_duration=init, window=det.window, min_duration=det.min_duration,
                               gyr=rec.gyr).intervals
        except ValueError as e:
            raise ModelError(f"method 'online' needs 'seq' ids, or rests between the motions; none given and rests "
                             f"cannot be detected ({e})") from None
    iv = np.asarray(iv, int)
    if len(iv) < 3:
        raise ModelError(f"method 'online' needs 'seq' ids, or rests between the motions; none given and only {len(iv)} "
                         "rests found (record rests of 1 s or more, --min-rest, between the motions)")
    data = mp.prepare(t, rec.acc, rec.gyr, iv, gyr_limit=det.gyr_limit)
    usable = np.asarray(data.seg_ok, bool)
    pad = max(1, int(round(options.rest_pad / float(np.median(np.diff(t))))))
    segs = np.array([(max(iv[j, 0], iv[j, 1] - pad), min(iv[j + 1, 1], iv[j + 1, 0] + pad))
                     for j in range(len(iv) - 1)], int).reshape(-1, 2)
    acc = np.asarray(rec.acc, np.float64)
    sigma = float(np.mean([acc[a:b].std(0).mean() for a, b in iv]))
    return RestSequences(iv, segs, usable, data, sigma)


def _hp(options: OnlineOptions, sigma_acc: float | None, segmented: bool) -> OnlineHP:
    hp = OnlineHP(prior_scale=float(options.prior_scale), prior_cross=float(options.prior_cross),
                  forgetting=float(options.forgetting))
    n_iter = options.n_iter if options.n_iter is not None else (8 if segmented else hp.n_iter)
    hp = hp._replace(n_iter=int(n_iter))
    sigma = options.sigma_acc if options.sigma_acc is not None else sigma_acc
    return hp if sigma is None else hp._replace(sigma_acc=float(sigma))


def _check_options(options: OnlineOptions) -> None:
    if options.kind not in ("affine", "diag"):
        raise ModelError(f"online: --kind must be affine or diag, got {options.kind!r}")
    if not 0.0 < float(options.forgetting) <= 1.0:
        raise ModelError(f"online: --forgetting must lie in (0, 1], got {options.forgetting}")
    if int(options.folds) < 2:
        raise ModelError(f"online: --folds must be at least 2, got {options.folds}")


def _fit_segments(rec: Recording, segs: np.ndarray, dt: float, acc_spec: Diag | None, gyr_spec: Diag | None,
                  hp: OnlineHP, kind: str) -> tuple[LinearCal, LinearCal]:
    """The filter streamed over the sample ranges ``segs`` (one sequence each, in order)."""
    idx = np.concatenate([np.arange(a, b) for a, b in segs])
    seq = np.concatenate([np.full(b - a, k) for k, (a, b) in enumerate(segs)])
    acc, gyr = np.asarray(rec.acc, np.float64)[idx], np.asarray(rec.gyr, np.float64)[idx]
    return fit_online_recording(acc, gyr, seq, dt, acc_spec, gyr_spec, hp, kind)


def fit(rec: Recording, options: OnlineOptions, log: Log) -> Fitted:
    """Self-calibrate both sensors from the recording's rotation sequences.

    Without ``seq`` ids the recording is cut between its rests (:func:`rest_sequences`) and the
    filter's accelerometer noise is the one measured there.

    Args:
        rec: a recording with ``acc``, ``gyr`` and ``seq`` ids or rests between its motions
            (datasheet values optional).
        options: :class:`OnlineOptions`.
        log: progress sink.
    """
    require_both(rec, "online")
    _check_options(options)
    acc_spec, gyr_spec = recording_spec(rec, "acc"), recording_spec(rec, "gyr")
    rests = None
    if rec.seq is None:
        rests = rest_sequences(rec, options)
        segs = rests.segments[rests.usable]
        if len(segs) < 2:
            raise ModelError(f"online: no 'seq' ids, and only {len(segs)} usable motions between {len(rests.intervals)} "
                             "rests (saturated ones are left out); record more rest-motion-rest sequences")
        n_seq = len(segs)
        log(f"online: no 'seq' ids: segmented between {len(rests.intervals)} rests into {n_seq} sequences "
            f"({int((~rests.usable).sum())} saturated motions left out)")
    else:
        seq = sequences_of(rec, "online")
        n_seq = len(sequence_slices(rec))
    dt = recording_dt(rec)
    spec_from = {s: ("metadata" if sp is not None else "data") for s, sp in (("acc", acc_spec), ("gyr", gyr_spec))}
    if rests is not None and acc_spec is None:
        acc_spec, spec_from["acc"] = _rest_acc_spec(rests), "rests (ellipsoid through the rest means)"
    hp = _hp(options, None if rests is None else rests.sigma_acc / _acc_scale(acc_spec, rec), rests is not None)
    log(f"fitting online on {n_seq} sequences ({rec.n} samples, dt {dt:g} s) ...")
    t0 = time.perf_counter()
    try:
        if rests is None:
            cals = fit_online_recording(np.asarray(rec.acc, np.float64), np.asarray(rec.gyr, np.float64), seq, dt,
                                        acc_spec, gyr_spec, hp, options.kind)
        else:
            cals = _fit_segments(rec, segs, dt, acc_spec, gyr_spec, hp, options.kind)
    except ValueError as e:
        raise ModelError(f"online: {e}") from None
    elapsed = time.perf_counter() - t0
    state = {s: linear_state(cal) for s, cal in zip(SENSORS, cals)}
    for s, m in state.items():
        if not (np.all(np.isfinite(m.S)) and np.all(np.isfinite(m.b))):
            raise ModelError(f"online: the {s} estimate is not finite (does the recording hold rotation sequences?)")
    log(f"fitting online ... done in {elapsed:.1f} s")
    meta = {
        "units": units(rec, SENSORS),
        "n_sequences": n_seq,
        "sequences_from": "seq" if rests is None else "rests",
        "kind": options.kind,
        "sigma_acc": float(hp.sigma_acc),
        "n_iter": int(hp.n_iter),
        "dt": dt,
        "fit_seconds": elapsed,
        "spec_from": spec_from,
    }
    return Fitted(SENSORS, state, meta)


def _rest_acc_spec(rests: RestSequences) -> Diag:
    """A datasheet-like accelerometer model from the rests: the axis-aligned ellipsoid through the
    rest means (:func:`jaxcal.multipos.acc.ellipsoid_init`), for a recording without datasheet values
    (raw offsets such as unsigned 16-bit ones defeat the filter's own guess, bias 0)."""
    with jax.enable_x64(True):
        pa = jnp.asarray(rests.data.pose_acc, jnp.float64)
        c, r = ellipsoid_init(pa, jnp.ones(pa.shape[0]))
        return Diag(np.asarray(r), np.asarray(c))


def _acc_scale(spec: Diag | None, rec: Recording) -> float:
    """Recorded accelerometer units per g: the spec's mean scale, else the median norm."""
    if spec is not None:
        return float(np.mean(np.asarray(spec.s, np.float64)))
    return float(np.median(np.linalg.norm(np.asarray(rec.acc, np.float64), axis=1)))


def _score(cals: tuple[Any, Any], data: Any) -> tuple[np.ndarray, np.ndarray]:
    """Per-rest ``| |f| - 1 g |`` (g) and per-motion carried-gravity angle (rad, NaN where unusable)."""
    with jax.enable_x64(True):
        d = jax.tree_util.tree_map(jnp.asarray, data)
        a, g = (jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float64), c) for c in cals)
        ea = np.asarray(mp.acc_norm_errors(a, d.pose_acc))
        eg = np.asarray(mp.gyro_angle_errors(g, jnp.zeros((3, 3)), a, d))
    return ea, np.where(np.asarray(data.seg_ok), eg, np.nan)


def _row(ea: np.ndarray, eg: np.ndarray, how: str) -> dict[str, Any]:
    eg = eg[np.isfinite(eg)]
    return {"acc_rms_mg": float(1e3 * np.sqrt(np.mean(ea**2))),
            "gyr_median_deg": float(np.degrees(np.median(eg))) if eg.size else None, "how": how}


HELD_OUT_SHARE = 0.2  # online on seq ids: the last fifth of the sequences is the held-out time split


def _ends_data(rec: Recording, bounds: list[tuple[int, int]]) -> Any:
    """Each sequence's first and last samples as two poses with the sequence between them
    (:func:`jaxcal.multipos.prepare`); transitions ``2k`` are the sequences, the others join two
    sequences and are not scored."""
    iv = np.array([p for a, b in bounds for p in ((a, a + 1), (b - 1, b))], int)
    return mp.prepare(np.asarray(rec.t, np.float64), rec.acc, rec.gyr, iv,
                      gyr_limit=mp.DetectOptions.for_recording(rec).gyr_limit)


def _time_split_rows(rec: Recording, held_out: bool, score: Any, fit_score: Any, verb: str) -> tuple[dict, dict | None]:
    """In-sample and time-split rows on a recording with ``seq`` ids: ``score(bounds)`` scores the
    sequences with sample ranges ``bounds``; ``fit_score(train, test)`` fits on the ``train``
    sequences (the first 80 %) and scores the ``test`` ones (the last 20 %)."""
    starts, ends = sequence_bounds(rec.seq)
    bounds = [(int(a), int(b)) for a, b in zip(starts, ends) if b - a >= 2]
    M = len(bounds)
    ea, eg = score(bounds)
    ins = _row(ea, eg[::2], f"first and last samples of all {M} sequences")
    if not held_out:
        return ins, None
    k = max(1, int(round(HELD_OUT_SHARE * M)))
    if M - k < 2:
        return ins, {"error": f"{M} sequences: too few for a held-out time split"}
    try:
        ea, eg = fit_score(bounds[: M - k], bounds[M - k:])
    except (ValueError, ModelError) as e:
        return ins, {"error": f"time split: {e}"}
    return ins, _row(ea, eg[::2], f"time split: {verb} on the first {M - k} sequences, scored on the last {k} "
                     "(their first and last samples)")


def _seq_quality(rec: Recording, options: OnlineOptions, model: Any, cals: tuple[Any, Any],
                 held_out: bool) -> tuple[dict, dict | None]:
    """:func:`quality` on a recording with ``seq`` ids: each sequence scored by its first and last
    samples (``| |f| - 1 g |`` there, and the gravity carried from the first to the last); held out:
    a time split, fitted on the first 80 % of the sequences and scored on the last 20 %."""

    def fit_score(train: list, test: list) -> tuple[np.ndarray, np.ndarray]:
        acc_spec, gyr_spec = recording_spec(rec, "acc"), recording_spec(rec, "gyr")
        c = _fit_segments(rec, np.asarray(train), recording_dt(rec), acc_spec, gyr_spec, _hp(options, None, False),
                          options.kind)
        return _score(c, _ends_data(rec, test))

    return _time_split_rows(rec, held_out, lambda bounds: _score(cals, _ends_data(rec, bounds)), fit_score, "fitted")


def _applied_score(model: Any, rec: Recording, bounds: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_score` of any model from its applied output (g, rad/s) at the sequences' ends;
    a sequence whose raw gyro saturates is not scored."""
    out = model.apply(rec)
    if "acc_cal" not in out or "gyr_cal" not in out:
        raise ModelError("the sequences' score needs a model of both sensors")
    iv = np.array([p for a, b in bounds for p in ((a, a + 1), (b - 1, b))], int)
    d = mp.prepare(np.asarray(rec.t, np.float64), np.asarray(out["acc_cal"], np.float64),
                   np.asarray(out["gyr_cal"], np.float64), iv)
    d = d._replace(seg_ok=np.asarray(d.seg_ok) & np.asarray(_ends_data(rec, bounds).seg_ok))
    ident = LinearCal(np.eye(3), np.zeros(3))
    return _score((ident, ident), d)


def seq_split_quality(method: str, rec: Recording, options: Any, model: Any, *, held_out: bool = True,
                      log: Log | None = None) -> tuple[dict, dict | None]:
    """In-sample and held-out quality of any method's model on a recording with ``seq`` ids, from
    its applied output (as :func:`quality` scores ``online``): each sequence by its first and last
    samples (``| |f| - 1 g |`` there, and the gravity carried from the first to the last). Held
    out: a time split, ``method`` refitted on the first 80 % of the sequences and scored on the
    last 20 %.

    Args:
        method: the registered method's name (refitted for the held-out row).
        rec: the recording the model was fitted on (with ``seq``).
        options: the fit's options.
        model: the fitted :class:`~jaxcal.methods.CalibrationModel`.
        held_out: also compute the held-out row.
        log: progress sink, or ``None``.

    Returns:
        ``(in_sample, held_out)`` rows (``held_out`` ``None`` when not asked for).
    """
    from jaxcal import methods  # the registry imports this module

    if rec.seq is None:
        raise ModelError(f"{method}: the sequences' score needs seq ids")

    def fit_score(train: list, test: list) -> tuple[np.ndarray, np.ndarray]:
        cut, rows = test[0][0], np.arange(rec.n)
        if log is not None:
            log(f"held out: refitting {method} on the first {len(train)} sequences, scoring the last {len(test)} ...")
        sub = methods.fit(method, take_rows(rec, rows < cut), options)
        return _applied_score(sub, take_rows(rec, rows >= cut), [(a - cut, b - cut) for a, b in test])

    return _time_split_rows(rec, held_out, lambda bounds: _applied_score(model, rec, bounds), fit_score, "refitted")


def quality(rec: Recording, options: OnlineOptions, model: Any, *, held_out: bool = True,
            log: Log | None = None) -> tuple[dict, dict | None]:
    """In-sample and held-out quality of an ``online`` model on the rests of its recording:
    ``| |f| - 1 g |`` RMS over the rests (mg) and the median carried-gravity angle over the
    motions between them (deg). Held out: ``folds`` interleaved rest folds; fold ``k`` streams the
    sequences whose two rests are both outside it and is scored on its rests and the motions
    starting there (as ``results/real.md``'s online rows, except that the initial rest is in no
    fold: every fold's stream starts from it, and without it the filter can diverge, e.g. 253 mg
    on one Xsens fold against 2-3 mg on the others).

    Args:
        rec: the recording the model was fitted on. With ``seq`` ids each sequence is scored by its
            first and last samples (rests in the simulator's Dataset 2) and the held-out figure is a
            time split (fitted on the first 80 % of the sequences, scored on the last 20 %).
        options: :class:`OnlineOptions` of the fit.
        model: the fitted :class:`~jaxcal.methods.CalibrationModel`.
        held_out: also compute the held-out row.
        log: progress sink (one line per fold), or ``None``.

    Returns:
        ``(in_sample, held_out)`` rows (``held_out`` ``None`` when not asked for).
    """
    with jax.enable_x64(True):
        cals = tuple(LinearCal.from_forward(affine_state(model.state[s])) for s in SENSORS)
        cals = tuple(LinearCal(np.asarray(c.A), np.asarray(c.b)) for c in cals)
    if rec.seq is not None:
        return _seq_quality(rec, options, model, cals, held_out)
    try:
        rests = rest_sequences(rec, options)
    except ModelError as e:
        return {"error": str(e)}, ({"error": str(e)} if held_out else None)
    ins = _row(*_score(cals, rests.data), f"all {len(rests.intervals)} rests")
    if not held_out:
        return ins, None
    P = len(rests.intervals)
    F = min(int(options.folds), P - 1)
    pf = np.concatenate([[-1], mp.fold_ids(P - 1, F)])  # the initial rest starts every fold's stream
    dt = recording_dt(rec)
    acc_spec, gyr_spec = recording_spec(rec, "acc"), recording_spec(rec, "gyr")
    if acc_spec is None:
        acc_spec = _rest_acc_spec(rests)
    hp = _hp(options, float(model.meta.get("sigma_acc", rests.sigma_acc / _acc_scale(acc_spec, rec))), True)
    ea, eg = np.full(P, np.nan), np.full(P - 1, np.nan)
    n_seq = []
    for k in range(F):
        train = [j for j in range(P - 1) if pf[j] != k and pf[j + 1] != k and rests.usable[j]]
        if len(train) < 2:
            return ins, {"error": f"fold {k + 1} of {F} keeps {len(train)} sequences; too few rests for held-out folds"}
        n_seq.append(len(train))
        if log:
            log(f"online held out: fold {k + 1}/{F}, {len(train)} sequences ...")
        try:
            c = _fit_segments(rec, rests.segments[train], dt, acc_spec, gyr_spec, hp, options.kind)
        except ValueError as e:
            return ins, {"error": f"fold {k + 1}: {e}"}
        a, g = _score(c, rests.data)
        ea[pf == k] = a[pf == k]
        sel = (pf[:-1] == k) & rests.usable
        eg[sel] = g[sel]
    return ins, _row(ea[1:], eg, f"{F} interleaved rest folds (the initial rest in none), {min(n_seq)}-{max(n_seq)} "
                     "sequences per fold")


METHOD = Method(
    "online", fit, apply_linear_state, OnlineOptions,
    "jaxcal's streaming self-calibration (affine per sensor, information filter on rotation "
    "sequences); seq ids, or rests between the motions; no labels",
    check_linear_state,
)
