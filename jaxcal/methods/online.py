"""Method ``online``: jaxcal's streaming self-calibration (an affine model per sensor, estimated
by an information filter over rotation sequences, :func:`jaxcal.online.fit_online_recording`);
no labels, datasheet values optional. Stored and applied as the linear methods are."""

from __future__ import annotations

import time
from typing import Any, NamedTuple

import numpy as np

from jaxcal import field, flags
from jaxcal import multipos as mp
from jaxcal.constants import SENSORS
from jaxcal.eval import seqsplit
from jaxcal.eval.heldout import fold_errors, stream_segments
from jaxcal.eval.scores import QualityRow, quality_row, score_cal
from jaxcal.flags import Flag
from jaxcal.methods.base import (
    GSENS_KEY,
    SHARED_FLAGS,
    Fitted,
    Log,
    Method,
    ModelError,
    apply_linear_state,
    check_linear_state,
    datasheet_cals,
    datasheet_prior,
    gsens_of,
    linear_cal_of_state,
    linear_state,
    recording_dt,
    recording_spec,
    require_both,
    sequences_of,
    units,
)
from jaxcal.online import HOLD, OnlineHP, fit_online_recording
from jaxcal.recording import PER_SAMPLE_FIELDS, Recording, sequence_slices
from jaxcal.sensor import Diag, LinearCal

__all__ = ["METHOD", "FieldSetup", "OnlineOptions", "RestSequences", "field_hp", "field_setup", "fit", "quality", "rest_seq_recording",
           "rest_sequences", "rest_spec"]


