"""A multi-position recording with a known calibration (the test truth of :mod:`jaxcal.multipos`).

:func:`simulate_poses`: a rest, then static poses (random, or given) joined by constant-rate body
rotations, as raw counts of an accelerometer and a gyroscope with the applied calibrations
:data:`ACC_TRUTH` and :data:`GYR_TRUTH` (or any others). Physical convention (``CONVENTIONS.md``):
``R(t) = R_j Exp(w t)`` over a move, the specific force is ``f = R^T (0, 0, 1)`` g (z up).

Pure: the rotations come from the PRNG ``key``, the white noise from the numpy seed
``noise_seed``; nothing else varies between calls. The JAX parts (random rotations, the log of
each move) run in float32, JAX's default, whatever the caller's precision setting, so the data do
not change with it; a move's per-sample rotation ``Exp(w dt)`` (:func:`jaxcal.rotation.exp_so3`) is
float64.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal.precision import float64
from jaxcal.rotation import exp_so3, log_so3, random_rotation
from jaxcal.sensor import LinearCal

__all__ = ["ACC_TRUTH", "GYR_TRUTH", "simulate_poses"]

#: applied accelerometer calibration ``x = A (y - b)`` (g/LSB, LSB): ``A = T diag(k)`` with ``T``
#: unit lower-triangular (the 9-parameter model's frame)
ACC_TRUTH = LinearCal(
    A=np.array([[1.0, 0.0, 0.0], [0.012, 1.0, 0.0], [-0.008, 0.02, 1.0]]) @ np.diag([1 / 16000, 1 / 16700, 1 / 16200]),
    b=np.array([310.0, -540.0, 820.0]),
)
#: applied gyroscope calibration (rad/s per LSB, LSB): a full matrix
GYR_TRUTH = LinearCal(
    A=np.array([[1.03, 0.01, -0.02], [-0.015, 0.97, 0.012], [0.008, 0.02, 1.01]]) / 7500.0,
    b=np.array([-420.0, 150.0, -80.0]),
)


@float64
def _exp64(v: np.ndarray) -> np.ndarray:
    """``Exp(v)`` (:func:`jaxcal.rotation.exp_so3`) of a float64 rotation vector, in float64, as numpy."""
    return np.asarray(exp_so3(jnp.asarray(v, jnp.float64)))


def simulate_poses(
    key: jax.Array | None,
    acc_cal: LinearCal = ACC_TRUTH,
    gyr_cal: LinearCal = GYR_TRUTH,
    *,
    n_poses: int = 24,
    fs: float = 100.0,
    rest: float = 10.0,
    hold: float = 2.0,
    move: float = 1.5,
    noise: bool = True,
    rots: np.ndarray | None = None,
    noise_seed: int = 0,
    gsens: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rest, then ``n_poses`` random static poses (or the given ``rots``) joined by
    constant-rate body rotations; raw ``y = A^-1 x + b`` (+ white noise) rounded to counts.

    Pose ``j`` is held ``rest`` s (the first) or ``hold`` s, then the body turns at the constant
    rate ``w = log(R_j^T R_{j+1}) / move`` for ``move`` s.

    Args:
        key: PRNG key of the random poses (pose 0 is the identity); ignored (may be ``None``)
            when ``rots`` is given.
        acc_cal: applied accelerometer calibration to simulate (default :data:`ACC_TRUTH`).
        gyr_cal: applied gyroscope calibration to simulate (default :data:`GYR_TRUTH`).
        n_poses: number of random poses (with ``key``).
        fs: sample rate (Hz).
        rest: duration of the first pose (s).
        hold: duration of every other pose (s).
        move: duration of each move between poses (s).
        noise: add white noise (std 4 LSB accelerometer, 2 LSB gyroscope) before rounding.
        rots: optional (P, 3, 3) body-to-world rotations of the poses, instead of random ones.
        noise_seed: seed of the numpy noise generator.
        gsens: optional gyroscope g-sensitivity ``G_s`` (3, 3) ((rad/s)/g): the gyroscope measures
            ``y = A^-1 (w + G_s f) + b``, ``f`` the specific force in g (the inverse of
            :func:`jaxcal.multipos.gyro.block_rotvecs`' ``w = A (y - b) - G_s f``).

    Returns:
        ``(t, acc, gyr)``: (N,) times (s) and (N, 3) raw counts (float).
    """
    dt = 1.0 / fs
    if rots is None:
        with jax.enable_x64(False):
            rots = np.asarray(random_rotation(key, (n_poses,)), np.float64)
        rots[0] = np.eye(3)
    n_poses = len(rots)
    f_list, w_list = [], []
    n_rest = int(rest * fs)
    for j in range(n_poses):
        n_hold = n_rest if j == 0 else int(hold * fs)
        f_list.append(np.tile(rots[j].T @ [0, 0, 1.0], (n_hold, 1)))
        w_list.append(np.zeros((n_hold, 3)))
        if j + 1 < n_poses:
            n_move = int(move * fs)
            with jax.enable_x64(False):
                w = np.asarray(log_so3(jnp.asarray(rots[j].T @ rots[j + 1]))) / (n_move * dt)
            r = rots[j].copy()
            step = _exp64(w * dt)
            for _ in range(n_move):
                r = r @ step
                f_list.append((r.T @ [0, 0, 1.0])[None])
                w_list.append(w[None])
    f, w = np.concatenate(f_list), np.concatenate(w_list)
    rng = np.random.default_rng(noise_seed)
    acc = f @ np.linalg.inv(np.asarray(acc_cal.A)).T + np.asarray(acc_cal.b)
    if gsens is not None:
        w = w + f @ np.asarray(gsens, np.float64).T
    gyr = w @ np.linalg.inv(np.asarray(gyr_cal.A)).T + np.asarray(gyr_cal.b)
    if noise:
        acc = acc + rng.normal(0, 4.0, acc.shape)
        gyr = gyr + rng.normal(0, 2.0, gyr.shape)
    t = np.arange(len(f)) * dt
    return t, np.round(acc), np.round(gyr)
