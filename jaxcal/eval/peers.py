"""Peers' and published calibrations as :class:`~jaxcal.sensor.LinearCal` pairs.

Each converter states the peer's equation and how its units map onto the recording's, so a
cross-method comparison starts from one type. ``imucal`` is an optional dependency (the
``compare`` extra); it is imported only by :func:`imucal_ferraris`.
"""

from __future__ import annotations

import numpy as np

from jaxcal.constants import G0
from jaxcal.sensor import LinearCal

__all__ = ["imucal_ferraris", "imu_tk_factory", "tedaldi_published", "datasheet"]


def imucal_ferraris(acc_g: np.ndarray, gyr_rads: np.ndarray, bounds: dict, fs: float,
                    grav: float = 9.81) -> tuple[LinearCal, LinearCal]:
    """imucal's Ferraris calibration on the given sections, converted to calibrations of data in g and rad/s.

    imucal computes ``acc = R_a^-1 K_a^-1 (raw - b_a)`` in m/s^2 (``|g| = grav``) and
    ``gyr = R_g^-1 K_g^-1 (raw - K_ga acc - b_g)`` in deg/s (``K_ga``, g-sensitivity, is left out);
    its raw input here is ``9.80665 y`` and ``degrees(y)``.

    Args:
        acc_g, gyr_rads: (N, 3) accelerometer (g) and gyroscope (rad/s) outputs.
        bounds: section name -> (start, end) sample indices, imucal's Ferraris section names.
        fs: sampling rate (Hz).
        grav: the gravity imucal normalises to (its default 9.81).
    """
    import pandas as pd
    from imucal import FerrarisCalibration, ferraris_regions_from_section_list

    sec = pd.DataFrame({n: {"start": int(a), "end": int(b)} for n, (a, b) in bounds.items()}).T
    df = pd.DataFrame(np.concatenate([acc_g * G0, np.degrees(gyr_rads)], 1).astype(np.float64),
                      columns=["acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"])
    regions = ferraris_regions_from_section_list(df, sec)
    ci = FerrarisCalibration(grav=grav, expected_angle=-360.0).compute(
        regions, sampling_rate_hz=fs, from_acc_unit="m/s^2", from_gyr_unit="deg/s")
    a_cal = LinearCal(np.linalg.inv(ci.K_a @ ci.R_a) * G0 / grav, ci.b_a / G0)
    g_cal = LinearCal(np.linalg.inv(ci.K_g @ ci.R_g), np.radians(ci.b_g))
    return a_cal, g_cal


def imu_tk_factory(k: np.ndarray, m: np.ndarray | None, offset: np.ndarray, unit: float = 1.0) -> LinearCal:
    """A factory calibration ``f = M^-1 K^-1 (raw - offset) / unit`` (imu_tk's Xsens README form;
    ``m = None``: the datasheet's diagonal ``K`` alone).

    Args:
        k: (3, 3) scale matrix ``K`` (LSB per factory unit).
        m: (3, 3) misalignment matrix ``M``; None: ``K`` alone.
        offset: (3,) bias (LSB).
        unit: size of the recording's unit in the factory's unit (e.g. local ``g`` in m/s^2 for data in g).
    """
    km = k if m is None else k @ m
    return LinearCal(np.linalg.inv(km) / unit, offset)


def tedaldi_published(params_acc: np.ndarray, params_gyr: np.ndarray) -> tuple[LinearCal, LinearCal]:
    """tomisuarez2/ImuCalibration's published Tedaldi parameters (``params_acc.csv``,
    ``params_gyro.csv``): ``a = T K (raw + bias)`` in m/s^2 (bias added), ``w = T K (raw - bias)`` in
    rad/s; returned for accelerometer data in g.

    Args:
        params_acc: (9,) accelerometer row of ``params_acc.csv``: 3 misalignments, 3 scales, 3 biases.
        params_gyr: (12,) gyroscope row of ``params_gyro.csv``: 6 misalignments, 3 scales, 3 biases.
    """
    pa, pg = params_acc, params_gyr
    ta = np.array([[1, -pa[0], pa[1]], [0, 1, -pa[2]], [0, 0, 1]])
    tg = np.array([[1, -pg[0], pg[1]], [pg[2], 1, -pg[3]], [-pg[4], pg[5], 1]])
    return LinearCal(ta @ np.diag(pa[3:6]) / G0, -pa[6:9]), LinearCal(tg @ np.diag(pg[6:9]), pg[9:12])


def datasheet(lsb_per_unit: float, bias: np.ndarray | float = 0.0) -> LinearCal:
    """A datasheet calibration: nominal sensitivity (LSB per g or per rad/s) and a bias (LSB).

    Args:
        lsb_per_unit: nominal sensitivity (LSB per g or per rad/s).
        bias: (3,) or scalar bias (LSB).
    """
    return LinearCal(np.eye(3) / lsb_per_unit, bias if np.ndim(bias) else np.full(3, float(bias)))
