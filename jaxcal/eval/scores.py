"""Scores of linear calibrations on static poses and the motions between them.

Accelerometer: per static pose, ``| |A_a (y - b_a)| - 1 |`` in g (the pose mean, so sensor noise
averages out). Gyroscope: per transition between consecutive poses, the angle between the gravity
direction of pose ``j`` carried by the integrated gyro (physical convention ``f_next = R^T f_prev``)
and the gravity direction measured in pose ``j + 1`` (rad; NaN where the transition is unusable,
e.g. a saturated gyro). :func:`score_cal` is the one scorer of a calibration pair (with the
gyroscope's g-sensitivity ``G`` where it has one); every score row is built from its per-item errors.

Two renderings of the same errors:

- :class:`QualityRow` (:func:`quality_row`): the row every method's quality reports (``jaxcal
  calibrate``'s ``in_sample`` / ``held_out`` metadata, CONVENTIONS.md "Model files"): RMS over the
  scored poses (mg) and the median over the scored transitions (deg), with what was scored.
- :func:`summarise`: the experiments' report row (means, maxima, counts), plus the per-item errors
  under ``_acc_err`` / ``_gyr_err`` (keys starting with ``_`` are not for reports).
"""

from __future__ import annotations

from typing import Any, TypedDict

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal import compare
from jaxcal import multipos as mp
from jaxcal.precision import float64
from jaxcal.sensor import LinearCal

__all__ = ["QualityRow", "quality_row", "summarise", "score_cal", "score_fixed", "score_heldout", "score_insample", "fair_row", "paired_with_peer",
           "public"]


class QualityRow(TypedDict, total=False):
    """A method's quality row (``in_sample`` / ``held_out`` of a model's metadata); every key optional.

    Args:
        acc_rms_mg: accelerometer error RMS (mg): ``| |f| - 1 g |`` over scored poses (rests), or
            against the labels for a labelled method.
        gyr_median_deg: median carried-gravity angle over the scored transitions (deg).
        gyr_rms_degs: gyroscope error RMS against the labels (deg/s), labelled methods.
        how: what was scored (and held out).
        initial_guess: the same items scored with the fit's starting point (a :class:`QualityRow`).
        not_held_out: items left unscored because their fold was undetermined.
        without_g_sensitivity: the same figure fitted without the gyro's g-sensitivity.
        bias_sd: the fitted biases' standard errors in the model's input units (``{"acc": [3] or
            None, "gyr": [3] or None, "how": str}``), from the held-out folds (``multipos``).
        fold_cals: the held-out folds' calibrations (``multipos``), which the exports' standard
            errors are built from (:func:`jaxcal.methods.multipos.fold_cals`).
        error: why the row could not be computed (the other keys absent).
        skipped: why the row was not computed.
    """

    acc_rms_mg: float | None
    gyr_median_deg: float | None
    gyr_rms_degs: float
    how: str
    initial_guess: Any
    not_held_out: dict
    without_g_sensitivity: Any
    bias_sd: dict
    fold_cals: dict
    error: str
    skipped: str


def quality_row(ea: np.ndarray, eg: np.ndarray, how: str) -> QualityRow:
    """The :class:`QualityRow` of per-pose errors ``ea`` (g, every one scored: the caller picks
    them) and per-transition angles ``eg`` (rad; non-finite ones are not scored).

    Args:
        ea: (P,) ``| |f| - 1 |`` of the scored poses, in g; ``acc_rms_mg`` ``None`` when empty.
        eg: (J,) carried-gravity angles, in rad; ``gyr_median_deg`` ``None`` when none is finite.
        how: what was scored.
    """
    ea = np.asarray(ea)
    eg = np.asarray(eg)
    eg = eg[np.isfinite(eg)]
    return {"acc_rms_mg": float(1e3 * np.sqrt(np.mean(ea**2))) if ea.size else None,
            "gyr_median_deg": float(np.degrees(np.median(eg))) if eg.size else None, "how": how}


def summarise(ea: np.ndarray, eg: np.ndarray, scored: str) -> dict:
    """A score row from per-pose accelerometer errors ``ea`` (g) and per-transition gyro angles ``eg``
    (rad, NaN = not scored).

    Args:
        ea: (P,) ``| |f| - 1 |`` per scored pose, in g.
        eg: (J,) carried-gravity angle per transition, in rad; NaN where not scored.
        scored: what the row was scored on (held out, in-sample, ...), kept in the row.
    """
    egd = np.degrees(eg)
    return {
        "acc_mean_mg": float(1e3 * np.mean(ea)),
        "acc_rms_mg": float(1e3 * np.sqrt(np.mean(ea**2))),
        "acc_max_mg": float(1e3 * np.max(ea)),
        "gyr_mean_deg": float(np.nanmean(egd)) if np.isfinite(egd).any() else None,
        "gyr_median_deg": float(np.nanmedian(egd)) if np.isfinite(egd).any() else None,
        "n_poses": int(len(ea)),
        "n_transitions": int(np.isfinite(egd).sum()),
        "scored": scored,
        "_acc_err": ea,
        "_gyr_err": eg,
    }


