"""Method ``multipos``: static poses joined by rotations (Tedaldi et al. 2014,
:func:`jaxcal.multipos.fit_multipos_recording`); no labels, no datasheet values. Stored and
applied as the linear methods are."""

from __future__ import annotations

import time
from typing import NamedTuple

from jaxcal.constants import SENSORS
from jaxcal.methods.base import (
    Fitted,
    Log,
    Method,
    ModelError,
    apply_linear_state,
    check_linear_state,
    linear_state,
    require_both,
    units,
)
from jaxcal.multipos import fit_multipos_recording
from jaxcal.recording import Recording

__all__ = ["METHOD", "MultiposOptions", "fit"]


class MultiposOptions(NamedTuple):
    """Options of ``multipos`` (static: plain Python values).

    Args:
        turns: whole turns about the vertical as ``((start, end), ...)`` in seconds, or ``None``;
            their axes are read from the accelerometer at the rests around them (no labels).
        partial: when the poses do not determine every combination, fit only those they do and
            leave the rest as recorded, instead of refusing.
    """

    turns: tuple[tuple[float, float], ...] | None = None
    partial: bool = False


def _say_quality(q: dict, log: Log) -> None:
    """The fit's quality summary (:func:`jaxcal.multipos.fit_summary`) as progress lines."""
    gm = "-" if q["gyr_median_deg"] is None else f"{q['gyr_median_deg']:.3f} deg"
    turns = f", worst turn {q['turn_max_deg']:.3f} deg" if "turn_max_deg" in q else ""
    log(f"multipos: {q['n_poses']} poses, {q['n_transitions']} usable transitions; in-sample |f| - 1 g RMS "
        f"{q['acc_rms_mg']:.3f} mg, carried-gravity median {gm}{turns}; least determined combination "
        f"(relative singular value): acc {q['acc_sv_min']:.2f}, gyro {q['gyr_sv_min']:.2f}")
    for s, what in q.get("partial", {}).items():
        log(f"multipos --partial: {s}: {what}")


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
    try:
        acc_cal, gyr_cal, q = fit_multipos_recording(rec, turn_times=options.turns, partial=options.partial, summary=True)
    except ValueError as e:
        raise ModelError(f"multipos: {e}") from None
    elapsed = time.perf_counter() - t0
    state = {s: linear_state(c) for s, c in zip(SENSORS, (acc_cal, gyr_cal)) if c is not None}
    if not state:
        raise ModelError("multipos: no sensor could be calibrated")
    log(f"fitted multipos on {rec.n} samples in {elapsed:.1f} s")
    _say_quality(q, log)
    sensors = tuple(s for s in SENSORS if s in state)
    return Fitted(sensors, state, {"units": units(rec, sensors), "fit_seconds": elapsed, "fit_quality": q})


METHOD = Method(
    "multipos", fit, apply_linear_state, MultiposOptions,
    "static poses joined by rotations (Tedaldi et al. 2014); no labels, no datasheet values",
    check_linear_state,
)
