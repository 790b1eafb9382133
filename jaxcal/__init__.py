"""jaxcal: IMU calibration in JAX (accelerometer + gyroscope), reproducing and extending
Claesson & Marklund (2019).

The user path, flat (``import jaxcal``)::

    rec = jaxcal.load_recording("session.npz")            # or jaxcal.read("euroc", [path])
    model = jaxcal.fit("multipos", rec)                     # any name in jaxcal.methods.REGISTRY
    jaxcal.save_model(model, "model.npz")
    out = jaxcal.apply(jaxcal.load_model("model.npz"), rec)   # {"acc_cal": ..., "gyr_cal": ...}
    report = jaxcal.diagnose.diagnose_recording(rec)        # what the simulation leaves out

Interchange types: :class:`Recording` (the only in-memory recording), :class:`LinearCal` (a linear
calibration ``x = A (y - b)``), :class:`CalibrationModel` (a fitted method's state). Subpackages
(``multipos``, ``online``, ``diagnose``, ``eval``, ``simulate``, ``methods``) and these names are
imported on first use, so ``jaxcal.multipos.fit_multipos`` works after ``import jaxcal`` and
``import jaxcal.cli`` stays light. ARCHITECTURE.md maps the modules.
"""

import importlib
from typing import Any

from jaxcal._version import __version__ as __version__

# Imported on first use (PEP 562), so that `import jaxcal.cli` (and `jaxcal --help`) does not load
# jax, flax and optimistix: attribute -> the module that defines it.
_SUBPACKAGES = ("constants", "diagnose", "eval", "methods", "multipos", "offline", "online", "online_thesis",
                "rotation", "sensor", "simulate")
_NAMES = {
    "CalibrationModel": "jaxcal.methods",
    "apply": "jaxcal.methods",
    "fit": "jaxcal.methods",
    "load_model": "jaxcal.model_file",
    "save_model": "jaxcal.model_file",
    "read": "jaxcal.formats",
    "Recording": "jaxcal.recording",
    "load_recording": "jaxcal.recording",
    "save_recording": "jaxcal.recording",
    "LinearCal": "jaxcal.sensor",
}


def __getattr__(name: str) -> Any:
    """The subpackage or user-path name ``name``, imported on first use (then a plain attribute)."""
    if name in _SUBPACKAGES:
        value = importlib.import_module(f"jaxcal.{name}")
    elif name in _NAMES:
        value = getattr(importlib.import_module(_NAMES[name]), name)
    else:
        raise AttributeError(f"module 'jaxcal' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_SUBPACKAGES, *_NAMES})


__all__ = [
    "__version__",
    "CalibrationModel",
    "LinearCal",
    "Recording",
    "apply",
    "constants",
    "diagnose",
    "fit",
    "load_model",
    "load_recording",
    "methods",
    "multipos",
    "offline",
    "online",
    "online_thesis",
    "read",
    "rotation",
    "save_model",
    "save_recording",
    "sensor",
    "simulate",
]
