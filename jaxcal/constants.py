"""Physical constants and default sensor ranges shared by every module (pure values, no imports).

One place for the numbers that were written in several modules: standard gravity (the ``g`` unit
of the conventions), the thesis sensors' full-scale ranges (Dataset 1 and 2, chapters 3-4; also the
CLI's defaults for eq. 3.6 bounds), and the physical unit of each sensor.
"""

from __future__ import annotations

import math

__all__ = ["G0", "EARTH_RATE", "ACC_RANGE_G", "GYR_RANGE_DEGS", "GYR_RANGE_RADS", "ACC_LSB_PER_G", "GYR_LSB_PER_DPS", "PHYS_UNIT", "SENSORS"]

G0 = 9.80665
"""Standard gravity in m/s^2 per g (the conventions' ``g`` unit)."""

EARTH_RATE = 7.292115e-5
"""The Earth's rotation rate in rad/s (WGS-84): a gyro at rest reads its vertical component
``EARTH_RATE sin(latitude)`` along the specific force."""

ACC_RANGE_G = 2.0
"""Accelerometer full scale of the thesis's sensors, in g (+-2 g)."""

GYR_RANGE_DEGS = 250.0
"""Gyroscope full scale of the thesis's sensors, in deg/s (+-250 deg/s)."""

GYR_RANGE_RADS = GYR_RANGE_DEGS * math.pi / 180.0
"""The same gyroscope full scale in rad/s."""

ACC_LSB_PER_G = 16384.0
"""MPU-6050-class accelerometer sensitivity at +-2 g (datasheet PS-MPU-6000A rev 3.4), LSB per g:
the thesis's sensors and the MPU-6050 recording."""

GYR_LSB_PER_DPS = 131.0
"""MPU-6050-class gyroscope sensitivity at +-250 deg/s (same datasheet), LSB per deg/s."""

SENSORS = ("acc", "gyr")
"""The two sensors of an IMU recording, in the order every module uses."""

PHYS_UNIT = {"acc": "g", "gyr": "rad/s"}
"""The calibrated (physical) unit of each sensor."""
