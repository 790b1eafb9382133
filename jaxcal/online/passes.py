"""Streaming passes of :mod:`jaxcal.online`'s filter: a batch of padded sequences
(:class:`SequenceBatch`), one ``lax.scan`` over them (:func:`online_scan`, :func:`online_pass`), and
the recording entry point :func:`fit_online_recording`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float, Int

from jaxcal.arrays import Array
from jaxcal.online.filter import Filter, OnlineHP, OnlineState, forward_models, make_filter
from jaxcal.precision import float64
from jaxcal.sensor import Diag, LinearCal
from jaxcal.sequences import pad_with_mask

__all__ = ["SequenceBatch", "spec_sequences", "online_scan", "online_scan_jit", "online_pass", "fit_online_recording"]

# ----------------------------------------------------------------------------------------------
# streaming passes
# ----------------------------------------------------------------------------------------------


class SequenceBatch(NamedTuple):
    """Sequences in spec-converted units, padded to a common length ``N`` with a mask (traced).

    ``weight`` and ``weight_t`` (optional; given together): each sample's residual weights along and
    across the predicted direction, apart from the mask (see :func:`_sequence_residuals`); a
    sequence whose weights are all 0 is skipped (no prediction, no update), so one batch of fixed
    shape serves every held-out fold (:mod:`jaxcal.field`).
    """

    u_acc: Float[Array, "M N 3"]
    u_gyr: Float[Array, "M N 3"]
    mask: Float[Array, "M N"]
    weight: Float[Array, "M N"] | None = None
    weight_t: Float[Array, "M N"] | None = None


def spec_sequences(acc: Float[Array, "M N 3"], gyr: Float[Array, "M N 3"], acc_spec: Diag, gyr_spec: Diag,
                   mask: Float[Array, "M N"] | None = None) -> SequenceBatch:
    """Spec-convert raw sequences (eq. 4.8) into a :class:`SequenceBatch`.

    Args:
        acc: (M, N, 3) raw accelerometer sequences (LSB).
        gyr: (M, N, 3) raw gyroscope sequences (LSB).
        acc_spec, gyr_spec: datasheet models (eq. 4.8).
        mask: (M, N) 1 on samples, 0 on padding; None: all ones.
    """
    if mask is None:
        mask = jnp.ones(acc.shape[:2], acc.dtype)
    return SequenceBatch((acc - acc_spec.b) / acc_spec.s, (gyr - gyr_spec.b) / gyr_spec.s, mask)


def _scan(filt: Filter, state0: OnlineState, batch: SequenceBatch, dt: float | Float[Array, ""],
          hp: OnlineHP) -> tuple[OnlineState, Float[Array, "M Q"]]:
    """``predict`` then ``update`` per sequence, in one ``lax.scan``."""

    if batch.weight is None:
        def step(state, seq):
            ua, ug, m = seq
            state = filt.update(filt.predict(state, hp), ua, ug, m, dt, hp)
            return state, state.theta

        return jax.lax.scan(step, state0, (batch.u_acc, batch.u_gyr, batch.mask))

    def weighted_step(state, seq):
        ua, ug, m, w, wt = seq
        new = filt.update(filt.predict(state, hp), ua, ug, m, dt, hp, w, wt)
        keep = jnp.any(w > 0)
        state = jax.tree_util.tree_map(lambda a, b: jnp.where(keep, a, b), new, state)
        return state, state.theta

    wt = batch.weight if batch.weight_t is None else batch.weight_t
    return jax.lax.scan(weighted_step, state0, (batch.u_acc, batch.u_gyr, batch.mask, batch.weight, wt))


def online_scan(
    state0: OnlineState, batch: SequenceBatch, dt: float | Float[Array, ""], hp: OnlineHP, kind: str
) -> tuple[OnlineState, Float[Array, "M Q"]]:
    """One streaming pass (pure): the final state and the estimate after every sequence (for
    convergence curves; not part of the state).

    Call under ``jit`` with ``kind`` static; everything else is traced (``vmap`` over ``hp`` runs
    several filters at once).

    Args:
        state0: initial state, e.g. ``make_filter(kind).init(hp, jnp.float64)``.
        batch: the sequences, spec-converted (:func:`spec_sequences`), visited in order.
        dt: sample period (s).
        hp: :class:`OnlineHP` (traced).
        kind: (static) ``"diag"`` or ``"affine"`` (:func:`make_filter`).
    """
    return _scan(make_filter(kind), state0, batch, dt, hp)


#: :func:`online_scan` compiled (``kind`` static), as :func:`online_pass` runs it.
online_scan_jit = jax.jit(online_scan, static_argnames=("kind",))


@float64
def online_pass(
    acc: Float[Array, "M N 3"],
    gyr: Float[Array, "M N 3"],
    dt: float | Float[Array, ""],
    acc_spec: Diag,
    gyr_spec: Diag,
    hp: OnlineHP = OnlineHP(),
    kind: str = "diag",
    mask: Float[Array, "M N"] | None = None,
) -> tuple[OnlineState, Float[Array, "M Q"]]:
    """Stream raw sequences (LSB) through the filter once, in float64 (one ``jit``; ``kind`` static).

    Args:
        acc, gyr: raw counts of ``M`` sequences of ``N`` samples, visited in order.
        dt: sample period (s).
        acc_spec, gyr_spec: datasheet models (initial point; eq. 4.8).
        hp: :class:`OnlineHP` (traced).
        kind: (static) ``"diag"`` or ``"affine"``.
        mask: optional (M, N) validity mask for padded sequences.

    Returns:
        Final :class:`OnlineState` and the estimate after each sequence, both float64 (use them
        inside ``jax.enable_x64(True)``; convert with :func:`to_linear_cal`).
    """
    f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    aspec = Diag(f64(acc_spec.s), f64(acc_spec.b))
    gspec = Diag(f64(gyr_spec.s), f64(gyr_spec.b))
    batch = spec_sequences(f64(acc), f64(gyr), aspec, gspec, None if mask is None else f64(mask))
    hp64 = OnlineHP(*[jnp.asarray(v) for v in hp])
    state0 = make_filter(kind).init(hp64, jnp.float64)
    return online_scan_jit(state0, batch, f64(dt), hp64, kind)


# ----------------------------------------------------------------------------------------------
# recordings (CLI entry point)
# ----------------------------------------------------------------------------------------------


@float64
def fit_online_recording(
    acc: Float[Array, "L 3"],
    gyr: Float[Array, "L 3"],
    seq: Int[Array, " L"],
    t_or_dt: Float[Array, " L"] | float,
    acc_spec: Diag | None,
    gyr_spec: Diag | None,
    hp: OnlineHP = OnlineHP(),
    kind: str = "affine",
) -> tuple[LinearCal, LinearCal]:
    """Self-calibrate a recording of rotation sequences without labels (method ``online``).

    Each contiguous run of equal ``seq`` is one sequence, rotated about the sensor's centre;
    sequences are padded to one length (:func:`jaxcal.sequences.pad_with_mask`) and streamed in
    order through :func:`online_pass`.

    Args:
        acc, gyr: raw outputs (LSB).
        seq: sequence ids (samples of one sequence contiguous).
        t_or_dt: sample times (s) or the sample period.
        acc_spec, gyr_spec: datasheet models. If ``None``: the accelerometer scale is the median
            norm of the raw output (bias 0); the gyroscope bias is the median raw output of the
            first and last samples of the sequences and its scale is the median ratio of the
            integrated raw rate to the angle between the first and last accelerometer readings.
        hp: :class:`OnlineHP` (the prior is widened to 0.3 relative when a spec is estimated).
        kind: ``"affine"`` (default) or ``"diag"``.

    Returns:
        ``(acc_cal, gyr_cal)``: :class:`~jaxcal.sensor.LinearCal` applied calibrations ``x = A (y - b)``
        (numpy float64; ``A`` is ``numpy.linalg.inv`` of the filter's forward ``S``).
    """
    acc = np.asarray(acc, np.float64)
    gyr = np.asarray(gyr, np.float64)
    if np.ndim(t_or_dt) == 0:
        dt = float(t_or_dt)
    else:
        dt = float(np.median(np.diff(np.asarray(t_or_dt, np.float64))))
    pa, mk = pad_with_mask(acc, seq)
    pg, _ = pad_with_mask(gyr, seq)
    lengths = mk.sum(1).astype(int)
    if acc_spec is None:
        s = float(np.median(np.linalg.norm(acc, axis=1)))
        acc_spec = Diag(np.full(3, s), np.zeros(3))
        hp = hp._replace(prior_scale=max(float(hp.prior_scale), 0.3), prior_acc_bias=max(float(hp.prior_acc_bias), 0.3))
    if gyr_spec is None:
        ends = np.concatenate([pg[:, 0], pg[np.arange(len(pg)), lengths - 1]])
        b = np.median(ends, axis=0)
        ua = (pa - np.asarray(acc_spec.b)) / np.asarray(acc_spec.s)
        a1 = ua[:, 0]
        an = ua[np.arange(len(ua)), lengths - 1]
        cosang = np.sum(a1 * an, 1) / (np.linalg.norm(a1, axis=1) * np.linalg.norm(an, axis=1))
        ang = np.arccos(np.clip(cosang, -1.0, 1.0))
        raw_ang = np.linalg.norm(((pg - b) * mk[..., None]).sum(1) * dt, axis=1)
        ok = ang > 0.05
        scale = float(np.median(raw_ang[ok] / ang[ok])) if np.any(ok) else 1.0
        gyr_spec = Diag(np.full(3, scale), b)
        hp = hp._replace(prior_scale=max(float(hp.prior_scale), 0.3), prior_gyr_bias=max(float(hp.prior_gyr_bias), 0.3))
    state, _ = online_pass(pa, pg, dt, acc_spec, gyr_spec, hp, kind, mask=mk)
    f64 = lambda x: jnp.asarray(x, jnp.float64)  # noqa: E731
    models = forward_models(make_filter(kind), state.theta, Diag(f64(acc_spec.s), f64(acc_spec.b)),
                             Diag(f64(gyr_spec.s), f64(gyr_spec.b)))
    am, gm = (LinearCal(np.linalg.inv(np.asarray(m.S)), np.asarray(m.b)) for m in models)
    return am, gm