class OnlineOptions(NamedTuple):
    """Options of ``online`` (static: plain Python values). The filter's other hyperparameters are
    :class:`jaxcal.online.OnlineHP`'s defaults (the prior widened where a datasheet value is
    estimated from the data).

    Without ``seq`` ids the recording is calibrated in the field (:mod:`jaxcal.field`): initialised
    from its rests, then the filter streamed over its motions with the accelerometer residuals at
    the rests (``residuals``).

    Args:
        kind: ``"affine"`` (scale, cross-axis, bias) or ``"diag"`` (scale and bias); ``None``:
            affine with ``seq`` ids, diag between rests (corrections to the data's initial
            calibration, which holds the cross-axis terms; ``results/field.md``).
        sigma_acc: accelerometer noise std (g) of the filter; ``None``: measured at the rests of a
            rest-segmented recording, else :class:`~jaxcal.online.OnlineHP`'s.
        n_iter: Gauss-Newton iterations per sequence; ``None``: 4 (between rests the filter starts
            at the rests' calibration: 3, 4 and 8 give the same held-out figures to 0.01 mg on the
            three real recordings of ``results/field.md``).
        forgetting: information forgetting factor per sequence, in ``(0, 1]``.
        prior_scale: prior std of the relative scale around the datasheet value.
        prior_cross: prior std of the cross-axis terms.
        init_duration: seconds of initial rest (rest detection, recordings without ``seq``);
            ``None``: the first 10 % of the recording, at most 30 s.
        min_rest: shortest rest kept, seconds.
        rest_window: moving-variance window of the rest detector, seconds.
        rest_pad: seconds of each rest streamed with the motions before and after it.
        folds: interleaved rest (pose) folds of the held-out score (the initial rest is in none).
        residuals: between rests, where the accelerometer residuals sit: ``"rests"`` (the rests
            only; the motions' samples carry the gravity through the gyroscope but hold physics
            the model lacks: translational acceleration, a lever arm, a time offset) or ``"all"``
            (every sample, the simulation's recipe).
        g_sensitivity: between rests, also take the gyroscope's g-sensitivity ``G`` from the rests
            (as ``multipos --g-sensitivity``) and out of the rates the filter integrates.
        g_sensitivity_auto: between rests, where ``g_sensitivity`` is off, let the rests choose it:
            on where their gyroscope means are predicted better with it, left one rest out at a
            time (:func:`jaxcal.field.choose_gsens`; each held-out fold chooses from its own rests).
        acc_from: between rests, where the accelerometer comes from: ``"rests"`` (its fit to the
            rests' ``|f| = 1 g``, held there while the filter corrects the gyroscope; the rests
            determine the accelerometer, and the filter's carried directions hold the gyroscope's
            errors) or ``"filter"`` (the filter corrects both). ``results/field.md`` compares them.
        datasheet_prior: between rests, fit the initial calibration with the recording's datasheet
            scales as the prior centre (``prior_scale``, ``prior_cross``; as ``multipos
            --datasheet-prior``); the datasheet is still never the starting point.
    """

    kind: str | None = None
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
    residuals: str = "rests"
    g_sensitivity: bool = False
    g_sensitivity_auto: bool = True
    acc_from: str = "rests"
    datasheet_prior: bool = False

    FLAGS = {
        "kind": Flag("--kind", flags.choice("affine", "diag"), None, "filter model: affine (scale, cross-axis, bias) "
                     "or diag (scale, bias)", "affine|diag", show_default="affine with seq ids, diag between rests"),
        "sigma_acc": Flag("--sigma-acc", flags.real(0.0, 1.0), None, "accelerometer noise std of the filter, in g",
                          "G", show_default="measured at the rests; 1.8e-5 with seq ids"),
        "n_iter": Flag("--n-iter", flags.count(1, 100), None, "Gauss-Newton iterations per sequence", "N",
                       show_default="4"),
        "forgetting": Flag("--forgetting", flags.real(0.0, 1.0), None,
                           "information forgetting factor per sequence, in (0, 1]", "L"),
        "rest_pad": Flag("--rest-pad", flags.real(0.0, 1e6), None, "seconds of each rest streamed with the motions "
                         "around it (recordings without seq ids)", "SEC"),
        "folds": Flag("--folds", flags.count(2, 1000), None, "interleaved rest folds of the held-out figure", "K"),
        "residuals": Flag("--residuals", flags.choice("rests", "all"), None, "between rests: the accelerometer "
                          "residuals at the rests only, or at every sample (the simulation's recipe; motions carry "
                          "translational acceleration)", "rests|all"),
        "g_sensitivity_auto": Flag("--g-sensitivity-auto", flags.choice("on", "off"), lambda v: v == "on",
                                   "between rests, without --g-sensitivity: the gyroscope's g-sensitivity where "
                                   "the rests' gyro means, each left out in turn, are predicted better with it "
                                   "(one-standard-error rule), or never", "on|off", show_default="on"),
        "acc_from": Flag("--acc-from", flags.choice("rests", "filter"), None, "between rests: the accelerometer as "
                         "fitted to the rests (the filter corrects the gyroscope), or corrected by the filter too",
                         "rests|filter"),
        **{k: SHARED_FLAGS[k] for k in ("prior_scale", "prior_cross", "init_duration", "min_rest", "rest_window",
                                        "g_sensitivity", "datasheet_prior")},
    }
    EFFECTS = {("gyr", "g_sensitivity"): "g_sensitivity"}  # what a diagnose report can switch on (methods.from_report)


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
        iv = mp.detect_rests(rec, det)
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


def _hp(options: OnlineOptions, sigma_acc: float | None) -> OnlineHP:
    hp = OnlineHP(prior_scale=float(options.prior_scale), prior_cross=float(options.prior_cross),
                  forgetting=float(options.forgetting))
    n_iter = options.n_iter if options.n_iter is not None else hp.n_iter
    hp = hp._replace(n_iter=int(n_iter))
    sigma = options.sigma_acc if options.sigma_acc is not None else sigma_acc
    return hp if sigma is None else hp._replace(sigma_acc=float(sigma))


def field_hp(options: OnlineOptions, sigma_acc: float | None) -> OnlineHP:
    """The filter's hyperparameters between rests (the field path): the options' values, the
    accelerometer noise ``sigma_acc`` (g; the option's if given), and, with ``acc_from="rests"``
    (the default), the accelerometer held at its fit to the rests (:data:`~jaxcal.online.HOLD`).

    Args:
        options: :class:`OnlineOptions`.
        sigma_acc: the accelerometer's noise at the rests (g), e.g. :func:`jaxcal.field.rest_noise`.
    """
    hp = _hp(options, sigma_acc)
    return hp._replace(acc_prior_factor=HOLD) if options.acc_from == "rests" else hp


