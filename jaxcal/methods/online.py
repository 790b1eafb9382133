"""Method ``online``: jaxcal's streaming self-calibration (an affine model per sensor, estimated
by an information filter over rotation sequences, :func:`jaxcal.online.fit_online_recording`);
no labels, datasheet values optional. Stored and applied as the linear methods are."""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from jaxcal.constants import SENSORS
from jaxcal.methods.base import (
    Fitted,
    Log,
    Method,
    ModelError,
    apply_linear_state,
    check_linear_state,
    linear_state,
    recording_dt,
    recording_spec,
    require_both,
    sequences_of,
    units,
)
from jaxcal.online import fit_online_recording
from jaxcal.recording import Recording, sequence_slices

__all__ = ["METHOD", "OnlineOptions", "fit"]


class OnlineOptions(NamedTuple):
    """Options of ``online``: none; the filter runs with :class:`jaxcal.online.OnlineHP`'s
    defaults (the prior widened where a datasheet value is estimated from the data).

    Attributes:
        (none): ``online`` takes no options (see above).
    """


def fit(rec: Recording, options: OnlineOptions, log: Log) -> Fitted:
    """Self-calibrate both sensors from the recording's rotation sequences.

    Args:
        rec: a recording with ``acc``, ``gyr`` and ``seq`` ids (datasheet values optional).
        options: :class:`OnlineOptions`.
        log: progress sink.
    """
    require_both(rec, "online")
    seq = sequences_of(rec, "online")
    n_seq = len(sequence_slices(rec))
    dt = recording_dt(rec)
    acc_spec, gyr_spec = recording_spec(rec, "acc"), recording_spec(rec, "gyr")
    log(f"fitting online on {n_seq} sequences ({rec.n} samples, dt {dt:g} s) ...")
    t0 = time.perf_counter()
    try:
        cals = fit_online_recording(
            np.asarray(rec.acc, np.float64), np.asarray(rec.gyr, np.float64), seq, dt, acc_spec, gyr_spec
        )
    except ValueError as e:
        raise ModelError(f"online: {e}") from None
    elapsed = time.perf_counter() - t0
    state = {s: linear_state(cal) for s, cal in zip(SENSORS, cals)}
    for s, m in state.items():
        if not (np.all(np.isfinite(m.S)) and np.all(np.isfinite(m.b))):
            raise ModelError(f"online: the {s} estimate is not finite (does the recording hold rotation sequences?)")
    log(f"fitting online ... done in {elapsed:.1f} s")
    meta = {
        "units": units(rec, SENSORS),
        "n_sequences": n_seq,
        "dt": dt,
        "fit_seconds": elapsed,
        "spec_from": {s: ("metadata" if sp is not None else "data") for s, sp in (("acc", acc_spec), ("gyr", gyr_spec))},
    }
    return Fitted(SENSORS, state, meta)


METHOD = Method(
    "online", fit, apply_linear_state, OnlineOptions,
    "jaxcal's streaming self-calibration (affine per sensor, information filter on rotation "
    "sequences); needs seq ids, no labels",
    check_linear_state,
)
