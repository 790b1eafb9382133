"""Independent checks of a gyroscope calibration on recordings with no labels.

Both checks integrate the calibrated gyro (Magnus blocks of :func:`jaxcal.multipos.prepare`) from
the first rest to the last and compare the carried rotation with what the recording's protocol
says: a ~90 deg turn about one axis (:func:`rotation_check`), or the return to the start pose of a
hand-held recording (:func:`loop_closure_deg`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal import multipos as mp
from jaxcal.precision import float64
from jaxcal.rotation import log_so3
from jaxcal.sensor import LinearCal

__all__ = ["carried_rotation", "rotation_check", "loop_closure_deg", "static_norm_error_mg"]


@float64
def carried_rotation(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, gyr_A, bias, rest: int, block: int) -> np.ndarray:
    """Rotation (3, 3) carried by the calibrated gyro ``w = A (y - bias)`` from the first ``rest``
    samples to the last ``rest`` samples (physical convention, float64).

    Args:
        t, acc, gyr: the recording (time in s, (N, 3) outputs).
        gyr_A: (3, 3) gyro calibration matrix (applied form).
        bias: (3,) gyro bias in the gyro's units.
        rest: samples at each end treated as the two rests.
        block: samples per Magnus block.
    """
    iv = np.array([[0, rest], [len(t) - rest, len(t)]])
    d = mp.prepare(t, acc, gyr, iv, block=block)
    dj = jax.tree_util.tree_map(jnp.asarray, d)
    rv = mp.block_rotvecs(jnp.asarray(gyr_A), jnp.asarray(bias, jnp.float64), jnp.zeros((3, 3)), dj, jnp.zeros_like(dj.sy))
    return np.asarray(mp.carry_rotation(rv, jnp.ones_like(dj.sdt)))[0]


@float64
def _rotvec(rot: np.ndarray) -> np.ndarray:
    return np.asarray(log_so3(jnp.asarray(rot)))


def static_norm_error_mg(acc_cal: LinearCal, acc: np.ndarray) -> float:
    """``abs(|mean f| - 1 g)`` in mg of a static recording's calibrated accelerometer.

    Args:
        acc_cal: accelerometer calibration (applied form, to g).
        acc: (N, 3) accelerometer outputs of a static recording (its units).
    """
    f = (acc - acc_cal.b) @ np.asarray(acc_cal.A).T
    return float(1e3 * abs(np.linalg.norm(f.mean(0)) - 1.0))


def rotation_check(acc_cal: LinearCal, gyr_cal: LinearCal, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray,
                   rest: int = 100, bias_samples: int = 300, block: int = 8) -> dict:
    """A turn between two rests (e.g. the MPU-6050's ~90 deg about x): the gyro's rotation vector, its
    angle and how far off the x axis it lies, and the angle between the gravity of the first rest
    carried by the gyro and the gravity measured at the last (deg).

    The gyro bias is the mean of the first ``bias_samples`` samples (the recording's own rest);
    gravity directions are the calibrated accelerometer's means over the first and last ``rest``.

    Args:
        acc_cal: accelerometer calibration (applied form, to g).
        gyr_cal: gyroscope calibration (applied form); only ``A`` is used, the bias comes from the first rest.
        t: (N,) times (s).
        acc, gyr: (N, 3) outputs (the recording's units).
        rest: samples at each end treated as the two rests.
        bias_samples: leading samples averaged for the gyro bias.
        block: samples per Magnus block.
    """
    a = (acc - acc_cal.b) @ np.asarray(acc_cal.A).T
    u0, u1 = a[:rest].mean(0), a[-rest:].mean(0)
    u0, u1 = u0 / np.linalg.norm(u0), u1 / np.linalg.norm(u1)
    bias = gyr[:bias_samples].mean(0)
    rot = carried_rotation(t, acc, gyr, gyr_cal.A, bias, rest, block)
    rotvec = np.degrees(_rotvec(rot))
    pred = rot.T @ u0
    return {
        "rotation_deg": rotvec.round(2).tolist(),
        "carried_gravity_err_deg": float(np.degrees(np.arccos(np.clip(pred @ u1, -1, 1)))),
        "angle_deg": float(np.linalg.norm(rotvec)),
        "off_axis_deg": float(np.degrees(np.arccos(np.clip(abs(rotvec[0]) / np.linalg.norm(rotvec), -1, 1)))),
    }


def loop_closure_deg(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, bias, rest: int = 100, block: int = 4) -> float:
    """Angle (deg) of the rotation the gyro (as recorded, minus ``bias``) integrates from the first
    rest to the last: zero for a device that returns to its start pose.

    Args:
        t: (N,) times (s).
        acc, gyr: (N, 3) outputs; the gyro in rad/s (applied as recorded, ``A = I``).
        bias: (3,) gyro bias (rad/s).
        rest: samples at each end treated as the two rests.
        block: samples per Magnus block.
    """
    return float(np.degrees(np.linalg.norm(_rotvec(carried_rotation(t, acc, gyr, np.eye(3), bias, rest, block)))))
