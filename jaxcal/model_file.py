"""Calibration model files: :func:`save_model` / :func:`load_model` of a
:class:`~jaxcal.methods.CalibrationModel`.

Format (``.npz``, ``allow_pickle=False``; format :data:`MODEL_FORMAT`):

=====================  ==========  ==========================================================
key                    kind        meaning
=====================  ==========  ==========================================================
``jaxcal_model_format`` int        format version (1)
``method``             str         the registered method's name (:mod:`jaxcal.methods`)
``sensors``            str array   the calibrated sensors, a subset of ``acc``, ``gyr``
``meta_json``          str         JSON object: units at fit time (``units``), hyperparameters, fit statistics
``jaxcal_version``     str         the jaxcal that wrote it
``state/<path>``       real array  the state, flattened by field name (e.g. ``state/acc/S``, ``state/acc/b``)
=====================  ==========  ==========================================================

Every field is checked on loading, then the method's own ``check`` (e.g. a 3x3 invertible ``S``),
so a corrupt model is refused on loading, not half-way through ``apply``. ``CalibrationModel``
and ``ModelError`` are defined in :mod:`jaxcal.methods` (a fit returns the former) and importable
from here.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from flax import traverse_util

from jaxcal._version import __version__
from jaxcal.constants import SENSORS
from jaxcal.methods import CalibrationModel, ModelError, get, names
from jaxcal.recording import NPZ_READ_ERRORS, atomic_output, read_npz_arrays

__all__ = ["MODEL_FORMAT", "CalibrationModel", "ModelError", "load_model", "save_model"]

MODEL_FORMAT = 1


def save_model(model: CalibrationModel, path: str | os.PathLike) -> None:
    """Write ``model`` as a ``.npz`` model file (see the module docstring).

    The file is written beside ``path`` and renamed over it only when complete
    (:func:`jaxcal.recording.atomic_output`): an interruption leaves an earlier model intact.

    Args:
        model: the model to write.
        path: destination, ending in ``.npz``.

    Raises:
        ModelError: ``path`` is not a ``.npz`` name, or it cannot be written.
    """
    p = Path(path)
    flat = traverse_util.flatten_dict(dict(model.state), sep="/")
    arrays = {f"state/{k}": np.asarray(v) for k, v in flat.items()}
    arrays.update(
        jaxcal_model_format=np.asarray(MODEL_FORMAT),
        method=np.asarray(model.method),
        sensors=np.asarray(list(model.sensors), dtype=str),
        meta_json=np.asarray(json.dumps(model.meta, sort_keys=True)),
        jaxcal_version=np.asarray(__version__),
    )
    if p.suffix.lower() != ".npz":
        raise ModelError(f"{p}: model files are .npz (got extension {p.suffix!r})")
    try:
        with atomic_output(p) as tmp, open(tmp, "wb") as fh:  # whole or not at all: never a truncated model
            np.savez_compressed(fh, **arrays)
    except OSError as e:
        raise ModelError(f"{p}: cannot write ({e.strerror or e})") from None


def load_model(path: str | os.PathLike) -> CalibrationModel:
    """Read a model file written by :func:`save_model`, checking every field before use.

    Args:
        path: the ``.npz`` model file.

    Raises:
        ModelError: missing/unreadable file, not a jaxcal model, a header field of the wrong
            kind (format not an integer, metadata not a JSON object, ...), state arrays that are
            not finite real numbers, an unknown method, or a state the method cannot use (its
            ``check``: e.g. a 2x2 or singular matrix).
    """
    p = Path(path)
    if not p.is_file():
        raise ModelError(f"{p}: no such model file")
    try:
        d = read_npz_arrays(p)
    except NPZ_READ_ERRORS as e:
        raise ModelError(f"{p}: cannot read as a .npz model file ({type(e).__name__})") from None
    try:
        method = _model_method(d)
        meta = _model_meta(d)
        sensors = _model_sensors(d)
        state = _model_state(d, sensors)
        spec = get(method)
    except ModelError as e:
        raise ModelError(f"{p}: {e}") from None
    if spec.check is not None:
        try:
            spec.check(state, meta, sensors)
        except ModelError as e:
            raise ModelError(f"{p}: malformed '{method}' model: {e}") from None
    return CalibrationModel(method, sensors, state, meta)


def _scalar_field(d: Mapping[str, np.ndarray], key: str, kinds: str, what: str) -> Any:
    """A 0-d entry of the model file whose dtype kind is in ``kinds``, as a Python scalar."""
    a = d[key]
    if a.shape != () or a.dtype.kind not in kinds:
        raise ModelError(f"'{key}' must be {what}, got {a.dtype} of shape {a.shape}")
    return a.item()


def _model_method(d: Mapping[str, np.ndarray]) -> str:
    """Format (an integer this jaxcal reads) and method name (a registered one)."""
    if "jaxcal_model_format" not in d or "method" not in d:
        raise ModelError("not a jaxcal model file (no 'jaxcal_model_format'/'method' keys)")
    fmt = _scalar_field(d, "jaxcal_model_format", "iu", "an integer")
    if not 1 <= fmt <= MODEL_FORMAT:
        raise ModelError(f"model format {fmt} is not one this jaxcal reads (1..{MODEL_FORMAT})")
    method = str(_scalar_field(d, "method", "U", "a string"))
    if method not in names():
        raise ModelError(f"model of unknown method '{method}' (known: {', '.join(names())})")
    return method


def _model_meta(d: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """``meta_json``: a JSON object (``{}`` if absent); its ``units``, if any, an object too."""
    text = _scalar_field(d, "meta_json", "U", "a JSON string") if "meta_json" in d else "{}"
    try:
        meta = json.loads(text)
    except ValueError:
        raise ModelError("'meta_json' is not valid JSON") from None
    if not isinstance(meta, dict):
        raise ModelError(f"'meta_json' must hold a JSON object, got {type(meta).__name__}")
    if not isinstance(meta.get("units", {}), dict):
        raise ModelError(f"'meta_json' field 'units' must be an object, got {type(meta['units']).__name__}")
    return meta


def _model_sensors(d: Mapping[str, np.ndarray]) -> tuple[str, ...]:
    """``sensors``: a non-empty set of strings from ``acc``, ``gyr``."""
    a = d.get("sensors", np.asarray([], dtype=str))
    if a.dtype.kind != "U" or a.ndim > 1:
        raise ModelError(f"'sensors' must be a list of strings, got {a.dtype} of shape {a.shape}")
    sensors = tuple(str(s) for s in np.atleast_1d(a))
    if not sensors or any(s not in SENSORS for s in sensors) or len(set(sensors)) != len(sensors):
        raise ModelError(f"bad 'sensors' entry {list(sensors)} (expected a subset of acc, gyr)")
    return sensors


def _model_state(d: Mapping[str, np.ndarray], sensors: tuple[str, ...]) -> dict[str, Any]:
    """The ``state/...`` arrays, unflattened: finite real numbers, an entry for every sensor."""
    flat = {k[len("state/"):]: v for k, v in d.items() if k.startswith("state/")}
    for k, v in flat.items():
        if v.dtype.kind not in "iuf":
            raise ModelError(f"state/{k}: expected real numbers, got {v.dtype}")
        if not np.all(np.isfinite(v)):
            raise ModelError(f"state/{k}: non-finite value")
    try:
        state = traverse_util.unflatten_dict(flat, sep="/") if flat else {}
    except (ValueError, TypeError, KeyError) as e:
        raise ModelError(f"state keys do not form a tree ({type(e).__name__}: {e})") from None
    missing = [s for s in sensors if not isinstance(state.get(s), dict)]
    if missing:
        raise ModelError(f"no state for '{missing[0]}', which 'sensors' lists")
    return state
