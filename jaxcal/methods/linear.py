"""Method ``linear``: the thesis's 12-parameter affine model per sensor (eq. 3.1-3.5), fitted to
reference labels with :func:`jaxcal.linear.fit_affine` and applied as a
:class:`~jaxcal.sensor.LinearCal` (``x = S^{-1} (y - b)``, eq. 3.5)."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxcal.linear import fit_affine
from jaxcal.methods.base import (
    SHARED_FLAGS,
    Fitted,
    Log,
    Method,
    ModelError,
    apply_linear_state,
    check_linear_state,
    fit_each_labelled,
    labelled_sensors,
    units,
)
from jaxcal.methods.quality import refit_quality
from jaxcal.precision import float64
from jaxcal.recording import Recording
from jaxcal.sensor import Affine, LinearCal

__all__ = ["METHOD", "LinearOptions", "fit"]


class LinearOptions(NamedTuple):
    """Options of ``linear`` (static: plain Python values).

    Args:
        sensors: sensors to calibrate (subset of ``("acc", "gyr")``); ``None``: every labelled one.
    """

    sensors: tuple[str, ...] | None = None

    FLAGS = {"sensors": SHARED_FLAGS["sensors"]}


@float64
def fit(rec: Recording, options: LinearOptions, log: Log) -> Fitted:
    """Fit ``y = S x + b`` per labelled sensor in float64 (eq. 3.2-3.3).

    Args:
        rec: a recording with ``acc``/``acc_ref`` and/or ``gyr``/``gyr_ref``.
        options: :class:`LinearOptions`.
        log: progress sink.
    """
    sensors = labelled_sensors(rec, options.sensors, "linear")

    def fit_one(s: str, y: np.ndarray, x: np.ndarray) -> tuple[Affine, np.ndarray]:
        # LSB ~ 1e4 with 1e-5 relative floors: fit in float64
        model = fit_affine(jnp.asarray(x), jnp.asarray(y))
        model = Affine(np.asarray(model.S), np.asarray(model.b))
        if not (np.all(np.isfinite(model.S)) and np.all(np.isfinite(model.b))):
            raise ModelError(f"linear fit of '{s}' failed (singular: labels must span 3 directions)")
        return model, np.asarray(LinearCal.from_forward(model).apply(jnp.asarray(y)))

    state, train_rms = fit_each_labelled(rec, sensors, "linear", fit_one, log)
    meta: dict[str, Any] = {"units": units(rec, sensors), "n_samples": rec.n, "train_rms": train_rms}
    return Fitted(sensors, state, meta)


METHOD = Method(
    "linear", fit, apply_linear_state, LinearOptions,
    "12-parameter affine model per sensor (thesis eq. 3.1-3.5); needs acc_ref/gyr_ref",
    check_linear_state,
    quality=refit_quality,
)
