"""Multipos on a whole recording: detect the static poses (imu_tk's threshold scan), fit, check
what the poses determine, summarise the fit (``jaxcal calibrate --method multipos``).

:class:`DetectOptions` holds the detection options and their defaults (one place);
:func:`detect_and_fit` works on arrays, :func:`fit_multipos_recording` on a
:class:`~jaxcal.recording.Recording` and returns :class:`~jaxcal.sensor.LinearCal` calibrations.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal.multipos.acc import acc_norm_errors, fit_acc_determined, fit_acc_jit
from jaxcal.multipos.data import OBSERVABLE_TOL, MultiposData, VerticalTurns, prepare, turns_from_times
from jaxcal.multipos.fit import MultiposConfig, MultiposFit, fit_prepared_numpy
from jaxcal.multipos.gyro import gyro_angle_errors_jit, vertical_turn_errors
from jaxcal.multipos.observe import Observability, check_observable, observability
from jaxcal.precision import float64
from jaxcal.sensor import LinearCal
from jaxcal.static import StaticDetection, detect_static

if TYPE_CHECKING:
    from jaxcal.recording import Recording

__all__ = [
    "default_gyr_limit",
    "DetectOptions",
    "detect_and_fit",
    "detect_rests",
    "TURN_TOL_DEG",
    "check_turns",
    "fit_summary",
    "fit_multipos_recording",
    "fit_multipos_recording_gsens",
    "rest_design_sv",
    "traceless",
]


def default_gyr_limit(gyr: np.ndarray, unit: str) -> float | None:
    """Saturation limit for raw counts: 32767 for signed, 65535 for unsigned 16-bit data.

    Args:
        gyr: (N, 3) gyroscope outputs (only their sign is read).
        unit: the gyroscope's unit; only ``"LSB"`` has a limit.
    """
    if unit != "LSB":
        return None
    return 32767.0 if np.min(gyr) < 0 else 65535.0


class DetectOptions(NamedTuple):
    """How :func:`detect_and_fit` finds the static poses and prepares the transitions (static:
    Python values, numpy side). The defaults are imu_tk's; :meth:`for_recording` gives those of
    :func:`fit_multipos_recording`.

    Args:
        init_duration: seconds of initial rest that set the variance threshold; ``None``: the
            first 10 % of the recording, capped at 30 s (a safe guess only if the user rested
            there; pass it).
        ks: threshold multipliers scanned; the one with the smallest mean squared ``|f| - 1``
            residual (at least 9 poses) is kept.
        window: moving-variance window (s).
        min_duration: shortest static interval (s).
        gyr_limit: gyro saturation limit (a transition reaching it is left out), or ``None``.
        gyr_gate: also require a quiet gyro at rest (:func:`~jaxcal.static.detect_static`), which
            keeps turns about the vertical out of the poses; off in imu_tk's detector.
    """

    init_duration: float | None = None
    ks: tuple[float, ...] = tuple(float(k) for k in range(1, 11))
    window: float = 1.0
    min_duration: float = 1.0
    gyr_limit: float | None = None
    gyr_gate: bool = False

    @classmethod
    def for_recording(cls, rec: Recording) -> DetectOptions:
        """The defaults of :func:`fit_multipos_recording`: the saturation limit of the recording's
        gyro units (:func:`default_gyr_limit`) and the gyro gate on (a turn about the vertical must
        not pass for a pose). Change fields with ``._replace``."""
        return cls(gyr_limit=default_gyr_limit(np.asarray(rec.gyr), rec.gyr_unit), gyr_gate=True)


def detect_and_fit(
    t: np.ndarray,
    acc: np.ndarray,
    gyr: np.ndarray,
    config: MultiposConfig = MultiposConfig(),
    *,
    detect: DetectOptions = DetectOptions(),
    turn_times: Any = None,
    check: bool = True,
) -> tuple[MultiposFit, np.ndarray, float]:
    """imu_tk's procedure: for each threshold multiplier ``k`` detect the static intervals and
    fit the accelerometer; keep the ``k`` with the smallest mean squared ``|f| - 1`` residual
    (at least 9 poses), then fit the gyroscope. Returns ``(fit, intervals, k)``.

    Args:
        t: (N,) times (s).
        acc, gyr: (N, 3) outputs.
        config: :class:`~jaxcal.multipos.fit.MultiposConfig`.
        detect: :class:`DetectOptions` (detection and saturation).
        turn_times: optional (K, 2) start/end times (s) of whole turns about the vertical
            (:func:`~jaxcal.multipos.data.turns_from_times`), unlabelled.
        check: raise ``ValueError`` when the poses do not determine the fit (:func:`check_observable`).
    """
    fit, det, data, turns = _detect_fit(t, acc, gyr, config, detect, turn_times)
    if check:
        check_observable(observability(data, fit.acc, fit.gyr, turns=turns))
    return fit, det.intervals, det.k


FALLBACK_K = 3.0  # detect_rests's single threshold multiplier when the scan finds fewer than 9 rests


def detect_rests(rec: Recording, detect: DetectOptions) -> np.ndarray:
    """The rests of a recording (both sensors): :func:`detect_and_fit`'s threshold scan (no fit
    check); with fewer than 9 rests for every threshold, :func:`~jaxcal.static.detect_static` with
    ``k =`` :data:`FALLBACK_K` and the gyro gate on. Returns (P, 2) sample ranges ``[a, b)``.

    Args:
        rec: the recording (``t``, ``acc``, ``gyr``).
        detect: :class:`DetectOptions` (``init_duration``, ``window``, ``min_duration`` also set the fallback's).

    Raises:
        ValueError: the fallback finds no rest either (its own message).
    """
    t = np.asarray(rec.t, np.float64)
    try:
        _, iv, _ = detect_and_fit(t, rec.acc, rec.gyr, detect=detect, check=False)
    except ValueError:
        init = detect.init_duration if detect.init_duration is not None else min(30.0, 0.1 * (t[-1] - t[0]))
        iv = detect_static(t, rec.acc, k=FALLBACK_K, init_duration=init, window=detect.window,
                           min_duration=detect.min_duration, gyr=rec.gyr).intervals
    return np.asarray(iv, int)


@float64
def _detect_fit(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, config: MultiposConfig, detect: DetectOptions,
                turn_times: Any) -> tuple[MultiposFit, StaticDetection, MultiposData, VerticalTurns | None]:
    """:func:`detect_and_fit`'s work: ``(fit, detection, prepared data, turns)``."""
    t = np.asarray(t, np.float64)
    init_duration = detect.init_duration
    if init_duration is None:
        init_duration = min(30.0, 0.1 * (t[-1] - t[0]))
    best = None
    for k in detect.ks:
        det = detect_static(t, acc, k=k, init_duration=init_duration, window=detect.window,
                            min_duration=detect.min_duration, gyr=gyr if detect.gyr_gate else None,
                            gyr_gsens=config.g_sensitivity)
        if len(det.intervals) < 9:
            continue
        pa = jnp.asarray(np.stack([np.asarray(acc, np.float64)[a:b].mean(0) for a, b in det.intervals]))
        _, cost = fit_acc_jit(pa, jnp.ones(len(pa)), config.acc_model, config.max_steps, None, config.acc_ridge)
        score = float(cost) / len(pa)
        if best is None or score < best[0]:
            best = (score, det)
    if best is None:
        raise ValueError("fewer than 9 static poses found for every threshold; record more poses")
    det = best[1]
    turns = None if turn_times is None else turns_from_times(t, acc, gyr, turn_times, gyr_limit=detect.gyr_limit)
    data = prepare(t, acc, gyr, det.intervals, gyr_limit=detect.gyr_limit, midpoint=config.midpoint)
    return fit_prepared_numpy(data, config, turns=turns), det, data, turns


TURN_TOL_DEG = 20.0  # a real whole turn closes within a degree or two after the fit


@float64
def check_turns(fit: MultiposFit, turns: VerticalTurns, times: Any) -> None:
    """Refuse turns the data contradict: after the fit, a window given as a whole turn about the
    vertical must integrate (with the calibrated gyroscope) to within :data:`TURN_TOL_DEG` of one.
    A window that is not a whole turn (wrong times, e.g. another session's) cannot be fitted to
    one, and would only bend the gyroscope calibration towards it. Raises ``ValueError`` naming the
    first such turn, its times and the angle the gyroscope measures there.

    Args:
        fit: the fit that used the turns.
        turns: the turns (:func:`~jaxcal.multipos.turns_from_times`).
        times: (K, 2) start and end of each turn (s), as the user gave them (for the message).
    """
    tj, fit = (jax.tree_util.tree_map(jnp.asarray, x) for x in (turns, fit))
    err = np.degrees(np.asarray(vertical_turn_errors(fit.gyr, fit.gsens, fit.acc, tj)))
    rate_int = np.asarray(tj.y_int - fit.gyr.b * tj.dt_sum[:, None]) @ np.asarray(fit.gyr.A).T
    angle = np.degrees(np.linalg.norm(rate_int, axis=1))
    tt = np.asarray(times, np.float64).reshape(-1, 2)
    for k in np.flatnonzero((err > TURN_TOL_DEG) & np.asarray(turns.seg_ok)):  # saturated turns are not fitted
        claimed = np.degrees(float(turns.angle[k]))
        raise ValueError(
            f"turn {k + 1} ({tt[k, 0]:g}-{tt[k, 1]:g} s): the calibrated gyroscope measures {angle[k]:.1f} deg of "
            f"rotation there, not a whole {claimed:.0f} deg turn about the vertical (it misses one by {err[k]:.0f} "
            "deg); check the turn times (--turns) against this recording")


@float64
def fit_summary(data: MultiposData, fit: MultiposFit, turns: VerticalTurns | None = None,
                obs: Observability | None = None) -> dict:
    """In-sample quality of a fit on its own poses, for the user to judge a calibration: pose and
    usable-transition counts, RMS ``| |f| - 1 |`` (mg), median carried-gravity angle (deg), the
    worst vertical-turn error (deg, with ``turns``), and the smallest relative singular values of
    :func:`observability` (near 0: a combination the poses barely determine). In-sample figures
    are optimistic; ``leave_poses_out`` gives held-out ones. ``obs``: :func:`observability` of the
    same fit, if already computed.

    Args:
        data: the fit's prepared poses and transitions.
        fit: the fit.
        turns: the vertical turns the fit used; None: none.
        obs: :func:`observability` of the same fit; None: computed here.
    """
    obs = observability(data, fit.acc, fit.gyr, turns=turns) if obs is None else obs
    d, fit = (jax.tree_util.tree_map(jnp.asarray, x) for x in (data, fit))
    ea = np.asarray(acc_norm_errors(fit.acc, d.pose_acc))
    eg = np.asarray(gyro_angle_errors_jit(fit.gyr, fit.gsens, fit.acc, d))[np.asarray(data.seg_ok)]
    et = None if turns is None else np.asarray(vertical_turn_errors(
        fit.gyr, fit.gsens, fit.acc, jax.tree_util.tree_map(jnp.asarray, turns)))
    out = {"n_poses": int(len(ea)), "n_transitions": int(len(eg)), "acc_rms_mg": float(1e3 * np.sqrt(np.mean(ea**2))),
           "gyr_median_deg": float(np.degrees(np.median(eg))) if len(eg) else None,
           "acc_sv_min": float(obs.acc_sv.min()), "gyr_sv_min": float(obs.gyr_sv.min())}
    if et is not None:
        out["turn_max_deg"] = float(np.degrees(et.max()))
    return out


def fit_multipos_recording(
    rec: Recording,
    config: MultiposConfig = MultiposConfig(),
    *,
    detect: DetectOptions | None = None,
    turn_times: Any = None,
    summary: bool = False,
    partial: bool = False,
    check: bool = True,
) -> tuple[LinearCal, LinearCal | None] | tuple[LinearCal, LinearCal | None, dict]:
    """Calibrate a :class:`~jaxcal.recording.Recording` by multi-position self-calibration. Needs
    ``acc`` and ``gyr``; no labels, no datasheet values.

    Returns the applied calibrations ``(acc_cal, gyr_cal)`` as :class:`~jaxcal.sensor.LinearCal`
    (``x = A (y - b)``, ``x`` in g and rad/s, ``y`` in the recording's units; numpy arrays;
    ``.to_forward()`` gives ``y = S x + b``). The g-sensitivity option is not representable as a
    ``LinearCal`` and is refused here; :func:`fit_multipos_recording_gsens` fits it.

    When the poses do not determine every combination (:func:`check_observable`) this raises,
    unless ``partial``: then, for a recording already in g and rad/s, the accelerometer is fitted
    by :func:`fit_acc_determined` (only the determined combinations move) and an undetermined
    gyroscope is left as recorded (its calibration is ``None``); the summary's ``partial`` says
    which. Turns (``turn_times``) that the calibrated gyroscope does not measure as whole turns
    raise (:func:`check_turns`), as the observability check does, unless ``check=False``.

    Args:
        rec: the recording (``t``, ``acc``, ``gyr``, ``acc_unit``, ``gyr_unit`` are read).
        config: :class:`~jaxcal.multipos.fit.MultiposConfig` (``g_sensitivity`` must be off).
        detect: :class:`DetectOptions`; ``None``: :meth:`DetectOptions.for_recording` (gyro gate
            on, saturation limit from the units).
        turn_times: optional (K, 2) start/end times (s) of whole turns about the vertical.
        summary: also return :func:`fit_summary` of the fit (in-sample quality, observability).
        partial: fit only what the poses determine instead of refusing (recording in g, rad/s).
        check: run the observability and turn checks.
    """
    if config.g_sensitivity:
        raise ValueError("fit_multipos_recording returns affine models; use fit_multipos_recording_gsens for g-sensitivity")
    fit, config, data, turns, obs, kept = _fit_recording(rec, config, detect, turn_times, partial, check, summary)
    cals = (fit.acc, None if config.gyr_fit == "none" else fit.gyr)
    if not summary:
        return cals
    return (*cals, fit_summary(data, fit, turns, obs) | ({"partial": kept} if kept else {}))


def fit_multipos_recording_gsens(
    rec: Recording,
    config: MultiposConfig = MultiposConfig(g_sensitivity=True),
    *,
    detect: DetectOptions | None = None,
    turn_times: Any = None,
    partial: bool = False,
    check: bool = True,
) -> tuple[LinearCal, LinearCal | None, np.ndarray | None, dict]:
    """:func:`fit_multipos_recording` with the gyroscope's g-sensitivity fitted
    (``config.g_sensitivity`` is forced on): ``w = A_g (y_g - b_g) - G_s f``, ``f`` the calibrated
    accelerometer (g), ``G_s`` in (rad/s)/g. By default (``config.gsens_from="rests"``) the bias
    and ``G_s`` come jointly from the rests (:func:`~jaxcal.multipos.gyro.rest_gsens`: at rest
    each pose's mean output is ``b_g + H f``), trace included; with ``"transitions"`` ``G_s`` is
    fitted from the carried gravity instead and made traceless (:func:`traceless`). Returns
    ``(acc_cal, gyr_cal, G_s, summary)``; ``gyr_cal`` and ``G_s`` are ``None`` when ``partial``
    leaves the gyroscope as recorded. With ``check``, rests whose gravity directions do not span
    3-D (:func:`rest_design_sv` below ``OBSERVABLE_TOL``) are refused.

    Args:
        rec: the recording (``t``, ``acc``, ``gyr``, ``acc_unit``, ``gyr_unit`` are read).
        config: :class:`~jaxcal.multipos.fit.MultiposConfig` (``g_sensitivity`` set to ``True``).
        detect: :class:`DetectOptions`; ``None``: :meth:`DetectOptions.for_recording`.
        turn_times: optional (K, 2) start/end times (s) of whole turns about the vertical.
        partial: fit only what the poses determine instead of refusing (recording in g, rad/s).
        check: run the observability and turn checks.
    """
    config = config._replace(g_sensitivity=True)
    fit, config, data, turns, obs, kept = _fit_recording(rec, config, detect, turn_times, partial, check, True)
    sv = rest_design_sv(data, fit.acc)
    if check and sv.min() < OBSERVABLE_TOL:
        raise ValueError(f"the g-sensitivity needs rests whose gravity directions span 3-D (at least 4 poses; relative "
                         f"singular values of the rests' design {np.array2string(sv, precision=3)}): add poses with "
                         f"each axis up and down")
    gs = np.asarray(fit.gsens, np.float64)
    if config.gsens_from == "transitions":
        gs = traceless(gs)
    fit = fit._replace(gsens=gs)
    gyr = None if config.gyr_fit == "none" else fit.gyr
    summary = fit_summary(data, fit, turns, obs) | {"gsens_rest_sv_min": float(sv.min())}
    return fit.acc, gyr, None if gyr is None else gs, summary | ({"partial": kept} if kept else {})


def rest_design_sv(data: MultiposData, acc: LinearCal) -> np.ndarray:
    """Relative singular values (largest 1) of the rests' design ``[1, f_k]`` of
    :func:`~jaxcal.multipos.gyro.rest_gsens` (columns scaled to unit norm): small when the poses'
    gravity directions do not span 3-D, so the bias and the g-sensitivity are not both determined.

    Args:
        data: prepared poses.
        acc: the accelerometer calibration giving ``f_k``.
    """
    f = (np.asarray(data.pose_acc, np.float64) - np.asarray(acc.b)) @ np.asarray(acc.A).T
    x = np.concatenate([np.ones((len(f), 1)), f], 1)
    n = np.linalg.norm(x, axis=0)
    sv = np.linalg.svd(x / np.where(n > 0, n, 1.0), compute_uv=False)
    return sv / sv[0]


def traceless(G: np.ndarray) -> np.ndarray:
    """``G - tr(G) / 3 I``: the part of a gyro g-sensitivity that gravity carrying observes.

    The isotropic part ``c I`` adds ``c f`` to the rate, a rotation about the specific force
    ``f``, i.e. about the vertical while the IMU only turns: it leaves every carried gravity
    direction unchanged (``du/dt = -(w + c u) x u = -w x u``), so the transitions alone do not
    determine it (a fit from them, ``gsens_from="transitions"``, left it at 0.5 to 1.5 (deg/s)/g on
    simulated sessions with a true trace of 0.04 (deg/s)/g), and that estimate sets it to zero.
    The rests do determine it (:func:`~jaxcal.multipos.gyro.rest_gsens`).

    Args:
        G: (3, 3) g-sensitivity.
    """
    return G - np.trace(G) / 3.0 * np.eye(3)


@float64
def _fit_recording(rec: Recording, config: MultiposConfig, detect: DetectOptions | None, turn_times: Any,
                   partial: bool, check: bool, summary: bool) -> tuple[MultiposFit, MultiposConfig, MultiposData,
                                                                     VerticalTurns | None, Observability | None, dict]:
    """The work of :func:`fit_multipos_recording` and :func:`fit_multipos_recording_gsens`:
    ``(fit, config as fitted, data, turns, observability, kept)``."""
    t, acc, gyr = rec.t, rec.acc, rec.gyr
    if acc is None or gyr is None:
        raise ValueError("multipos needs both 'acc' and 'gyr'")
    units = (rec.acc_unit, rec.gyr_unit)
    if partial and units != ("g", "rad/s"):
        raise ValueError(f"partial keeps what the poses do not determine as recorded, which needs a recording in "
                         f"g and rad/s; this one is in {units[0]} and {units[1]}")
    detect = DetectOptions.for_recording(rec) if detect is None else detect
    fit, _, data, turns = _detect_fit(t, acc, gyr, config, detect, turn_times)
    if turns is not None and check:
        check_turns(fit, turns, turn_times)
    obs = observability(data, fit.acc, fit.gyr, turns=turns) if check or summary or partial else None
    kept = {}
    if partial:
        if (obs.acc_sv < OBSERVABLE_TOL).any():
            config = config._replace(acc_fit="determined")
            n = int(fit_acc_determined(jnp.asarray(data.pose_acc, jnp.float64), jnp.ones(len(data.pose_acc)))[1])
            kept["acc"] = f"{9 - n} of 9 combinations left as recorded, {n} fitted"
            fit = fit_prepared_numpy(data, config, turns=turns)
            obs = observability(data, fit.acc, fit.gyr, turns=turns)  # the gyro design, linearised at the new gravity directions
        if (obs.gyr_sv < OBSERVABLE_TOL).any():
            config = config._replace(gyr_fit="none")
            kept["gyr"] = "left as recorded (the rotations determine too little)"
            fit = fit_prepared_numpy(data, config, turns=turns)
    elif check:
        try:
            check_observable(obs)
        except ValueError as e:
            raise ValueError(f"{e}; or calibrate only what the poses determine (partial=True, --partial)") from None
    return fit, config, data, turns, obs, kept