def _kind(options: OnlineOptions, segmented: bool) -> str:
    """The filter's layout: the option, else ``diag`` between rests and ``affine`` with ``seq`` ids."""
    return options.kind if options.kind is not None else ("diag" if segmented else "affine")


def _check_options(options: OnlineOptions) -> None:
    if options.acc_from not in ("rests", "filter"):
        raise ModelError(f"online: --acc-from must be rests or filter, got {options.acc_from!r}")
    if options.residuals not in field.RESIDUALS:
        raise ModelError(f"online: --residuals must be one of {', '.join(field.RESIDUALS)}, got {options.residuals!r}")
    if options.kind is not None and options.kind not in ("affine", "diag"):
        raise ModelError(f"online: --kind must be affine or diag, got {options.kind!r}")
    if not 0.0 < float(options.forgetting) <= 1.0:
        raise ModelError(f"online: --forgetting must lie in (0, 1], got {options.forgetting}")
    if int(options.folds) < 2:
        raise ModelError(f"online: --folds must be at least 2, got {options.folds}")


class FieldSetup(NamedTuple):
    """What the field path needs of a recording without ``seq`` ids (:func:`field_setup`).

    Args:
        rests: :func:`rest_sequences`.
        batch: the motions as filter sequences (:func:`jaxcal.field.field_batch`).
        config: the initial fit's :class:`~jaxcal.multipos.MultiposConfig`.
        hp: the filter's :class:`~jaxcal.online.OnlineHP` (its ``sigma_acc`` measured at the rests).
        dt: sample period (s).
        kind: the filter's layout.
        init: the initial calibration from all the rests (:func:`jaxcal.field.rest_init`).
        gsens_choice: the rests' :class:`~jaxcal.field.GsensChoice` (``None`` where the options
            fix the g-sensitivity); ``config.g_sensitivity`` holds its outcome.
    """

    rests: RestSequences
    batch: field.FieldBatch
    config: mp.MultiposConfig
    hp: OnlineHP
    dt: float
    kind: str
    init: field.FieldInit
    gsens_choice: field.GsensChoice | None = None


def field_setup(rec: Recording, options: OnlineOptions) -> FieldSetup:
    """Cut a recording without ``seq`` ids between its rests and prepare the field path
    (:mod:`jaxcal.field`); refuses, in one line, a recording with fewer than two usable motions.

    Args:
        rec: a recording with ``acc`` and ``gyr`` (no ``seq``).
        options: :class:`OnlineOptions`.
    """
    rests = rest_sequences(rec, options)
    n_use = int(rests.usable.sum())
    if n_use < 2:
        raise ModelError(f"online: no 'seq' ids, and only {n_use} usable motions between {len(rests.intervals)} "
                         "rests (saturated ones are left out); record more rest-motion-rest sequences")
    prior = datasheet_prior(rec, options.prior_scale, options.prior_cross, "online") if options.datasheet_prior else None
    config = mp.MultiposConfig(g_sensitivity=bool(options.g_sensitivity), prior=prior)
    try:
        batch = field.field_batch(rec.acc, rec.gyr, rests.intervals, rests.usable)
    except ValueError as e:
        raise ModelError(f"online: {e}") from None
    init, choice = field.rest_init_chosen(rests.data, config=config, auto=options.g_sensitivity_auto)
    if choice is not None and choice.chosen:
        config = config._replace(g_sensitivity=True)
    hp = field_hp(options, field.rest_noise(rec.acc, rests.intervals, init.acc))
    return FieldSetup(rests, batch, config, hp, recording_dt(rec), _kind(options, True), init, choice)


