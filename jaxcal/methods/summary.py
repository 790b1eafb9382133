"""What ``jaxcal calibrate`` reports about a fitted model: its parameters in familiar units and its
quality in-sample and held out.

* :func:`linear_parameters`: a forward affine model ``y = S x + b`` as bias (mg, deg/s), scale
  factor (ppm and % from the nominal/datasheet scale), misalignment and non-orthogonality (mrad).
* :func:`describe`: the ``parameters`` / ``in_sample`` / ``held_out`` metadata entries of any
  registered method's model (CONVENTIONS.md, "Model files"); :func:`summary_lines` prints them.

The quality rows are the method's own: each :class:`~jaxcal.methods.base.Method` declares its
``quality`` (:mod:`jaxcal.methods.quality` for the methods scored through their applied output,
:func:`jaxcal.methods.online.quality`, :func:`jaxcal.methods.multipos.quality`), scored through
:mod:`jaxcal.eval`; a method without one has no built-in held-out score.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from jaxcal.constants import SENSORS
from jaxcal.methods.base import GSENS_KEY, Log, ModelError, recording_spec
from jaxcal.recording import Recording

__all__ = ["contradiction", "describe", "linear_parameters", "quality_text", "summary_lines"]

_BIAS_UNIT = {"acc": ("mg", 1e3), "gyr": ("deg/s", 180.0 / math.pi)}


def linear_parameters(S: np.ndarray, b: np.ndarray, sensor: str, nominal: np.ndarray | None,
                      recorded_unit: str | None = None) -> dict[str, Any]:
    """A forward affine model ``y = S x + b`` (``y`` recorded, ``x`` in g or rad/s) in familiar units.

    * ``bias``: the input-referred bias ``S^-1 b`` in mg (acc) or deg/s (gyr), per axis; with
      ``recorded_unit`` ``"LSB"`` also ``offset_lsb``, ``b`` itself (e.g. ~32768 for unsigned counts);
    * ``scale``: each axis's sensitivity ``|S[i, :]|`` (recorded unit per g or rad/s);
      ``scale_ppm`` / ``scale_pct``: its deviation from ``nominal`` (datasheet; 1 in physical units),
      absent without a nominal;
    * ``misalignment_mrad``: (3, 3) the row-normalised ``S`` minus the identity (small angles: entry
      ``[i, j]`` is how far axis ``i`` leans towards ``j``), in mrad;
    * ``nonorthogonality_mrad``: ``{"xy", "xz", "yz"}``: 90 deg minus the angle between two sensitive
      axes, in mrad.

    Args:
        S: (3, 3) forward matrix.
        b: (3,) forward bias (recorded unit).
        sensor: ``"acc"`` or ``"gyr"``.
        nominal: (3,) or () nominal scale (recorded unit per g or rad/s), or ``None``.
        recorded_unit: the recording's unit of ``sensor`` (``"LSB"`` adds ``offset_lsb``), or ``None``.
    """
    S = np.asarray(S, np.float64)
    b = np.asarray(b, np.float64)
    unit, k = _BIAS_UNIT[sensor]
    scale = np.linalg.norm(S, axis=1)
    u = S / scale[:, None]
    out: dict[str, Any] = {
        "bias_unit": unit,
        "bias": (k * np.linalg.solve(S, b)).tolist(),
        "scale": scale.tolist(),
        "misalignment_mrad": (1e3 * (u - np.eye(3))).tolist(),
        "nonorthogonality_mrad": {f"{'xyz'[i]}{'xyz'[j]}": float(1e3 * np.arcsin(np.clip(u[i] @ u[j], -1, 1)))
                                  for i, j in ((0, 1), (0, 2), (1, 2))},
    }
    if recorded_unit == "LSB":
        out["offset_lsb"] = b.tolist()
    if nominal is not None:
        dev = scale / np.broadcast_to(np.asarray(nominal, np.float64), (3,)) - 1.0
        out["scale_ppm"] = (1e6 * dev).tolist()
        out["scale_pct"] = (1e2 * dev).tolist()
    return out


def _nominal(rec: Recording, sensor: str) -> np.ndarray | None:
    spec = recording_spec(rec, sensor)
    return None if spec is None else np.asarray(spec.s, np.float64)


def describe(method: str, rec: Recording, options: Any, model: Any, log: Log, *, held_out: bool = True) -> dict[str, Any]:
    """The metadata entries ``parameters``, ``in_sample`` and ``held_out`` of a fitted model.

    Args:
        method: the registered method's name.
        rec: the recording the model was fitted on.
        options: the fit's options.
        model: the fitted :class:`~jaxcal.methods.CalibrationModel`.
        log: progress sink.
        held_out: compute the held-out figure (a refit or folds: seconds); ``False``: skip it.

    Returns:
        ``{"parameters": {sensor: ...}, "in_sample": {...}, "held_out": {...}}``; ``parameters``
        only for linear-state models (``S``, ``b`` per sensor); ``held_out`` holds ``error`` when it
        cannot be computed, ``skipped`` when not asked for.
    """
    from jaxcal import methods  # the registry imports this module

    params = {}
    for s in SENSORS:
        st = model.state.get(s)
        if isinstance(st, Mapping) and "S" in st and "b" in st:
            params[s] = linear_parameters(st["S"], st["b"], s, _nominal(rec, s), getattr(rec, f"{s}_unit"))
            if s == "gyr" and GSENS_KEY in st:
                params[s]["g_sensitivity_degs_per_g"] = np.degrees(np.asarray(st[GSENS_KEY], np.float64)).tolist()
    out: dict[str, Any] = {"parameters": params} if params else {}
    try:
        quality = methods.get(method).quality
        if quality is None:
            ho = {"error": f"no built-in held-out score for '{method}'"} if held_out else None
        else:
            ins, ho = quality(rec, options, model, held_out=held_out, log=log)
            if ins is not None:
                out["in_sample"] = ins
    except ModelError as e:
        ho = {"error": str(e)}
    out["held_out"] = ho if held_out else {"skipped": "not asked for, --no-held-out"}
    if out["held_out"] is None:
        out["held_out"] = {"error": "not computed"}
    return out


_G_GAIN = 0.05  # a G fit must cut the held-out carried-gravity median by 5 % to count as an improvement


# A held-out figure this much worse than the initial guess the method started from (ratio, plus an
# absolute slack for figures at the noise floor) means the method diverged or made things worse.
WORSE_RATIO = {"acc_rms_mg": (1.25, 0.05), "gyr_median_deg": (1.25, 0.05)}
# A scale this far (relative) from the datasheet/nominal one is no calibration of this part.
SCALE_PLAUSIBLE_REL = 0.5


def contradiction(desc: Mapping[str, Any]) -> str | None:
    """Why a fitted model must not be written, in one line, or ``None``: its held-out figure worse
    than the starting point it was fitted from, scored on the same held-out items
    (:data:`WORSE_RATIO`; ``held_out.initial_guess``: ``online`` between rests, its initial
    calibration from the rests; the ``seq`` methods, the datasheet values), a non-finite held-out
    figure, or a scale more than
    :data:`SCALE_PLAUSIBLE_REL` from the datasheet's (e.g. 1700x the part's nominal).

    Args:
        desc: :func:`describe`'s result.
    """
    for s, p in desc.get("parameters", {}).items():
        pct = p.get("scale_pct")
        if pct is not None and np.max(np.abs(np.asarray(pct, np.float64))) > 100 * SCALE_PLAUSIBLE_REL:
            return (f"the {s} scale is {_fmt3(np.asarray(pct) / 100 + 1, '.4g')} times the datasheet's: no calibration "
                    "of this part (wrong datasheet values, or the fit diverged)")
    ho = desc.get("held_out") or {}
    for k in ("acc_rms_mg", "gyr_median_deg"):
        if k in ho and ho[k] is not None and not math.isfinite(float(ho[k])):
            return f"the held-out {k} is not finite: the fit diverged"
    init = ho.get("initial_guess")
    if isinstance(init, Mapping):
        for k, (ratio, slack) in WORSE_RATIO.items():
            v, v0 = ho.get(k), init.get(k)
            if v is not None and v0 is not None and v > ratio * v0 + slack:
                return (f"the held-out {k} {v:.3f} is worse than its own starting point's {v0:.3f} on the same items "
                        f"({init.get('how', 'initial guess')}): the fit made the calibration worse")
    return None


def _fmt3(v: Any, f: str = "+.3f") -> str:
    return "[" + ", ".join(format(float(x), f) for x in v) + "]"


def quality_text(q: Mapping[str, Any]) -> str:
    if "error" in q:
        return f"not available ({q['error']})"
    if "skipped" in q:
        return f"skipped ({q['skipped']})"
    names = {"acc_rms_mg": ("acc RMS", "mg"), "gyr_rms_degs": ("gyr RMS", "deg/s"),
             "gyr_median_deg": ("carried-gravity median", "deg")}
    parts = [f"{names[k][0]} {q[k]:.3f} {names[k][1]}" for k in names if q.get(k) is not None]
    if q.get("acc_rms_mg") is not None and "gyr_rms_degs" not in q and "gyr_median_deg" in q:
        parts[0] = parts[0].replace("acc RMS", "acc | |f| - 1 g | RMS")
    return ", ".join(parts) + (f" ({q['how']})" if q.get("how") else "")


def summary_lines(desc: Mapping[str, Any]) -> list[str]:
    """Human-readable lines of :func:`describe`'s result (what ``jaxcal calibrate`` prints).

    Args:
        desc: :func:`describe`'s result.
    """
    lines = []
    for s, p in desc.get("parameters", {}).items():
        scale = (f"scale deviation {_fmt3(p['scale_ppm'], '+.0f')} ppm ({_fmt3(p['scale_pct'], '+.3f')} %)"
                 if "scale_ppm" in p else f"scale {_fmt3(p['scale'], '.6g')} per {'g' if s == 'acc' else 'rad/s'}")
        mis = np.asarray(p["misalignment_mrad"])
        off = [mis[i, j] for i in range(3) for j in range(3) if i != j]
        no = p["nonorthogonality_mrad"]
        offset = f" (offset {_fmt3(p['offset_lsb'], '.1f')} LSB)" if "offset_lsb" in p else ""
        lines.append(f"{s}: bias {_fmt3(p['bias'])} {p['bias_unit']}{offset}; {scale}")
        lines.append(f"{s}: misalignment xy xz yx yz zx zy {_fmt3(off, '+.2f')} mrad; non-orthogonality "
                     f"xy {no['xy']:+.2f}, xz {no['xz']:+.2f}, yz {no['yz']:+.2f} mrad")
        if "g_sensitivity_degs_per_g" in p:
            rows = "; ".join(_fmt3(row, "+.4f") for row in p["g_sensitivity_degs_per_g"])
            lines.append(f"{s}: g-sensitivity G rows {rows} (deg/s)/g")
    if "in_sample" in desc:
        lines.append(f"in-sample: {quality_text(desc['in_sample'])}")
    if "held_out" in desc:
        ho = desc["held_out"]
        lines.append(f"held out: {quality_text(ho)}")
        if isinstance(ho.get("initial_guess"), Mapping):
            lines.append(f"held out, initial guess: {quality_text(ho['initial_guess'])}")
        plain = ho.get("without_g_sensitivity")
        if plain is not None:
            lines.append(f"held out without --g-sensitivity: {quality_text(plain)}")
            with_g, without = ho.get("gyr_median_deg"), plain.get("gyr_median_deg")
            if with_g is not None and without is not None and with_g > (1.0 - _G_GAIN) * without:
                verdict = "worse" if with_g > (1.0 + _G_GAIN) * without else f"no better (within {_G_GAIN:.0%})"
                lines.append(f"note: G left the held-out carried-gravity median {verdict}: {with_g:.3f} deg against "
                             f"{without:.3f} deg without it; this session does not support fitting G: drop "
                             "--g-sensitivity, or record more poses and rotations (README, recording protocol)")
    return lines
