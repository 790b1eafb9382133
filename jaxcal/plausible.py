"""Plausibility of applying a model to a recording: is the recording inside what the model saw?

A model is valid where it was fitted. ``apply`` used to extrapolate without a word: a ``cubic``
model fitted on poses within 18 deg of z-up, applied over the sphere, was off by 1281 g on average;
a temperature model fed Kelvin as degC; a time offset longer than the recording. Each check here
returns sentences (empty: plausible); ``jaxcal apply`` refuses on any (or, with
``--allow-extrapolation``, prints them as warnings). Pure: a model and a recording in, strings out.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from jaxcal.recording import Recording

__all__ = ["OUTSIDE_FRACTION", "RANGE_MARGIN", "TEMP_MARGIN_DEGC", "apply_range_problems"]

OUTSIDE_FRACTION = 0.01  # more than this share of samples outside a model's range is refused
RANGE_MARGIN = 0.1  # a cubic model's input range widened by this share of its span on each side
TEMP_MARGIN_DEGC = 15.0  # the fitted temperature range widened by this on each side


def _axis(i: int) -> str:
    return "xyz"[i]


def _cubic(s: str, p: Mapping[str, Any], y: np.ndarray, unit: str) -> str | None:
    b = p.get("bounds") if isinstance(p, Mapping) else None
    if not isinstance(b, Mapping) or "lo" not in b or "hi" not in b:
        return None
    lo, hi = np.asarray(b["lo"], np.float64), np.asarray(b["hi"], np.float64)
    span = np.abs(hi - lo)
    lo_w, hi_w = np.minimum(lo, hi) - RANGE_MARGIN * span, np.maximum(lo, hi) + RANGE_MARGIN * span
    out = (y < lo_w) | (y > hi_w)
    frac = float(np.mean(out.any(axis=1)))
    if frac <= OUTSIDE_FRACTION:
        return None
    c = int(np.argmax(out.mean(axis=0)))
    return (f"{s}: {100 * frac:.1f} % of the samples lie outside the cubic model's fitted input range (axis {_axis(c)}: "
            f"{min(lo[c], hi[c]):.4g} to {max(lo[c], hi[c]):.4g} {unit}, the recording {y[:, c].min():.4g} to "
            f"{y[:, c].max():.4g}); a polynomial extrapolates wildly there: fit it on data that covers these inputs")


def _temperature(s: str, meta: Mapping[str, Any], rec: Recording) -> str | None:
    rng = (meta.get("temperature_range_degC") or {}).get(s) if isinstance(meta.get("temperature_range_degC"), Mapping) else None
    if rng is None or rec.temp is None:
        return None
    t0, t1 = float(min(rng)), float(max(rng))
    T = np.asarray(rec.temp, np.float64)
    out = (T < t0 - TEMP_MARGIN_DEGC) | (T > t1 + TEMP_MARGIN_DEGC)
    if float(np.mean(out)) <= OUTSIDE_FRACTION:
        return None
    hint = " (Kelvin read as degC?)" if np.median(T) > 200.0 and t1 < 150.0 else ""
    return (f"{s}: the recording's temperature {T.min():.4g} to {T.max():.4g} degC lies outside the model's fitted "
            f"{t0:.4g} to {t1:.4g} degC (+- {TEMP_MARGIN_DEGC:g}){hint}; its temperature terms would extrapolate")


def _time_offset(s: str, p: Mapping[str, Any], rec: Recording) -> str | None:
    if "time_offset" not in p:
        return None
    tau = float(np.asarray(p["time_offset"], np.float64))
    t = np.asarray(rec.t, np.float64)
    dur = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    if abs(tau) < 0.5 * dur:
        return None
    return (f"{s}: the model's time offset {tau:.4g} s is not short against the {dur:.4g} s recording (at most half of it); "
            "shifting by it would hold the edge samples over most of the output")


def apply_range_problems(method: str, state: Mapping[str, Any], meta: Mapping[str, Any], rec: Recording) -> list[str]:
    """Why applying a model to ``rec`` would extrapolate, one sentence each (empty: inside its range).

    Checked: a ``cubic`` model's stored input bounds (more than :data:`OUTSIDE_FRACTION` of the
    samples beyond the range widened by :data:`RANGE_MARGIN` of its span), a ``diagnosed`` model's
    fitted temperature range (``meta["temperature_range_degC"]``, widened by
    :data:`TEMP_MARGIN_DEGC`) and its time offset (at most half the recording).

    Args:
        method: the model's method name.
        state: the model's state (``sensor -> parameters``).
        meta: the model's metadata (``units``, ``temperature_range_degC``).
        rec: the recording it is to be applied to.
    """
    out: list[str] = []
    units = meta.get("units") if isinstance(meta.get("units"), Mapping) else {}
    for s, p in state.items():
        if not isinstance(p, Mapping):
            continue
        y = getattr(rec, s, None)
        if method == "cubic" and y is not None:
            why = _cubic(s, p, np.asarray(y, np.float64), str(units.get(s, "")))
            if why:
                out.append(why)
        if method == "diagnosed":
            for why in (_temperature(s, meta, rec), _time_offset(s, p, rec)):
                if why:
                    out.append(why)
    return out
