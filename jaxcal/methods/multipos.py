"""Method ``multipos``: static poses joined by rotations (Tedaldi et al. 2014,
:func:`jaxcal.multipos.fit_multipos_recording`); no labels, no datasheet values. Stored and
applied as the linear methods are; with ``g_sensitivity`` (``--g-sensitivity``) the gyroscope's
state also holds its g-sensitivity ``G`` ((rad/s)/g, ``state/gyr/G``), applied as
``w = A_g (y_g - b_g) - G f`` with the calibrated accelerometer ``f``
(:func:`~jaxcal.methods.base.apply_linear_state`)."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from jaxcal import flags
from jaxcal.constants import EARTH_RATE, SENSORS
from jaxcal.eval.scores import QualityRow, quality_row
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
    datasheet_prior,
    linear_state,
    require_both,
    units,
)
from jaxcal.multipos import (
    OBSERVABLE_TOL,
    DetectOptions,
    MultiposConfig,
    detect_and_fit,
    fit_multipos_recording,
    jackknife_sd,
    leave_poses_out,
    observability,
    prepare,
)
from jaxcal.multipos.detect import fit_multipos_recording_gsens
from jaxcal.recording import Recording

__all__ = ["METHOD", "MultiposOptions", "bias_sd", "detect_options", "determined_folds", "fit", "fold_cals", "heldout", "multipos_config",
           "quality"]


class MultiposOptions(NamedTuple):
    """Options of ``multipos`` (static: plain Python values).

    Args:
        turns: whole turns about the vertical as ``((start, end), ...)`` in seconds, or ``None``;
            their axes are read from the accelerometer at the rests around them (no labels).
        partial: when the poses do not determine every combination, fit only those they do and
            leave the rest as recorded, instead of refusing.
        acc_model: ``"9"`` (scale, 3 misalignment angles, bias) or ``"12"`` (full 3x3 and bias).
        gyro_bias: ``"static"`` (mean over all rests) or ``"init"`` (the initial rest, as imu_tk).
        datasheet_prior: MAP with the recording's datasheet scales (``acc_lsb_per_g``,
            ``gyr_lsb_per_rads``) as prior centre (:class:`~jaxcal.multipos.DatasheetPrior`).
        prior_scale: the prior's relative scale tolerance (datasheet sensitivity tolerance).
        prior_cross: the prior's cross-axis tolerance (datasheet cross-axis sensitivity).
        init_duration: seconds of initial rest that set the rest threshold; ``None``: the first
            10 % of the recording, at most 30 s.
        min_rest: shortest rest (pose) kept, seconds.
        rest_window: moving-variance window of the rest detector, seconds.
        g_sensitivity: also fit the gyroscope's g-sensitivity ``G`` ((rad/s)/g; stored as
            ``state/gyr/G``, applied with the calibrated accelerometer), jointly with the bias
            from the rests (:func:`~jaxcal.multipos.gyro.rest_gsens`; needs ``gyro_bias="static"``).
        latitude: the rig's latitude in degrees, or ``None``: with ``g_sensitivity`` the vertical
            Earth rate (:data:`~jaxcal.constants.EARTH_RATE` ``sin(latitude)``, which the rests read
            along gravity) is taken out of ``G``; without it ``G``'s trace holds it (at most
            0.0042 (deg/s)/g).
    """

    turns: tuple[tuple[float, float], ...] | None = None
    partial: bool = False
    acc_model: str = "9"
    gyro_bias: str = "static"
    datasheet_prior: bool = False
    prior_scale: float = 0.03
    prior_cross: float = 0.02
    init_duration: float | None = None
    min_rest: float = 1.0
    rest_window: float = 1.0
    g_sensitivity: bool = False
    latitude: float | None = None

    FLAGS = {
        "turns": Flag("--turns", flags.turns, None, "whole turns about the vertical (e.g. turned flat on a table), "
                      "start-end in seconds; their axes are read from the accelerometer at the rests around them (no "
                      "labels)", "T0-T1[,T0-T1...]", show_default="none"),
        "partial": Flag("--partial", None, None, "when the poses do not determine every combination, fit only those "
                        "they do and leave the rest as recorded (recordings in g and rad/s; an undetermined gyroscope "
                        "is not calibrated) instead of refusing", const=True, show_default="refuse"),
        "acc_model": Flag("--acc-model", flags.choice("9", "12"), None, "accelerometer model: 9 (3 scales, 3 "
                          "misalignment angles, bias) or 12 (full 3x3 and bias)", "9|12"),
        "gyro_bias": Flag("--gyro-bias", flags.choice("static", "init"), None,
                          "gyro bias from all rests (static) or the initial rest only (init, as imu_tk)", "static|init"),
        "datasheet_prior": SHARED_FLAGS["datasheet_prior"],
        "g_sensitivity": SHARED_FLAGS["g_sensitivity"],
        "latitude": Flag("--latitude", flags.real(-90.0, 90.0, open_low=False), None, "the rig's latitude in degrees: "
                         "with --g-sensitivity the vertical Earth rate (15.04 sin(latitude) deg/h, read at rest along "
                         "gravity) is taken out of G instead of left in its trace", "DEG",
                         show_default="none: left in G"),
        **{k: SHARED_FLAGS[k] for k in ("prior_scale", "prior_cross", "init_duration", "min_rest", "rest_window")},
    }
    EFFECTS = {("gyr", "g_sensitivity"): "g_sensitivity"}  # what a diagnose report can switch on (methods.from_report)


def multipos_config(rec: Recording, options: MultiposOptions) -> MultiposConfig:
    """The :class:`~jaxcal.multipos.MultiposConfig` of ``options`` on ``rec`` (the datasheet prior
    reads the recording's datasheet scales; refused without them).

    Args:
        rec: the recording.
        options: :class:`MultiposOptions`.
    """
    if options.acc_model not in ("9", "12"):
        raise ModelError(f"multipos: --acc-model must be 9 or 12, got {options.acc_model!r}")
    if options.gyro_bias not in ("static", "init"):
        raise ModelError(f"multipos: --gyro-bias must be static or init, got {options.gyro_bias!r}")
    if options.g_sensitivity and options.gyro_bias != "static":
        raise ModelError("multipos: --g-sensitivity takes the bias jointly from all rests; it cannot be used with "
                         "--gyro-bias init")
    if options.latitude is not None and not options.g_sensitivity:
        raise ModelError("multipos: --latitude takes the Earth's rate out of the --g-sensitivity fit; give both or neither")
    prior = datasheet_prior(rec, options.prior_scale, options.prior_cross, "multipos") if options.datasheet_prior else None
    return MultiposConfig(acc_model=options.acc_model, gyro_bias=options.gyro_bias, prior=prior,
                          g_sensitivity=bool(options.g_sensitivity),
                          earth_rate_up=0.0 if options.latitude is None else EARTH_RATE * math.sin(math.radians(options.latitude)))


def detect_options(rec: Recording, options: MultiposOptions) -> DetectOptions:
    """:meth:`~jaxcal.multipos.DetectOptions.for_recording` with the rest options of ``options``.

    Args:
        rec: the recording.
        options: :class:`MultiposOptions`.
    """
    return DetectOptions.for_recording(rec)._replace(
        init_duration=options.init_duration, min_duration=float(options.min_rest), window=float(options.rest_window))


def _say_quality(q: dict, log: Log) -> None:
    """The fit's quality summary (:func:`jaxcal.multipos.fit_summary`) as progress lines."""
    gm = "-" if q["gyr_median_deg"] is None else f"{q['gyr_median_deg']:.3f} deg"
    turns = f", worst turn {q['turn_max_deg']:.3f} deg" if "turn_max_deg" in q else ""
    log(f"multipos: {q['n_poses']} poses, {q['n_transitions']} usable transitions; in-sample |f| - 1 g RMS "
        f"{q['acc_rms_mg']:.3f} mg, carried-gravity median {gm}{turns}; least determined combination "
        f"(relative singular value): acc {q['acc_sv_min']:.2f}, gyro {q['gyr_sv_min']:.2f}")
    for s, what in q.get("partial", {}).items():
        log(f"multipos --partial: {s}: {what}")


def _g_rows(G: np.ndarray) -> str:
    """``G`` ((rad/s)/g) in (deg/s)/g, row by row."""
    return "; ".join("[" + ", ".join(f"{v:+.4f}" for v in row) + "]" for row in np.degrees(np.asarray(G, np.float64)))


def fit(rec: Recording, options: MultiposOptions, log: Log) -> Fitted:
    """Detect the static poses, fit both sensors and check that the poses determine the fit.

    Args:
        rec: a recording with ``acc`` and ``gyr`` (static poses joined by rotations).
        options: :class:`MultiposOptions`.
        log: progress sink.
    """
    require_both(rec, "multipos")
    # No progress line before the fit: its refusals (poses that determine too little, turns the
    # data contradict) come from the fit itself and must stay the only line on stderr.
    t0 = time.perf_counter()
    gsens = None
    try:
        if options.g_sensitivity:
            acc_cal, gyr_cal, gsens, q = fit_multipos_recording_gsens(
                rec, multipos_config(rec, options), detect=detect_options(rec, options), turn_times=options.turns,
                partial=options.partial)
        else:
            acc_cal, gyr_cal, q = fit_multipos_recording(rec, multipos_config(rec, options), detect=detect_options(rec, options),
                                                         turn_times=options.turns, partial=options.partial, summary=True)
    except ValueError as e:
        raise ModelError(f"multipos: {e}") from None
    elapsed = time.perf_counter() - t0
    state: dict[str, Any] = {s: linear_state(c) for s, c in zip(SENSORS, (acc_cal, gyr_cal)) if c is not None}
    if gsens is not None and "gyr" in state:
        state["gyr"] = {**state["gyr"]._asdict(), GSENS_KEY: np.asarray(gsens, np.float64)}
    if not state:
        raise ModelError("multipos: no sensor could be calibrated")
    log(f"fitted multipos on {rec.n} samples in {elapsed:.1f} s")
    _say_quality(q, log)
    if gsens is not None and "gyr" in state:
        log(f"multipos: gyro g-sensitivity G (deg/s)/g, rows {_g_rows(gsens)}")
    sensors = tuple(s for s in SENSORS if s in state)
    return Fitted(sensors, state, {"units": units(rec, sensors), "fit_seconds": elapsed, "fit_quality": q})


def heldout(rec: Recording, options: MultiposOptions, meta: Mapping[str, Any] | None = None) -> QualityRow:
    """Leave-one-pose-out quality of ``multipos`` on ``rec`` (:func:`jaxcal.multipos.leave_poses_out`:
    every fold fitted inside one compiled ``lax.map``): each pose's ``| |f| - 1 g |`` from the fit
    that left it out (RMS, mg), and each usable transition's carried-gravity angle from the fit
    that left it out (median, deg). The poses are those the fit detected; turns (``--turns``) are
    not used by the folds. With ``--g-sensitivity`` every fold fits ``G`` too. Folds that leave the
    fit undetermined (:func:`determined_folds`) are not scored; ``not_held_out`` lists their poses
    and transitions. With ``--partial`` the folds fit what the whole fit did
    (``meta["fit_quality"]["partial"]``).

    Args:
        rec: the recording the model was fitted on.
        options: :class:`MultiposOptions` of the fit.
        meta: the fitted model's metadata (for ``--partial``), or ``None``.
    """
    config = multipos_config(rec, options)
    kept = ((meta or {}).get("fit_quality") or {}).get("partial", {})
    if "acc" in kept:
        config = config._replace(acc_fit="determined")
    if "gyr" in kept:
        config = config._replace(gyr_fit="none")
    det = detect_options(rec, options)
    try:
        whole, iv, _ = detect_and_fit(rec.t, rec.acc, rec.gyr, config, detect=det, check=False)
        data = prepare(rec.t, rec.acc, rec.gyr, iv, gyr_limit=det.gyr_limit, midpoint=config.midpoint)
        ho = leave_poses_out(data, config)
    except ValueError as e:
        raise ModelError(f"multipos held out: {e}") from None
    acc_ok, gyr_ok = determined_folds(data, whole, ho)
    ea = ho.acc_err[acc_ok]
    eg = ho.gyr_err[gyr_ok & np.isfinite(ho.gyr_err)]
    how = f"leave-one-pose-out, {ea.size} poses, {eg.size} transitions"
    skipped = [f"{n} {what}{'s' if n > 1 else ''}" for n, what in ((int((~acc_ok).sum()), "pose"),
                                                                  (int((~gyr_ok).sum()), "transition")) if n]
    if skipped:
        how += (f"; {' and '.join(skipped)} not held out: without one of them the others do not determine the fit "
                "(relative singular value below OBSERVABLE_TOL), so its score would be an extrapolation")
    row = quality_row(ea, eg, how + ("; turns not used by the folds" if options.turns else ""))
    row["not_held_out"] = {"poses": np.flatnonzero(~acc_ok).tolist(), "transitions": np.flatnonzero(~gyr_ok).tolist()}
    row["bias_sd"] = bias_sd(ho, acc_ok, kept)
    row["fold_cals"] = fold_cals(ho, acc_ok, kept)
    return row


def bias_sd(ho: Any, acc_ok: np.ndarray, kept: Mapping[str, Any]) -> dict[str, Any]:
    """The standard errors of the fitted biases, in the model's input units, from the
    leave-one-pose-out folds (:func:`jaxcal.multipos.jackknife_sd` of each fold's bias): fold ``k``
    leaves pose ``k`` out of both fits (the gyroscope's bias is the weighted mean of the poses'
    rests). Folds that leave the fit undetermined are not used; a sensor the fit kept at its
    starting point (``--partial``) has none.

    Args:
        ho: :func:`jaxcal.multipos.leave_poses_out`'s result, one fold per pose.
        acc_ok: (P,) the folds that determine the fit (:func:`determined_folds`).
        kept: ``meta["fit_quality"]["partial"]``.
    """
    out: dict[str, Any] = {}
    for s, folds in (("acc", ho.acc_bias), ("gyr", ho.gyr_bias)):
        sd = jackknife_sd(folds, acc_ok)
        out[s] = None if s in kept or not np.all(np.isfinite(sd)) else sd.tolist()
    out["how"] = (f"delete-one-pose jackknife over {int(acc_ok.sum())} poses: the standard error of this session's "
                  "estimate (between-pose spread included); a part's turn-on bias repeatability adds to it")
    return out


def fold_cals(ho: Any, acc_ok: np.ndarray, kept: Mapping[str, Any]) -> dict[str, Any]:
    """Each determined leave-one-pose-out fold's calibration ``x = A (y - b)`` (model input units), per
    sensor ``{"A": (F, 3, 3), "b": (F, 3)}`` as lists; a sensor the fit kept at its starting point
    (``--partial``) has ``None``. The exports jackknife their own parameters over these
    (:func:`jaxcal.formats.yaml_doc.intrinsics_sd`): the file's matrices are non-linear in ``A``, so their
    standard errors come from the folds, not from ``A``'s.

    Args:
        ho: :func:`jaxcal.multipos.leave_poses_out`'s result, one fold per pose.
        acc_ok: (P,) the folds that determine the fit (:func:`determined_folds`).
        kept: ``meta["fit_quality"]["partial"]``.
    """
    out: dict[str, Any] = {}
    for s, A, b in (("acc", ho.acc_A, ho.acc_bias), ("gyr", ho.gyr_A, ho.gyr_bias)):
        A, b = np.asarray(A, np.float64)[acc_ok], np.asarray(b, np.float64)[acc_ok]
        ok = s not in kept and len(A) >= 2 and np.all(np.isfinite(A)) and np.all(np.isfinite(b))
        out[s] = {"A": A.tolist(), "b": b.tolist()} if ok else None
    out["how"] = f"the {int(acc_ok.sum())} determined delete-one-pose folds of the held-out figure"
    return out


def determined_folds(data: Any, whole: Any, ho: Any) -> tuple[np.ndarray, np.ndarray]:
    """Which leave-one-out folds of :func:`jaxcal.multipos.leave_poses_out` (one pose and one
    transition per fold) still determine the fit: ``(acc_ok (P,), gyr_ok (J,))``, from
    :func:`jaxcal.multipos.observability` at the whole fit with that pose (transition) left out.
    A pose whose fold is undetermined (e.g. the only pose with one axis down, as in a six-face
    Ferraris session) is scored by an extrapolation, not a calibration.

    Args:
        data: the prepared poses and transitions.
        whole: the fit on all of them (:class:`~jaxcal.multipos.MultiposFit`).
        ho: the folds' scores (:class:`~jaxcal.multipos.HeldOut`).
    """
    P, J = len(ho.acc_err), len(ho.gyr_err)
    acc_ok, gyr_ok = np.ones(P, bool), np.ones(J, bool)
    for k in range(P):
        aw = (ho.pose_fold != ho.pose_fold[k]).astype(np.float64)
        acc_ok[k] = observability(data, whole.acc, whole.gyr, acc_w=aw).acc_sv.min() >= OBSERVABLE_TOL
    for j in range(J):
        gw = (ho.trans_fold != ho.trans_fold[j]).astype(np.float64)
        gyr_ok[j] = observability(data, whole.acc, whole.gyr, gyr_w=gw).gyr_sv.min() >= OBSERVABLE_TOL
    return acc_ok, gyr_ok


def _without_g(rec: Recording, options: MultiposOptions, model: Any, log: Log) -> dict[str, Any]:
    """The same leave-one-pose-out figure of ``multipos`` without ``--g-sensitivity``, so a user sees
    whether fitting ``G`` helped this session (on the MPU-6050's 10 poses it does not; results/real.md)."""
    log("held out without --g-sensitivity, for comparison ...")
    plain = options._replace(g_sensitivity=False, latitude=None)
    try:
        q = heldout(rec, plain, model.meta)
    except ModelError as e:
        return {"error": str(e)}
    return {k: q[k] for k in ("acc_rms_mg", "gyr_median_deg", "how")}


def quality(rec: Recording, options: MultiposOptions, model: Any, *, held_out: bool = True,
            log: Log | None = None) -> tuple[QualityRow, QualityRow | None]:
    """In-sample quality from the fit's summary (``meta["fit_quality"]``: all poses and
    transitions) and the leave-one-pose-out figure (:func:`heldout`); with ``--g-sensitivity``
    also that figure without ``G`` (``without_g_sensitivity``).

    The arguments and rows of a method's ``quality`` (:data:`jaxcal.methods.quality.QualityFn`).
    """
    q = model.meta.get("fit_quality", {})
    ins: QualityRow = {"acc_rms_mg": q.get("acc_rms_mg"), "gyr_median_deg": q.get("gyr_median_deg"),
                       "how": "all poses and transitions"}
    if not held_out:
        return ins, None
    try:
        ho = heldout(rec, options, model.meta)
    except ModelError as e:
        return ins, {"error": str(e)}
    if options.g_sensitivity:
        ho["without_g_sensitivity"] = _without_g(rec, options, model, log or (lambda msg: None))
    return ins, ho


METHOD = Method(
    "multipos", fit, apply_linear_state, MultiposOptions,
    "static poses joined by rotations (Tedaldi et al. 2014); no labels, no datasheet values",
    check_linear_state,
    quality=quality,
)
