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
(``multipos``, ``online``, ``diagnose``, ``eval``, ``simulate``, ``methods``) are imported, so
``jaxcal.multipos.fit_multipos`` works after ``import jaxcal``. ARCHITECTURE.md maps the modules.
"""

__version__ = "0.1.0"

from jaxcal import constants as constants
from jaxcal import diagnose as diagnose
from jaxcal import eval as eval  # the subpackage; left out of __all__ so `import *` keeps the builtin
from jaxcal import methods as methods
from jaxcal import multipos as multipos
from jaxcal import offline as offline
from jaxcal import online as online
from jaxcal import online_thesis as online_thesis
from jaxcal import rotation as rotation
from jaxcal import sensor as sensor
from jaxcal import simulate as simulate
from jaxcal.formats import read as read
from jaxcal.methods import CalibrationModel as CalibrationModel
from jaxcal.methods import apply as apply
from jaxcal.methods import fit as fit
from jaxcal.model_file import load_model as load_model
from jaxcal.model_file import save_model as save_model
from jaxcal.recording import Recording as Recording
from jaxcal.recording import load_recording as load_recording
from jaxcal.recording import save_recording as save_recording
from jaxcal.sensor import LinearCal as LinearCal

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