def _fit_field(rec: Recording, options: OnlineOptions, log: Log) -> tuple[dict, dict]:
    """The field path of :func:`fit`: the state and the metadata."""
    fs = field_setup(rec, options)
    n_use = int(fs.rests.usable.sum())
    log(f"online: no 'seq' ids: segmented between {len(fs.rests.intervals)} rests into {n_use} sequences "
        f"({int((~fs.rests.usable).sum())} saturated motions left out)")
    log(f"online: initialised from the rests (|f| = 1 g) and the gravity carried between them; streaming the "
        f"{'every sample' if options.residuals == 'all' else 'rest'} residuals ({fs.kind}) ...")
    ch = fs.gsens_choice
    if ch is not None and np.isfinite(ch.loo_bias):
        log(f"online: the gyroscope's g-sensitivity {'taken' if ch.chosen else 'left out'}: the {ch.n_rests} rests' gyro "
            f"means, each left out in turn, {'are' if ch.chosen else 'are not'} predicted better with it "
            f"(mean squared error {ch.loo_gsens:.3g} +- {ch.se_gsens:.3g} against {ch.loo_bias:.3g} with a bias alone, "
            "recorded gyro units squared; "
            "--g-sensitivity-auto off to leave it out)")
    t0 = time.perf_counter()
    init = fs.init
    use = fs.rests.usable.astype(np.float64)
    cal = field.fit_field(fs.batch, init, fs.dt, fs.hp, fs.kind, options.residuals,
                          sigma_dir=field.carried_sigma(init, fs.rests.data, use))
    state = {s: linear_state(c)._asdict() for s, c in zip(SENSORS, cal[:2])}
    if fs.config.g_sensitivity:
        state["gyr"][GSENS_KEY] = np.asarray(cal.G, np.float64)
    meta = {
        "n_sequences": n_use,
        "sequences_from": "rests",
        "kind": fs.kind,
        "residuals": options.residuals,
        "g_sensitivity": bool(fs.config.g_sensitivity),
        **({} if fs.gsens_choice is None else {"g_sensitivity_choice": {  # JSON: no NaN (below 6 rests)
            k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in fs.gsens_choice._asdict().items()}}),
        "acc_from": options.acc_from,
        "datasheet_prior": bool(options.datasheet_prior),
        "sigma_acc": float(fs.hp.sigma_acc),
        "n_iter": int(fs.hp.n_iter),
        "dt": fs.dt,
        "fit_seconds": time.perf_counter() - t0,
        "spec_from": {"acc": "data (rests: |f| = 1 g)", "gyr": "data (rests and the gravity carried between them)"},
    }
    return state, meta


def fit(rec: Recording, options: OnlineOptions, log: Log) -> Fitted:
    """Self-calibrate both sensors from the recording's rotation sequences.

    With ``seq`` ids the filter streams every sample from the datasheet values (or a guess from the
    data), as on the thesis's Dataset 2. Without them the recording is calibrated in the field
    (:func:`field_setup`, :mod:`jaxcal.field`): cut between its rests, initialised from them, and
    streamed with the accelerometer residuals at the rests, the accelerometer held at its fit to
    the rests (``acc_from``); datasheet values are never the starting point (a wrong one cannot
    make it diverge), only, with ``datasheet_prior``, the initial fit's prior centre.

    Args:
        rec: a recording with ``acc``, ``gyr`` and ``seq`` ids or rests between its motions
            (datasheet values optional).
        options: :class:`OnlineOptions`.
        log: progress sink.
    """
    require_both(rec, "online")
    _check_options(options)
    if rec.seq is None:
        state, meta = _fit_field(rec, options, log)
        meta = {"units": units(rec, SENSORS), **meta}
    else:
        if options.g_sensitivity or options.residuals != "rests" or options.acc_from != "rests" or options.datasheet_prior:
            raise ModelError("online: --g-sensitivity, --residuals, --acc-from and --datasheet-prior apply between rests "
                             "(a recording without 'seq' ids); this one has seq ids (its datasheet values are the "
                             "filter's prior centre)")
        state, meta = _fit_seq(rec, options, log)
    for s, m in state.items():
        vals = m._asdict().values() if hasattr(m, "_asdict") else m.values()
        if not all(np.all(np.isfinite(np.asarray(v, np.float64))) for v in vals):
            raise ModelError(f"online: the {s} estimate is not finite (does the recording hold rotation sequences?)")
    log(f"fitting online ... done in {meta['fit_seconds']:.1f} s")
    return Fitted(SENSORS, state, meta)


