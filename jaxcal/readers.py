"""The recording readers' old import path: every name re-exported from :mod:`jaxcal.formats`.

Each reader now lives in its format's module (``jaxcal/formats/``: ``imu_tk``, ``imucal``, ``euroc``,
``tumvi``, ``mpu6050``, ``xio``, ``broad``, ``generic_csv``, ``rosbag``) and :func:`read` dispatches
through :data:`jaxcal.formats.REGISTRY`. This module keeps ``jaxcal.readers.read``,
``jaxcal.readers.ReaderError`` and the per-format functions where users import them.
"""

from __future__ import annotations

from jaxcal.formats import read, readers
from jaxcal.formats.broad import read_broad
from jaxcal.formats.euroc import read_euroc
from jaxcal.formats.generic_csv import read_generic_csv
from jaxcal.formats.imu_tk import read_imu_tk
from jaxcal.formats.imucal import read_imucal
from jaxcal.formats.mpu6050 import MPU6050_ACC_LSB_PER_G, MPU6050_GYR_LSB_PER_RADS, read_mpu6050
from jaxcal.formats.pose import attach_pose, unit_quaternions
from jaxcal.formats.table import (
    ReaderError,
    check_column_units,
    finish_recording,
    unit_factor,
    unit_from_header,
)
from jaxcal.formats.tumvi import read_tumvi
from jaxcal.formats.xio import read_fusion

__all__ = [
    "FORMATS",
    "ReaderError",
    "attach_pose",
    "finish_recording",
    "unit_quaternions",
    "read",
    "read_imu_tk",
    "read_imucal",
    "read_euroc",
    "read_tumvi",
    "read_mpu6050",
    "read_fusion",
    "read_broad",
    "read_generic_csv",
    "unit_factor",
    "unit_from_header",
    "check_column_units",
    "MPU6050_ACC_LSB_PER_G",
    "MPU6050_GYR_LSB_PER_RADS",
]

FORMATS = readers()
"""The formats :func:`read` takes (:func:`jaxcal.formats.readers`; ``rosbag`` included since it reads through the registry)."""
