"""Plausibility: what the data contradict in a recording's declared units and datasheet scales
(CONVENTIONS.md, "What is refused"): :func:`implausible` judges values said to be in g or rad/s,
:func:`check_plausible` judges a whole :class:`~jaxcal.recording.Recording`."""

from __future__ import annotations

import numpy as np

from jaxcal.constants import PHYS_UNIT, SENSORS
from jaxcal.recording.types import Recording, _fail

ACC_NORM_G = (0.25, 4.0)  # median |f| of a resting or hand-held accelerometer, g
GYR_MEDIAN_MAX = 20.0  # rad/s (1150 deg/s): a median rate above this is a unit error
GYR_Q99_MAX = 35.0  # rad/s (2000 deg/s, the largest common full scale)


def implausible(sensor: str, x: np.ndarray, how: str) -> str | None:
    """What contradicts values ``x`` (N, 3) being in g (``acc``) or rad/s (``gyr``), or ``None``.

    The median ``|f|`` of a resting or hand-held accelerometer lies in :data:`ACC_NORM_G` (near 1 g);
    outside, the unit is off by a large factor (m/s^2 declared as g reads ~9.8). A median rate
    above :data:`GYR_MEDIAN_MAX` or a 99th percentile above :data:`GYR_Q99_MAX` (2000 deg/s) means
    deg/s declared as rad/s. ``how`` says where the values came from (e.g. "after unit conversion").

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        x: (N, 3) values, declared in g (``acc``) or rad/s (``gyr``).
        how: where the values came from, for the message.
    """
    with np.errstate(over="ignore", invalid="ignore"):  # huge values are refused elsewhere, with their row
        norm = np.linalg.norm(np.asarray(x, np.float64), axis=-1).ravel()
    norm = norm[np.isfinite(norm)]  # non-finite values are refused elsewhere, with their row
    if norm.size == 0:
        return None
    med = float(np.median(norm))
    if sensor == "acc":
        if ACC_NORM_G[0] <= med <= ACC_NORM_G[1]:
            return None
        hint = " (looks like m/s^2)" if 5.0 < med < 15.0 else ""
        return f"median |acc| is {med:.3g} g {how}, not near 1 g{hint}"
    q99 = float(np.quantile(norm, 0.99))
    if med > GYR_MEDIAN_MAX:
        return f"median |gyr| is {med:.3g} rad/s {how}, faster than any hand or rig turns (deg/s declared as rad/s?)"
    if q99 > GYR_Q99_MAX:
        return f"99th percentile of |gyr| is {q99:.3g} rad/s {how}, beyond 2000 deg/s (deg/s declared as rad/s?)"
    return None


_SCALE_KEY = {"acc": ("acc_lsb_per_g", "acc_bias_lsb"), "gyr": ("gyr_lsb_per_rads", "gyr_bias_lsb")}
_SENSOR_WORD = {"acc": "accelerometer", "gyr": "gyroscope"}


def _physical_values(rec: Recording, s: str) -> tuple[np.ndarray, str, str] | None:
    """Sensor ``s`` in g / rad/s with how it got there and what to blame, or ``None`` (raw counts
    without a datasheet scale cannot be judged)."""
    y = np.asarray(getattr(rec, s), np.float64)
    if getattr(rec, f"{s}_unit") == PHYS_UNIT[s]:
        return y, f"with {s}_unit = {PHYS_UNIT[s]!r}", f"the declared {_SENSOR_WORD[s]} unit is wrong"
    scale_key, bias_key = _SCALE_KEY[s]
    scale, bias = getattr(rec, scale_key), getattr(rec, bias_key)
    if scale is None:
        return None
    x = (y - np.asarray(0.0 if bias is None else bias, np.float64)) / np.asarray(scale, np.float64)
    return x, f"after the datasheet scale '{scale_key}'", f"the datasheet scale '{scale_key}' or the unit is wrong"


def check_plausible(rec: Recording, source: str = "") -> None:
    """Refuse declared units or datasheet scales that the data contradict (:func:`implausible`).

    Judges ``acc``/``gyr`` declared in g / rad/s, raw counts converted with the datasheet scale
    where the recording gives one, and the labels ``acc_ref`` (g) and ``gyr_ref`` (rad/s).
    Raises :class:`RecordingError` naming the key.

    Args:
        rec: the recording.
        source: prefix of the error message (e.g. the file); empty: none.
    """
    for s in SENSORS:
        got = None if getattr(rec, s) is None else _physical_values(rec, s)
        why = None if got is None else implausible(s, got[0], got[1])
        if why:
            raise _fail(source, f"key '{s}': {why}; {got[2]}")
    for s, key in (("acc", "acc_ref"), ("gyr", "gyr_ref")):
        x = getattr(rec, key)
        why = None if x is None else implausible(s, x, "in the labels")
        if why:
            raise _fail(source, f"key '{key}': {why}; labels must be in {PHYS_UNIT[s]}")
