"""A recording's sensors replaced by a model's calibrated output (:func:`with_calibrated`): what
``jaxcal apply`` writes, and what scoring against mocap prepares."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from jaxcal.constants import PHYS_UNIT, SENSORS
from jaxcal.recording.types import Recording

_SPEC_KEYS = {"acc": ("acc_lsb_per_g", "acc_bias_lsb"), "gyr": ("gyr_lsb_per_rads", "gyr_bias_lsb")}


def with_calibrated(rec: Recording, outputs: Mapping[str, np.ndarray]) -> Recording:
    """``rec`` with each calibrated sensor's output in its physical unit (pure; not validated).

    For each ``{s}_cal`` in ``outputs`` (``acc_cal`` in g, ``gyr_cal`` in rad/s, on ``rec``'s
    samples): ``s`` becomes that output as float64, ``{s}_unit`` its physical unit, and the
    sensor's datasheet values (which convert raw counts) are dropped. Every other field, a sensor
    the outputs do not calibrate included, and the extras are kept.

    Args:
        rec: the recording the outputs were computed on.
        outputs: ``{"acc_cal": (N, 3), "gyr_cal": (N, 3)}`` (either may be absent).
    """
    changes: dict = {}
    for s in SENSORS:
        if f"{s}_cal" not in outputs:
            continue
        changes.update({s: np.asarray(outputs[f"{s}_cal"], np.float64), f"{s}_unit": PHYS_UNIT[s]})
        changes.update(dict.fromkeys(_SPEC_KEYS[s]))
    return rec.replace(**changes)