def _fit_seq(rec: Recording, options: OnlineOptions, log: Log) -> tuple[dict, dict]:
    """The ``seq`` path of :func:`fit` (the thesis's setting): the state and the metadata."""
    acc_spec, gyr_spec = recording_spec(rec, "acc"), recording_spec(rec, "gyr")
    seq = sequences_of(rec, "online")
    n_seq = len(sequence_slices(rec))
    dt = recording_dt(rec)
    spec_from = {s: ("metadata" if sp is not None else "data") for s, sp in (("acc", acc_spec), ("gyr", gyr_spec))}
    hp = _hp(options, None)
    kind = _kind(options, False)
    log(f"fitting online on {n_seq} sequences ({rec.n} samples, dt {dt:g} s) ...")
    t0 = time.perf_counter()
    try:
        cals = fit_online_recording(np.asarray(rec.acc, np.float64), np.asarray(rec.gyr, np.float64), seq, dt,
                                    acc_spec, gyr_spec, hp, kind)
    except ValueError as e:
        raise ModelError(f"online: {e}") from None
    state = {s: linear_state(cal) for s, cal in zip(SENSORS, cals)}
    meta = {
        "units": units(rec, SENSORS),
        "n_sequences": n_seq,
        "sequences_from": "seq",
        "kind": kind,
        "sigma_acc": float(hp.sigma_acc),
        "n_iter": int(hp.n_iter),
        "dt": dt,
        "fit_seconds": time.perf_counter() - t0,
        "spec_from": spec_from,
    }
    return state, meta


def _seq_quality(rec: Recording, options: OnlineOptions, cals: tuple[LinearCal, LinearCal],
                 held_out: bool) -> tuple[QualityRow, QualityRow | None]:
    """:func:`quality` on a recording with ``seq`` ids (:mod:`jaxcal.eval.seqsplit`): each sequence
    scored by its first and last samples (``| |f| - 1 g |`` there, and the gravity carried from the
    first to the last); held out: a time split, fitted on the first 80 % of the sequences and
    scored on the last 20 %, beside the datasheet values it starts from."""
    acc_spec, gyr_spec = recording_spec(rec, "acc"), recording_spec(rec, "gyr")

    def fit_score(train: seqsplit.Bounds, test: seqsplit.Bounds) -> seqsplit.Errors:
        c = stream_segments(rec.acc, rec.gyr, np.asarray(train), recording_dt(rec), acc_spec, gyr_spec,
                            _hp(options, None), _kind(options, False))
        return score_cal(*c, seqsplit.ends_data(rec, test))

    return seqsplit.time_split_rows(rec, held_out, lambda bounds: score_cal(*cals, seqsplit.ends_data(rec, bounds)),
                                    fit_score, "fitted", datasheet_cals(rec))


def _field_held_out(fs: FieldSetup, options: OnlineOptions, log: Log | None) -> QualityRow:
    """:func:`quality`'s held-out row between rests: ``folds`` interleaved rest folds
    (:func:`jaxcal.field.fold_fits`) scored by :func:`jaxcal.eval.heldout.fold_errors`, beside
    the same folds' initial calibrations."""
    P = len(fs.rests.intervals)
    F = min(int(options.folds), P - 1)
    if log:
        log(f"online held out: {F} rest folds, each initialised and streamed without its rests ...")
    try:
        folds = field.fold_fits(fs.rests.data, fs.batch, fs.dt, fs.hp, F, fs.kind, options.residuals,
                                fs.config._replace(g_sensitivity=bool(options.g_sensitivity)), whole=fs.init,
                                gsens_auto=fs.gsens_choice is not None)
    except ValueError as e:
        return {"error": str(e)}
    how = (f"{F} interleaved rest folds (the initial rest in none), each initialised from its own rests, "
           f"{folds.n_seq.min()}-{folds.n_seq.max()} sequences per fold")
    if fs.gsens_choice is not None:
        how += f"; the gyroscope's g-sensitivity chosen by {int(folds.gsens.sum())} of the {F} folds' own rests"
    skipped = np.flatnonzero(~folds.determined)
    if skipped.size:
        n_rests = int(np.isin(folds.rest_fold, skipped).sum())
        how += (f"; {n_rests} rests not held out: without them the others do not determine the accelerometer "
                "(relative singular value below OBSERVABLE_TOL), so their score would be an extrapolation")
    if skipped.size == F:
        return {"error": "no fold's rests determine the accelerometer without the fold: record more rests"}
    ea, eg = fold_errors(folds.final, fs.rests.data, folds.rest_fold, folds.determined)
    row = quality_row(ea[1:][np.isfinite(ea[1:])], eg, how)
    ea0, eg0 = fold_errors(folds.init, fs.rests.data, folds.rest_fold, folds.determined)
    row["initial_guess"] = quality_row(ea0[1:][np.isfinite(ea0[1:])], eg0,
                                       "the same folds: the initial calibration from the rests, before the filter")
    return row