@float64
def score_cal(acc: LinearCal, gyr: LinearCal, data: mp.MultiposData,
              G: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose ``|f|`` errors and per-transition carried-gravity angles (NaN where ``data.seg_ok`` is
    false) of a given calibration pair, in float64.

    Args:
        acc: accelerometer calibration (applied form; ``1 g`` = the unit the errors are in).
        gyr: gyroscope calibration (applied form, to rad/s).
        data: prepared poses and transitions (:func:`jaxcal.multipos.prepare`).
        G: (3, 3) the gyroscope's g-sensitivity ((rad/s)/g: ``w = A_g (y_g - b_g) - G f``, ``f``
            the calibrated accelerometer); ``None``: zero.
    """
    d = jax.tree_util.tree_map(jnp.asarray, data)
    a = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float64), acc)
    g = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float64), gyr)
    gs = jnp.zeros((3, 3)) if G is None else jnp.asarray(G, jnp.float64)
    ea = np.asarray(mp.acc_norm_errors(a, d.pose_acc))
    eg = np.asarray(mp.gyro_angle_errors_jit(g, gs, a, d))
    return ea, np.where(np.asarray(data.seg_ok, bool), eg, np.nan)


def score_fixed(acc: LinearCal, gyr: LinearCal, data: mp.MultiposData) -> dict:
    """The row of a calibration fixed in advance (nothing fitted on this recording): every pose scored.

    Args:
        acc, gyr: the calibration pair (applied form).
        data: prepared poses and transitions (:func:`jaxcal.multipos.prepare`).
    """
    return summarise(*score_cal(acc, gyr, data), "all poses (nothing fitted)")


def score_heldout(data: mp.MultiposData, config: mp.MultiposConfig, n_folds: int | None) -> dict:
    """The row of multipos fitted and scored leave-poses-out (:func:`jaxcal.multipos.leave_poses_out`).

    Args:
        data: prepared poses and transitions.
        config: multipos configuration (static: one compile per configuration).
        n_folds: interleaved pose folds; ``None`` leaves one pose out at a time.
    """
    h = mp.leave_poses_out(data, config, n_folds)
    return summarise(h.acc_err, h.gyr_err, f"held out ({'leave-one-pose-out' if n_folds is None else f'{n_folds} interleaved folds'})")


@float64
def score_insample(data: mp.MultiposData, config: mp.MultiposConfig) -> dict:
    """The row of multipos fitted on every pose and scored on the same poses (labelled IN-SAMPLE).

    Args:
        data: prepared poses and transitions (numpy, :func:`jaxcal.multipos.prepare`).
        config: :class:`~jaxcal.multipos.MultiposConfig` (static: a new config recompiles).
    """
    d = jax.tree_util.tree_map(jnp.asarray, data)
    fit = mp.fit_prepared_numpy(data, config)  # the compiled fit the other callers share
    ea = np.asarray(mp.acc_norm_errors(fit.acc, d.pose_acc))
    eg = np.asarray(mp.gyro_angle_errors_jit(fit.gyr, fit.gsens, fit.acc, d))
    return summarise(ea, np.where(np.asarray(data.seg_ok), eg, np.nan), "IN-SAMPLE (fitted on all poses)")


def fair_row(parts: list, scored: str) -> dict:
    """The row of a time-split comparison: ``parts`` holds one ``(acc_err, gyr_err, turn_err)`` per fold
    (see :mod:`jaxcal.eval.heldout`); adds the closure error of the 360 deg turns (deg).

    Args:
        parts: one ``(acc_err, gyr_err, turn_err)`` per fold.
        scored: what the row was scored on, kept in the row.
    """
    ea, eg, ek = (np.concatenate(x) for x in zip(*parts))
    r = summarise(ea, eg, scored)
    r["turn_mean_deg"] = float(np.degrees(np.mean(ek)))
    r["turn_max_deg"] = float(np.degrees(np.max(ek)))
    r["n_turns"] = int(len(ek))
    r["_turn_err"] = ek
    return r


def paired_with_peer(rows: dict, peer: str, gyr_items=None, seed: int = 100, also: tuple[str, ...] = ()) -> dict:
    """:func:`jaxcal.compare.paired_comparison` of every held-out jaxcal multipos row, and of the rows
    named in ``also``, with the row ``peer`` (same items).

    Args:
        rows: score rows by name (rows whose name starts with ``jaxcal multipos`` and is not in-sample
            are compared).
        peer: name of the row to compare with.
        gyr_items: ``f(errors_rad) -> errors_deg`` giving the gyro items (e.g. two folds averaged);
            by default one item per scored transition. Items either row left unscored (NaN) are dropped.
        seed: PRNG seed of the bootstrap (row ``k`` uses ``PRNGKey(seed + k)``; the ``also`` rows
            come after the multipos rows, so adding one leaves their draws as they were).
        also: names of further held-out rows to compare (e.g. another method's on the same items).
    """
    ref = rows[peer]
    items = gyr_items or (lambda e: np.degrees(np.asarray(e)))
    gp = items(ref["_gyr_err"])
    out = {}
    names = [n for n in rows if n.startswith("jaxcal multipos") and "in-sample" not in n.lower()]
    for k, (n, r) in enumerate((n, rows[n]) for n in names + [n for n in also if n in rows and n not in names]):
        ka, kg = jax.random.split(jax.random.PRNGKey(seed + k))
        gj = items(r["_gyr_err"])
        fin = np.isfinite(gp) & np.isfinite(gj)
        a = compare.paired_comparison(r["_acc_err"], ref["_acc_err"], ka)
        g = compare.paired_comparison(gj[fin], gp[fin], kg)
        out[n] = {"acc": a._asdict() | {"verdict": a.verdict()},
                  "gyr": g._asdict() | {"verdict": g.verdict(), "verdict_median": g.verdict("median")}}
    return out


def public(x):
    """A copy of nested result dicts without the ``_``-prefixed keys, numpy scalars as Python numbers."""
    if isinstance(x, dict):
        return {k: public(v) for k, v in x.items() if not k.startswith("_")}
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x
