"""A toy calibration method: the whole of what a new method needs (see ``test_methods_contract.py``).

Per-axis scale and bias fitted to reference labels (``y = k x + b`` per axis, ordinary least
squares), stored and applied as the linear methods are (a forward ``Affine`` on file, applied as a
``LinearCal``). Register it with one line, ``methods.register(toy_method.METHOD)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxcal.flags import Flag
from jaxcal.methods.base import (
    REF_KEY,
    SHARED_FLAGS,
    Fitted,
    Log,
    Method,
    apply_linear_state,
    check_linear_state,
    labelled_sensors,
    units,
)
from jaxcal.recording import Recording
from jaxcal.sensor import Affine

__all__ = ["METHOD", "ToyOptions", "fit"]


class ToyOptions(NamedTuple):
    """Options of ``toy-diag``.

    Args:
        sensors: sensors to calibrate; ``None``: every labelled one.
        through_origin: fit ``y = k x`` (no bias).
    """

    sensors: tuple[str, ...] | None = None
    through_origin: bool = False

    # the command-line flags of its fields (jaxcal calibrate reads them; no CLI edit)
    FLAGS = {"sensors": SHARED_FLAGS["sensors"],
             "through_origin": Flag("--through-origin", None, None, "fit y = k x (no bias)", const=True,
                                    show_default="off")}


def fit(rec: Recording, options: ToyOptions, log: Log) -> Fitted:
    """Per-axis ``y = k x + b`` by least squares on the labels.

    Args:
        rec: a labelled recording.
        options: :class:`ToyOptions`.
        log: progress sink.
    """
    sensors = labelled_sensors(rec, options.sensors, "toy-diag")
    state = {}
    for s in sensors:
        y = np.asarray(getattr(rec, s), np.float64)
        x = np.asarray(getattr(rec, REF_KEY[s]), np.float64)
        if options.through_origin:
            k = (x * y).sum(0) / (x * x).sum(0)
            state[s] = Affine(np.diag(k), np.zeros(3))
        else:
            xc = x - x.mean(0)
            k = (xc * (y - y.mean(0))).sum(0) / (xc * xc).sum(0)
            state[s] = Affine(np.diag(k), y.mean(0) - k * x.mean(0))
        log(f"toy-diag ({s}): scale {k}")
    return Fitted(sensors, state, {"units": units(rec, sensors)})


METHOD = Method("toy-diag", fit, apply_linear_state, ToyOptions,
                "per-axis scale and bias (a test plug-in); needs acc_ref/gyr_ref", check_linear_state)