def quality(rec: Recording, options: OnlineOptions, model: Any, *, held_out: bool = True,
            log: Log | None = None) -> tuple[QualityRow, QualityRow | None]:
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
    cals = tuple(linear_cal_of_state(model.state[s]) for s in SENSORS)
    if rec.seq is not None:
        return _seq_quality(rec, options, cals, held_out)
    try:
        fs = field_setup(rec, options)
    except ModelError as e:
        return {"error": str(e)}, ({"error": str(e)} if held_out else None)
    ins = quality_row(*score_cal(*cals, fs.rests.data, gsens_of(model.state)), f"all {len(fs.rests.intervals)} rests")
    return ins, (_field_held_out(fs, options, log) if held_out else None)


METHOD = Method(
    "online", fit, apply_linear_state, OnlineOptions,
    "jaxcal's streaming self-calibration (affine per sensor, information filter on rotation "
    "sequences); seq ids, or rests between the motions; no labels",
    check_linear_state,
    quality=quality,
)


def rest_seq_recording(rec: Recording, options: OnlineOptions = OnlineOptions()) -> Recording:
    """A recording without ``seq`` ids as the thesis's Dataset 2 sees one: each usable motion
    between two rests, with ``rest_pad`` seconds of each rest, is a sequence with static ends; all
    are made as long as the longest by repeating the samples of the rest after it (a longer static
    end: the body does not move there). Times are re-laid at the recording's sample period. Missing
    datasheet values are filled in from the rests (:func:`rest_spec`).

    Args:
        rec: a recording with ``acc`` and ``gyr`` and rests between its motions (no ``seq``).
        options: :class:`OnlineOptions` (the rest options).
    """
    rests = rest_sequences(rec, options)
    js = np.flatnonzero(rests.usable)
    if len(js) < 2:
        raise ModelError(f"no 'seq' ids, and only {len(js)} usable motions between {len(rests.intervals)} rests; "
                         "record more rest-motion-rest sequences")
    n = int(max(b - a for a, b in rests.segments[js]))
    rows, seq = [], []
    for k, j in enumerate(js):
        a, b = rests.segments[j]
        r0, r1 = rests.intervals[j + 1]
        extra = np.resize(np.arange(r0, r1), n - (b - a))  # the next rest's samples, cycled
        rows.append(np.concatenate([np.arange(a, b), extra]))
        seq.append(np.full(n, k))
    idx = np.concatenate(rows)
    changes = {f: np.asarray(getattr(rec, f))[idx] for f in PER_SAMPLE_FIELDS if getattr(rec, f) is not None}
    changes["t"] = np.arange(len(idx)) * recording_dt(rec)
    changes["seq"] = np.concatenate(seq)
    for s, spec in zip(SENSORS, rest_spec(rests)):
        if recording_spec(rec, s) is None:  # no datasheet: the rests' diagonal stands in for it
            key = "acc_lsb_per_g" if s == "acc" else "gyr_lsb_per_rads"
            changes[key], changes[f"{s}_bias_lsb"] = np.asarray(spec.s), np.asarray(spec.b)
    return rec.replace(**changes, extra={}, gt_t=None, gt_pos=None, gt_quat=None)


def rest_spec(rests: RestSequences) -> tuple[Diag, Diag]:
    """Datasheet-like diagonal models ``y = s x + b`` of both sensors from a recording's rests
    (:func:`rest_sequences`; :func:`jaxcal.field.rest_init`'s diagonal), for a method that needs
    datasheet values on a recording without them (``online-thesis`` between rests)."""
    init = field.rest_init(rests.data)
    return tuple(Diag(1.0 / np.diag(np.asarray(c.A)), np.asarray(c.b)) for c in init[:2])
