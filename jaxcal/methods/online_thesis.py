"""Method ``online-thesis``: thesis chapter 4 as published (two 3-5-10-5-3 networks
self-calibrated on rotation sequences, :func:`jaxcal.online_thesis.fit_online_thesis_recording`);
needs ``seq`` ids and datasheet values, no labels."""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal.constants import ACC_RANGE_G, GYR_RANGE_RADS, SENSORS
from jaxcal.methods.base import (
    SHARED_FLAGS,
    Fitted,
    Log,
    Method,
    ModelError,
    recording_dt,
    recording_spec,
    require_both,
    require_spec,
    sequences_of,
    units,
)
from jaxcal.methods.quality import seq_split_quality
from jaxcal.online_thesis import calibrate_acc, calibrate_gyr, fit_online_thesis_recording
from jaxcal.recording import Recording, sequence_slices
from jaxcal.sensor import Diag

__all__ = ["METHOD", "OnlineThesisOptions", "OnlineThesisState", "apply", "fit", "quality"]


class OnlineThesisOptions(NamedTuple):
    """Options of ``online-thesis`` (static: plain Python values).

    Args:
        seed: PRNG seed (initial weights and the training order's randomness).
    """

    seed: int = 0

    FLAGS = {"seed": SHARED_FLAGS["seed"]}


class OnlineThesisState(NamedTuple):
    """One sensor's stored state (``state/<sensor>/params/...``, ``state/<sensor>/spec/{s,b}``).

    Args:
        params: the network's flax parameters.
        spec: the datasheet model of the eq. 3.6 bounds (float64 on file).
    """

    params: Any
    spec: Diag


def fit(rec: Recording, options: OnlineThesisOptions, log: Log) -> Fitted:
    """Run the published online algorithm on the recording's rotation sequences.

    Args:
        rec: a recording with ``acc``, ``gyr``, ``seq`` ids of equal length and datasheet scales.
        options: :class:`OnlineThesisOptions`.
        log: progress sink.
    """
    require_both(rec, "online-thesis")
    spec_from = "metadata"
    if rec.seq is None:  # rests between motions: the thesis's sequences cut from them
        from jaxcal.methods.online import rest_seq_recording

        if recording_spec(rec, "acc") is None or recording_spec(rec, "gyr") is None:
            spec_from = "rests (no datasheet values: the diagonal of the initial calibration from the rests)"
        rec = rest_seq_recording(rec)
        log(f"online-thesis: no 'seq' ids: {len(sequence_slices(rec))} sequences cut between rests, made equally "
            "long with the next rest's samples")
    seq = sequences_of(rec, "online-thesis")
    acc_spec = require_spec(rec, "acc", "online-thesis")
    gyr_spec = require_spec(rec, "gyr", "online-thesis")
    dt = recording_dt(rec)
    n_seq = len(sequence_slices(rec))
    log(f"fitting online-thesis on {n_seq} sequences ({rec.n} samples, dt {dt:g} s) ...")
    t0 = time.perf_counter()
    try:
        res = fit_online_thesis_recording(
            np.asarray(rec.acc, np.float32), np.asarray(rec.gyr, np.float32), seq, dt,
            acc_spec, gyr_spec, jax.random.PRNGKey(options.seed), None,
        )
        jax.block_until_ready(res.acc_params)
    except ValueError as e:  # e.g. sequences of unequal length
        raise ModelError(f"online-thesis: {e}") from None
    elapsed = time.perf_counter() - t0
    log(f"fitting online-thesis ... done in {elapsed:.1f} s")
    f64 = lambda d: Diag(np.asarray(d.s, np.float64), np.asarray(d.b, np.float64))  # noqa: E731
    state = {
        "acc": OnlineThesisState(res.acc_params, f64(acc_spec)),
        "gyr": OnlineThesisState(res.gyr_params, f64(gyr_spec)),
    }
    meta = {
        "units": units(rec, SENSORS),
        "seed": int(options.seed),
        "n_sequences": n_seq,
        "dt": dt,
        "fit_seconds": elapsed,
        "spec_from": spec_from,
        "acc_range": float(ACC_RANGE_G),
        "gyr_range": float(GYR_RANGE_RADS),
    }
    return Fitted(SENSORS, state, meta)


def _thesis_state(p: Mapping[str, Any]) -> OnlineThesisState:
    """A stored sensor state as float32 :class:`OnlineThesisState`."""
    params = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), dict(p["params"]))
    return OnlineThesisState(params, Diag(*(jnp.asarray(p["spec"][k], jnp.float32) for k in Diag._fields)))


def apply(state: Mapping[str, Any], meta: Mapping[str, Any], rec: Recording) -> dict[str, np.ndarray]:
    """Calibrate with the stored networks (:func:`~jaxcal.online_thesis.calibrate_acc` / ``_gyr``).

    Args:
        state: ``sensor -> {"params", "spec"}``.
        meta: the fit's metadata (``acc_range``, ``gyr_range``: the eq. 3.6 full scales).
        rec: the recording to calibrate.
    """
    out = {}
    for s, fn, rng in (("acc", calibrate_acc, meta["acc_range"]), ("gyr", calibrate_gyr, meta["gyr_range"])):
        y = getattr(rec, s)
        if y is None or s not in state:
            continue
        st = _thesis_state(state[s])
        out[f"{s}_cal"] = np.asarray(fn(st.params, jnp.asarray(y, jnp.float32), st.spec, rng))
    return out


def quality(rec: Recording, options: OnlineThesisOptions, model: Any, *, held_out: bool = True,
            log: Log | None = None) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """In-sample and held-out quality from the model's applied output on the sequences it was
    fitted on (:func:`jaxcal.methods.quality.seq_split_quality`: each sequence by its first and last
    samples; held out, a time split refitted on the first 80 % of the sequences), the sequences cut
    between rests as :func:`fit` cut them when the recording has no ``seq`` ids.

    The arguments and rows of a method's ``quality`` (:data:`jaxcal.methods.quality.QualityFn`).
    """
    from jaxcal.methods.online import rest_seq_recording

    seq_rec = rec if rec.seq is not None else rest_seq_recording(rec)  # as fit cut it
    return seq_split_quality(seq_rec, options, model, held_out=held_out, log=log)


METHOD = Method(
    "online-thesis", fit, apply, OnlineThesisOptions,
    "thesis chapter 4 as published: two 3-5-10-5-3 NNs self-calibrated on rotation sequences; "
    "seq ids and datasheet values, or rests between the motions",
    quality=quality,
)
