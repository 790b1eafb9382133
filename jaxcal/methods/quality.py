"""Quality functions that methods declare on their :class:`~jaxcal.methods.base.Method` record
(``Method.quality``), for methods scored through their applied output; each returns
``(in_sample, held_out)`` :class:`~jaxcal.eval.scores.QualityRow`\\ s (``held_out`` ``None`` when
not asked for).

* :func:`refit_quality` (``linear``, ``cubic``): RMS against the labels, in-sample and on a
  validation split the method is refitted without;
* :func:`early_stopping_quality` (``nn``): RMS against the labels on the rows its early stopping
  held out (not refitted: minutes);
* :func:`seq_split_quality` (any method's model on a recording with ``seq`` ids; ``online-thesis``):
  :mod:`jaxcal.eval.seqsplit`'s time split, the method refitted on the first 80 % of the sequences.

The self-calibration methods' own quality lives in their modules
(:func:`jaxcal.methods.online.quality`, :func:`jaxcal.methods.multipos.quality`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from jaxcal.eval import seqsplit
from jaxcal.eval.scores import QualityRow
from jaxcal.methods.base import REF_KEY, Log, ModelError, datasheet_cals, holdout_mask, rms
from jaxcal.recording import Recording, take_rows

__all__ = ["QualityFn", "early_stopping_quality", "refit_quality", "seq_split_quality"]

QualityFn = Callable[..., tuple[QualityRow | None, QualityRow | None]]
"""``quality(rec, options, model, *, held_out=True, log=None) -> (in_sample, held_out)``: ``rec`` the
recording the model was fitted on, ``options`` the fit's options, ``model`` the fitted
:class:`~jaxcal.methods.CalibrationModel`, ``held_out`` whether to compute the held-out row (else
it is ``None``), ``log`` a progress sink or ``None``; the rows are
:class:`~jaxcal.eval.scores.QualityRow` (``None`` where not computed)."""

_RMS_KEY = {"acc": ("acc_rms_mg", 1e3), "gyr": ("gyr_rms_degs", 180.0 / math.pi)}


def _rms_entry(res: Mapping[str, float]) -> QualityRow:
    """``sensor -> rms`` (g, rad/s) as ``{"acc_rms_mg", "gyr_rms_degs"}``."""
    return {_RMS_KEY[s][0]: _RMS_KEY[s][1] * v for s, v in res.items()}  # type: ignore[return-value]


def _labelled(rec: Recording, options: Any, model: Any) -> tuple[float, np.ndarray, dict, list[str], dict]:
    """The validation share and mask (:func:`~jaxcal.methods.base.holdout_mask`), the model's
    output on ``rec``, the calibrated sensors and their labels."""
    fraction = float(getattr(options, "val_fraction", 0.15))
    val = holdout_mask(rec, fraction)
    out = model.apply(rec)
    sensors = [s for s in model.sensors if f"{s}_cal" in out]
    refs = {s: np.asarray(getattr(rec, REF_KEY[s]), np.float64) for s in sensors}
    return fraction, val, out, sensors, refs


def early_stopping_quality(rec: Recording, options: Any, model: Any, *, held_out: bool = True,
                           log: Log | None = None) -> tuple[QualityRow | None, QualityRow | None]:
    """In-sample and held-out RMS against the labels of a model trained with early stopping
    (``nn``), scored on the rows its early stopping held out (optimistic: they chose the epoch);
    not refitted (minutes). Nothing is computed when ``held_out`` is false.

    Args:
        rec: the labelled recording the model was fitted on.
        options: the fit's options (``val_fraction``).
        model: the fitted :class:`~jaxcal.methods.CalibrationModel`.
        held_out: compute the rows.
        log: progress sink (unused).
    """
    if not held_out:
        return None, None
    fraction, val, out, sensors, refs = _labelled(rec, options, model)
    ins = _rms_entry({s: rms((out[f"{s}_cal"] - refs[s])[~val]) for s in sensors})
    ho = _rms_entry({s: rms((out[f"{s}_cal"] - refs[s])[val]) for s in sensors})
    ho["how"] = f"the {int(val.sum())} rows ({fraction:.0%}) held out for early stopping (they chose the epoch)"
    return ins | {"how": "training rows"}, ho


def refit_quality(rec: Recording, options: Any, model: Any, *, held_out: bool = True,
                  log: Log | None = None) -> tuple[QualityRow | None, QualityRow | None]:
    """In-sample and held-out RMS against the labels of a labelled method's model, refitted on the
    rows :func:`~jaxcal.methods.base.holdout_mask` keeps (15 %, whole sequences when ``seq`` has 4
    or more) and scored on the others (``linear``, ``cubic``). Nothing is computed when
    ``held_out`` is false.

    Args:
        rec: the labelled recording the model was fitted on.
        options: the fit's options.
        model: the fitted :class:`~jaxcal.methods.CalibrationModel` (refitted by its method).
        held_out: compute the rows.
        log: progress sink, or ``None``.

    Returns:
        ``({"acc_rms_mg", "gyr_rms_degs", "how"}, the same with the held-out ``how``)`` for the
        fitted sensors.
    """
    from jaxcal import methods  # the registry imports this module

    if not held_out:
        return None, None
    fraction, val, out, sensors, refs = _labelled(rec, options, model)
    ins = _rms_entry({s: rms(out[f"{s}_cal"] - refs[s]) for s in sensors}) | {"how": "all rows"}
    if log is not None:
        log(f"held out: refitting {model.method} on {int((~val).sum())} rows, scoring {int(val.sum())} ...")
    sub = methods.fit(model.method, take_rows(rec, ~val), options)
    out_va = sub.apply(take_rows(rec, val))
    ho = _rms_entry({s: rms(out_va[f"{s}_cal"] - refs[s][val]) for s in sensors if f"{s}_cal" in out_va})
    what = "whole sequences" if rec.seq is not None and len(np.unique(rec.seq)) >= 4 else "every k-th row"
    ho["how"] = f"validation split: refitted on {int((~val).sum())} rows, scored on {int(val.sum())} ({what}, {fraction:.0%})"
    return ins, ho


def _applied(model: Any, rec: Recording, bounds: seqsplit.Bounds) -> seqsplit.Errors:
    """:func:`jaxcal.eval.seqsplit.applied_errors` of ``model``'s output on ``rec``."""
    out = model.apply(rec)
    if "acc_cal" not in out or "gyr_cal" not in out:
        raise ModelError("the sequences' score needs a model of both sensors")
    return seqsplit.applied_errors(out["acc_cal"], out["gyr_cal"], rec, bounds)


