"""Calibration methods as plug-ins: the registry behind ``jaxcal calibrate`` / ``jaxcal apply``.

:data:`REGISTRY` is an ordinary dict (name -> :class:`~jaxcal.methods.base.Method`) filled below
when this package is imported; every method ships. Built in (one module each, each with its typed
options):

* ``linear`` (:mod:`~jaxcal.methods.linear`, :class:`LinearOptions`): thesis eq. 3.1-3.5; labels.
* ``nn`` (:mod:`~jaxcal.methods.nn`, :class:`NNOptions`): thesis section 3.3; labels.
* ``cubic`` (:mod:`~jaxcal.methods.cubic`, :class:`CubicOptions`): the cubic polynomial of thesis
  section 2.1.2; labels.
* ``online-thesis`` (:mod:`~jaxcal.methods.online_thesis`, :class:`OnlineThesisOptions`): thesis
  chapter 4 as published; ``seq`` ids and datasheet values.
* ``online`` (:mod:`~jaxcal.methods.online`, :class:`OnlineOptions`): streaming self-calibration;
  ``seq`` ids.
* ``multipos`` (:mod:`~jaxcal.methods.multipos`, :class:`MultiposOptions`): static poses joined by
  rotations; no labels, no datasheet values.

Adding a method: write a module with a ``fit``, an ``apply``, an options ``NamedTuple`` and a
``METHOD = Method(...)``, then add one line ``register(module.METHOD)`` below (or call
:func:`register` from your own code). ``tests/test_methods_contract.py`` runs every registered
method through fit -> save -> load -> apply.

:func:`fit` returns a :class:`CalibrationModel` (its state as nested dicts of numpy arrays, the
form a model file holds); :func:`apply` (or :meth:`CalibrationModel.apply`) calibrates a
recording with it. Model files: :mod:`jaxcal.model_file`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import numpy as np
from flax import serialization
from flax.errors import FlaxError

from jaxcal.constants import SENSORS
from jaxcal.methods import cubic, diagnosed, linear, multipos, nn, online, online_thesis
from jaxcal.methods.base import Fitted, Log, Method, ModelError, units
from jaxcal.methods.cubic import CubicOptions
from jaxcal.methods.linear import LinearOptions
from jaxcal.methods.multipos import MultiposOptions
from jaxcal.methods.nn import NNOptions
from jaxcal.methods.online import OnlineOptions
from jaxcal.methods.online_thesis import OnlineThesisOptions
from jaxcal.recording import Recording

__all__ = [
    "REGISTRY",
    "CalibrationModel",
    "CubicOptions",
    "Fitted",
    "LinearOptions",
    "Method",
    "ModelError",
    "MultiposOptions",
    "NNOptions",
    "OnlineOptions",
    "OnlineThesisOptions",
    "apply",
    "fit",
    "get",
    "names",
    "register",
]

REGISTRY: dict[str, Method] = {}
"""Every calibration method by name, in the order ``jaxcal methods`` lists them."""


def register(method: Method) -> None:
    """Register (or replace) ``method`` under ``method.name``.

    Args:
        method: a :class:`~jaxcal.methods.base.Method`.
    """
    REGISTRY[method.name] = method


def names() -> tuple[str, ...]:
    """The registered method names, in registration order."""
    return tuple(REGISTRY)


def get(name: str) -> Method:
    """The method registered as ``name``.

    Args:
        name: a method name, e.g. ``"linear"``.

    Raises:
        ModelError: no method of that name.
    """
    if name not in REGISTRY:
        raise ModelError(f"unknown method '{name}' (known: {', '.join(names())})")
    return REGISTRY[name]


@dataclass(frozen=True, eq=False)
class CalibrationModel:
    """A fitted calibration: method name, calibrated sensors, state (nested dicts of numpy
    arrays, as in the model file) and JSON metadata. :meth:`apply` maps a recording to calibrated
    physical units.

    Args:
        method: the registered method's name.
        sensors: the calibrated sensors, a subset of ``("acc", "gyr")``.
        state: ``sensor -> parameters`` (nested dicts of numpy arrays).
        meta: JSON-able metadata; ``meta["units"]`` holds each sensor's unit at fit time.
    """

    method: str
    sensors: tuple[str, ...]
    state: Mapping[str, Any]
    meta: Mapping[str, Any]

    def apply(self, rec: Recording) -> dict[str, np.ndarray]:
        """Calibrate ``rec`` (see :func:`apply`)."""
        return apply(self, rec)


def _to_state(state: Any) -> dict[str, Any]:
    """A fitted state pytree as nested dicts of numpy arrays, keyed by field name."""
    sd = serialization.to_state_dict(state)
    return jax.tree.map(lambda a: np.asarray(a), sd)


def fit(method: str, rec: Recording, options: NamedTuple | None = None, *, log: Log | None = None) -> CalibrationModel:
    """Fit ``method`` on ``rec``.

    Args:
        method: a registered method name (:func:`names`).
        rec: the recording to fit.
        options: the method's options (e.g. :class:`NNOptions`); ``None``: its defaults.
        log: progress sink (e.g. printing to stderr); ``None`` for silence.

    Returns:
        A :class:`CalibrationModel` (state as numpy dicts, ``meta["units"]`` set).

    Raises:
        ModelError: unknown method, options of another method, or a recording the method cannot
            use (one line saying what is missing).
    """
    m = get(method)
    options = m.options() if options is None else options
    if not isinstance(options, m.options):
        raise ModelError(f"method '{method}' takes {m.options.__name__}, got {type(options).__name__}")
    fitted = m.fit(rec, options, log or (lambda msg: None))
    meta = dict(fitted.meta)
    meta.setdefault("units", units(rec, tuple(fitted.sensors)))
    return CalibrationModel(method, tuple(fitted.sensors), _to_state(fitted.state), meta)


def apply(model: CalibrationModel, rec: Recording) -> dict[str, np.ndarray]:
    """Calibrate ``rec`` with ``model``.

    Args:
        model: a fitted or loaded :class:`CalibrationModel`.
        rec: the recording to calibrate.

    Returns:
        ``{"acc_cal": (N, 3) g, "gyr_cal": (N, 3) rad/s}`` (float64) for the sensors that both
        the model and the recording have.

    Raises:
        ModelError: the recording has none of the model's sensors, a sensor's unit differs from
            the one the model was fitted on, the method is unknown, the model is malformed
            (its output is not finite ``(N, 3)`` arrays), or the method's ``apply`` refuses the
            recording (its own one-line :class:`ModelError`, e.g. a channel the model needs).
    """
    present = [s for s in model.sensors if getattr(rec, s) is not None]
    if not present:
        raise ModelError(
            f"recording has no {' or '.join(repr(s) for s in model.sensors)}, "
            f"which the '{model.method}' model calibrates"
        )
    fitted_units = model.meta.get("units", {})
    for s in present:
        want, got = fitted_units.get(s), getattr(rec, f"{s}_unit")
        if want is not None and want != got:
            raise ModelError(f"recording's '{s}' is in {got}, the model was fitted on {want}")
    m = get(model.method)
    state = {s: model.state[s] for s in present if s in model.state}
    other = {k: v for k, v in model.state.items() if k not in SENSORS}
    try:
        out = m.apply({**other, **state}, model.meta, rec)
    except ModelError:  # the method's own one-line refusal (e.g. a channel the model needs is missing)
        raise
    except (KeyError, TypeError, IndexError, ValueError, AttributeError, FlaxError) as e:
        # a state/meta entry missing or of the wrong kind or shape
        msg = " ".join(str(e).split())[:200]
        raise ModelError(f"'{model.method}' model is malformed ({type(e).__name__}: {msg})") from None
    out = {k: np.asarray(v, np.float64) for k, v in out.items() if k in ("acc_cal", "gyr_cal")}
    _check_output(model.method, out, rec.n)
    return out


def _check_output(method: str, out: Mapping[str, np.ndarray], n: int) -> None:
    """Calibrated arrays must be (N, 3) and finite: a model that yields NaN or inf is refused
    rather than written."""
    if not out:
        raise ModelError(f"the '{method}' model calibrated none of the recording's sensors")
    for k, v in out.items():
        if v.shape != (n, 3):
            raise ModelError(f"'{method}' model gives {k} of shape {v.shape}, expected ({n}, 3): the model is malformed")
        bad = np.argwhere(~np.isfinite(v))
        if bad.size:
            raise ModelError(f"'{method}' model gives a non-finite {k} at row {int(bad[0][0])} (a singular or "
                             "corrupt model, or input far outside its range)")


register(linear.METHOD)
register(nn.METHOD)
register(online_thesis.METHOD)
register(online.METHOD)
register(multipos.METHOD)
register(cubic.METHOD)
register(diagnosed.METHOD)
