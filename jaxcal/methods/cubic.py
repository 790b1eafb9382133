"""Method ``cubic``: a polynomial calibration ``x = f(y)`` per sensor (the cubic sensor model of thesis
section 2.1.2), fitted to reference labels by weighted linear least squares with
:func:`jaxcal.polynomial.fit_cubic` and applied with :func:`jaxcal.polynomial.cubic_calibrate`.

The raw counts are normalised with bounds from the fitted data's range (stored with the model), then
each output axis is a full polynomial of the chosen degree in the three normalised inputs (every
cross term; degree 3: 20 monomials per axis, 60 parameters per sensor). The state on file is plain
arrays: ``state/<sensor>/coef`` ``(3, Q)`` and ``state/<sensor>/bounds/{lo, hi}`` ``(3,)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxcal import flags
from jaxcal.flags import Flag
from jaxcal.methods.base import SHARED_FLAGS, Fitted, Log, Method, ModelError, fit_each_labelled, labelled_sensors, units
from jaxcal.methods.quality import refit_quality
from jaxcal.normalise import Bounds
from jaxcal.polynomial import CubicCal, cubic_calibrate, degree_of, fit_cubic, n_monomials, n_params
from jaxcal.precision import float64
from jaxcal.recording import Recording

__all__ = ["METHOD", "CubicOptions", "apply", "check", "fit"]


class CubicOptions(NamedTuple):
    """Options of ``cubic`` (static: plain Python values).

    Args:
        sensors: sensors to calibrate (subset of ``("acc", "gyr")``); ``None``: every labelled one.
        degree: total degree of the polynomial (1: affine, 2: quadratic, 3: cubic with all cross terms).
        ridge: penalty on the degree >= 2 coefficients relative to the mean squared residual
            (:func:`jaxcal.polynomial.fit_cubic`); 0: plain least squares (minimum-norm when the
            labels do not determine every coefficient).
    """

    sensors: tuple[str, ...] | None = None
    degree: int = 3
    ridge: float = 0.0

    FLAGS = {
        "sensors": SHARED_FLAGS["sensors"],
        "degree": Flag("--degree", flags.count(1, 9), None, "polynomial degree", "D"),
        "ridge": Flag("--ridge", flags.real(0.0, 1e12, open_low=False), None,
                      "ridge penalty on the polynomial coefficients", "R"),
    }


@float64
def fit(rec: Recording, options: CubicOptions, log: Log) -> Fitted:
    """Fit ``x = f(y)`` per labelled sensor in float64.

    Args:
        rec: a recording with ``acc``/``acc_ref`` and/or ``gyr``/``gyr_ref``.
        options: :class:`CubicOptions`.
        log: progress sink.
    """
    degree, ridge = int(options.degree), float(options.ridge)
    if degree < 1:
        raise ModelError(f"method 'cubic': degree must be at least 1, got {degree}")
    if not ridge >= 0.0:
        raise ModelError(f"method 'cubic': ridge must be non-negative, got {ridge}")
    sensors = labelled_sensors(rec, options.sensors, "cubic")

    def fit_one(s: str, y: np.ndarray, x: np.ndarray) -> tuple[CubicCal, np.ndarray]:
        # LSB ~ 1e4 with sub-mg floors: fit in float64
        model = fit_cubic(jnp.asarray(y), jnp.asarray(x), None, degree, ridge)
        model = CubicCal(np.asarray(model.coef), Bounds(np.asarray(model.bounds.lo), np.asarray(model.bounds.hi)))
        if not np.all(np.isfinite(model.coef)):
            raise ModelError(f"cubic fit of '{s}' failed (non-finite coefficients)")
        return model, np.asarray(cubic_calibrate(model, jnp.asarray(y)))

    state, train_rms = fit_each_labelled(rec, sensors, "cubic", fit_one, log,
                                         detail=f", degree {degree} ({n_params(degree)} parameters),")
    meta: dict[str, Any] = {"units": units(rec, sensors), "n_samples": rec.n, "degree": degree, "ridge": ridge,
                            "n_params": n_params(degree), "train_rms": train_rms}
    return Fitted(sensors, state, meta)


def _cubic_state(p: Mapping[str, Any]) -> CubicCal:
    """A stored ``{"coef", "bounds": {"lo", "hi"}}`` as a float64 :class:`CubicCal` (call under x64)."""
    b = p["bounds"]
    return CubicCal(jnp.asarray(p["coef"], jnp.float64), Bounds(*(jnp.asarray(b[k], jnp.float64) for k in Bounds._fields)))


def check(state: Mapping[str, Any], meta: Mapping[str, Any], sensors: tuple[str, ...]) -> None:
    """:data:`~jaxcal.methods.base.CheckFn` of ``cubic``: each sensor's ``coef`` is ``(3, Q)`` with
    ``Q`` a full polynomial's monomial count (4, 10, 20, ...), bounds ``lo``/``hi`` are ``(3,)`` with
    ``hi != lo``, everything finite.

    Args:
        state: the loaded state (nested dicts of numpy arrays).
        meta: the model's metadata (unused).
        sensors: the model's sensors.
    """
    for s in sensors:
        p = state.get(s)
        b = p.get("bounds") if isinstance(p, Mapping) else None
        if not isinstance(b, Mapping) or "coef" not in p or any(k not in b for k in Bounds._fields):
            raise ModelError(f"state of '{s}' is not a polynomial calibration (coef, bounds/lo, bounds/hi)")
        coef = np.asarray(p["coef"])
        try:
            ok = coef.ndim == 2 and coef.shape[0] == 3 and n_monomials(degree_of(coef.shape[1])) == coef.shape[1]
        except ValueError:
            ok = False
        if not ok:
            raise ModelError(f"state/{s}/coef has shape {coef.shape}, expected (3, Q) with Q in 4, 10, 20, 35, ...")
        lo, hi = np.asarray(b["lo"], np.float64), np.asarray(b["hi"], np.float64)
        if lo.shape != (3,) or hi.shape != (3,):
            raise ModelError(f"state/{s}/bounds has shapes {lo.shape}, {hi.shape}, expected (3,)")
        if not (np.isfinite(coef).all() and np.isfinite(lo).all() and np.isfinite(hi).all()) or np.any(hi == lo):
            raise ModelError(f"state of '{s}' has non-finite values or an empty normalisation range")


@float64
def apply(state: Mapping[str, Any], meta: Mapping[str, Any], rec: Recording) -> dict[str, np.ndarray]:
    """Calibrate with the stored polynomials, in float64.

    Args:
        state: ``sensor -> {"coef", "bounds"}``.
        meta: the model's metadata (unused: the degree is read from ``coef``'s shape).
        rec: the recording to calibrate.
    """
    out = {}
    for s, p in state.items():
        y = getattr(rec, s)
        if y is not None:
            out[f"{s}_cal"] = np.asarray(cubic_calibrate(_cubic_state(p), jnp.asarray(y, jnp.float64)))
    return out


METHOD = Method(
    "cubic", fit, apply, CubicOptions,
    "polynomial (default cubic, all cross terms) model x = f(y) per sensor (thesis 2.1.2); needs acc_ref/gyr_ref",
    check,
    quality=refit_quality,
)