def seq_split_quality(rec: Recording, options: Any, model: Any, *, held_out: bool = True,
                      log: Log | None = None) -> tuple[QualityRow, QualityRow | None]:
    """In-sample and held-out quality of any method's model on a recording with ``seq`` ids, from
    its applied output (:mod:`jaxcal.eval.seqsplit`): each sequence by its first and last samples
    (``| |f| - 1 g |`` there, and the gravity carried from the first to the last). Held out: a time
    split, the model's method refitted on the first 80 % of the sequences and scored on the last
    20 %.

    Args:
        rec: the recording the model was fitted on (with ``seq``).
        options: the fit's options.
        model: the fitted :class:`~jaxcal.methods.CalibrationModel`.
        held_out: also compute the held-out row.
        log: progress sink, or ``None``.

    Returns:
        ``(in_sample, held_out)`` rows (``held_out`` ``None`` when not asked for).
    """
    from jaxcal import methods  # the registry imports this module

    method = model.method
    if rec.seq is None:
        raise ModelError(f"{method}: the sequences' score needs seq ids")

    def fit_score(train: seqsplit.Bounds, test: seqsplit.Bounds) -> seqsplit.Errors:
        cut, rows = test[0][0], np.arange(rec.n)
        if log is not None:
            log(f"held out: refitting {method} on the first {len(train)} sequences, scoring the last {len(test)} ...")
        sub = methods.fit(method, take_rows(rec, rows < cut), options)
        return _applied(sub, take_rows(rec, rows >= cut), [(a - cut, b - cut) for a, b in test])

    return seqsplit.time_split_rows(rec, held_out, lambda bounds: _applied(model, rec, bounds), fit_score, "refitted",
                                    datasheet_cals(rec))
