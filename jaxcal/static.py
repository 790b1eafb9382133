"""Static-interval detection as in imu_tk (Tedaldi, Pretto, Menegatti, ICRA 2014).

The detector looks at the accelerometer only. For each sample it takes the per-axis variance of
the accelerometer over a centred sliding window of ``2 h + 1`` samples and its magnitude
``|var| = sqrt(var_x^2 + var_y^2 + var_z^2)``. The threshold is ``k`` times the same magnitude
computed over an initial rest period (the first ``init_duration`` seconds, which the user keeps
still); samples below it are static, and runs of static samples at least ``min_duration`` long
form the intervals. imu_tk scans ``k`` (1, 2, ..., 10) and keeps the ``k`` whose intervals give
the smallest accelerometer calibration residual; :func:`threshold_scan` returns the candidates and
the caller (e.g. :func:`jaxcal.multipos.fit_multipos_recording`) makes that choice.

:func:`moving_mean` and :func:`moving_variance` are pure JAX; turning a mask into intervals has data-dependent output size
and is plain numpy. Intervals are ``(K, 2)`` int arrays of ``[start, stop)`` sample indices.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.precision import float64

__all__ = [
    "StaticDetection",
    "moving_mean",
    "moving_variance",
    "intervals_from_mask",
    "detect_static",
    "rest_gyr_baseline",
    "threshold_scan",
    "static_mask",
    "initial_rest_bias",
    "REST_GYR_STD_MAX",
]


class StaticDetection(NamedTuple):
    """One detector run: ``intervals`` (K, 2) ``[start, stop)``, the per-sample variance magnitude
    ``var_mag`` (N,) (input unit squared), the ``threshold`` and the multiplier ``k`` used."""

    intervals: np.ndarray
    var_mag: np.ndarray
    threshold: float
    k: float


@jax.jit
def _cumsum0(x: Float[Array, "N ..."]) -> Float[Array, "N+1 ..."]:
    return jnp.concatenate([jnp.zeros_like(x[:1]), jnp.cumsum(x, axis=0)], axis=0)


def moving_mean(x: Float[Array, "N ..."], half: int) -> Float[Array, "N ..."]:
    """Mean over the centred window ``[n - half, n + half]`` (clipped at the ends), along axis 0,
    from cumulative sums.

    Args:
        x: (N, ...) signal, averaged along axis 0.
        half: half-width of the window (samples).
    """
    x = jnp.asarray(x)
    n = x.shape[0]
    c = _cumsum0(x)
    idx = jnp.arange(n)
    lo = jnp.clip(idx - half, 0, n)
    hi = jnp.clip(idx + half + 1, 0, n)
    cnt = (hi - lo).astype(x.dtype).reshape((n,) + (1,) * (x.ndim - 1))
    return (c[hi] - c[lo]) / cnt


def moving_variance(x: Float[Array, "N 3"], half: int) -> Float[Array, "N 3"]:
    """Per-axis variance over the centred window ``[n - half, n + half]`` (clipped at the ends).

    Computed from cumulative sums of the mean-removed signal (float64 advisable for raw counts).

    Args:
        x: (N, 3) signal, e.g. the accelerometer (any unit).
        half: half-width of the window (samples).
    """
    x = jnp.asarray(x)
    x = x - jnp.mean(x, axis=0)
    mean = moving_mean(x, half)
    return jnp.maximum(moving_mean(x * x, half) - mean * mean, 0.0)


def intervals_from_mask(mask: np.ndarray, min_samples: int) -> np.ndarray:
    """Runs of ``True`` at least ``min_samples`` long as ``(K, 2)`` ``[start, stop)`` indices.

    Args:
        mask: (N,) bool, True where static.
        min_samples: shortest run kept (samples).
    """
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(np.int8))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    keep = (stops - starts) >= min_samples
    return np.stack([starts[keep], stops[keep]], axis=1).astype(np.int64).reshape(-1, 2)


@float64
def detect_static(
    t: np.ndarray,
    acc: np.ndarray,
    *,
    k: float = 2.0,
    init_duration: float = 10.0,
    window: float = 1.0,
    min_duration: float = 1.0,
    gyr: np.ndarray | None = None,
    gyr_k: float = 10.0,
    gyr_gsens: bool = False,
) -> StaticDetection:
    """imu_tk's detector with one threshold multiplier ``k``.

    imu_tk looks at the accelerometer only, so a turn about the vertical (gravity stays put)
    passes for rest. With ``gyr`` given, a sample is also required to have a window-mean
    ``|gyr - b|`` below ``gyr_k`` times the gyro noise, which cuts such turns out; ``b`` is the
    median gyro output over the accelerometer-static samples and the noise (norm of the per-axis
    std) is estimated robustly there from sample-to-sample differences (1.4826 MAD / sqrt 2), so a
    hand still moving during the initial period does not inflate it. With ``gyr_gsens`` the rest
    output may depend on the pose (a gyro g-sensitivity): ``b`` is then :func:`rest_gyr_baseline`,
    the gyro output at rest as an affine function of the accelerometer's direction.

    Args:
        t: (N,) sample times (s).
        acc: (N, 3) accelerometer (any unit; raw counts fine).
        k: threshold = ``k`` x the variance magnitude of the initial rest period.
        init_duration: length (s) of the initial rest period the user kept still. It is always
            returned as the first interval (imu_tk does the same), unless the gyro gate (below)
            finds it moving.
        window: sliding-window length (s).
        min_duration: shortest static interval kept (s).
        gyr: optional (N, 3) gyroscope (any unit), see above.
        gyr_k: gyro threshold multiplier.
        gyr_gsens: let the gyro's rest output follow the pose (see above).

    Returns:
        :class:`StaticDetection`.
    """
    t = np.asarray(t, np.float64)
    dt = float(np.median(np.diff(t)))
    half = max(1, int(round(0.5 * window / dt)))
    a = jnp.asarray(np.asarray(acc, np.float64))
    var = np.asarray(moving_variance(a, half))
    var_mag = np.linalg.norm(var, axis=1)
    n_init = int(np.searchsorted(t, t[0] + init_duration))
    if n_init < 2 * half + 1:
        raise ValueError(f"the initial rest (--init-duration) {init_duration:g} s holds fewer samples than one moving-variance "
                         f"window (--rest-window) {window:g} s")
    init_var = np.var(np.asarray(acc, np.float64)[:n_init], axis=0)
    threshold = float(k * np.linalg.norm(init_var))
    mask = var_mag < threshold
    mask[:n_init] = True
    if gyr is not None:  # applies to the initial period too
        g = np.asarray(gyr, np.float64)
        still = mask.copy()  # accelerometer-static, initial period included
        dg = np.abs(np.diff(g, axis=0))[still[1:] & still[:-1]]
        sigma = float(np.linalg.norm(1.4826 * np.median(dg, axis=0) / np.sqrt(2.0)))
        if gyr_gsens:
            b = rest_gyr_baseline(g, np.asarray(acc, np.float64), still, gyr_k * max(sigma, 1e-12))
        else:
            b = np.median(g[still], axis=0)
        dev = np.asarray(moving_mean(jnp.asarray(np.linalg.norm(g - b, axis=1)), half))
        mask &= dev < gyr_k * max(sigma, 1e-12)
    iv = intervals_from_mask(mask, max(1, int(round(min_duration / dt))))
    return StaticDetection(iv, var_mag, threshold, float(k))


def rest_gyr_baseline(gyr: np.ndarray, acc: np.ndarray, still: np.ndarray, gate: float, steps: int = 3) -> np.ndarray:
    """The gyro's output at rest as ``b + H a / |a|`` (``a`` the accelerometer), per sample: the
    pose-dependent rest output of a gyro with a g-sensitivity, fitted by least squares on the
    accelerometer-still samples, trimmed: a sample whose residual exceeds
    ``max(gate, 5 median residual)`` (e.g. a turn about the vertical, which the accelerometer
    cannot see) is left out, starting from the median output (``H = 0``), ``steps`` times.

    Args:
        gyr: (N, 3) gyroscope output.
        acc: (N, 3) accelerometer output (any unit; only its direction is used).
        still: (N,) accelerometer-still samples.
        gate: residual norm below which a sample always counts as rest (gyro units).
        steps: trimming rounds.
    """
    x = np.concatenate([np.ones((len(acc), 1)), acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-300)], 1)
    base = np.broadcast_to(np.median(gyr[still], axis=0), gyr.shape)
    for _ in range(steps):
        r = np.linalg.norm(gyr - base, axis=1)
        keep = still & (r < max(gate, 5.0 * float(np.median(r[still]))))
        if keep.sum() < 8:
            break
        base = x @ np.linalg.lstsq(x[keep], gyr[keep], rcond=None)[0]
    return base


def threshold_scan(
    t: np.ndarray, acc: np.ndarray, ks: Sequence[float] = tuple(range(1, 11)), **kwargs
) -> list[StaticDetection]:
    """:func:`detect_static` for each multiplier in ``ks`` (imu_tk scans 1..10).

    Args:
        t: (N,) sample times (s).
        acc: (N, 3) accelerometer (any unit).
        ks: threshold multipliers to try.
        **kwargs: the other keyword arguments of :func:`detect_static`.
    """
    return [detect_static(t, acc, k=k, **kwargs) for k in ks]


def static_mask(n: int, intervals: np.ndarray) -> np.ndarray:
    """(N,) bool mask of the samples inside ``intervals``.

    Args:
        n: number of samples ``N``.
        intervals: (K, 2) ``[start, stop)`` sample ranges.
    """
    m = np.zeros(n, bool)
    for a, b in np.asarray(intervals).reshape(-1, 2):
        m[a:b] = True
    return m


REST_GYR_STD_MAX = 0.02  # rad/s (1.1 deg/s) per axis: a stretch whose gyro varies more is no rest


def initial_rest_bias(t: np.ndarray, gyr: np.ndarray, seconds: float) -> np.ndarray:
    """The gyroscope's start-up bias of this power-up: the mean of its calibrated output (rad/s)
    over the first ``seconds`` of the recording, which must be at rest (the Earth's rate, at most
    7.3e-5 rad/s, is left in). A gyro's bias changes at every power-up (the MPU-6050's by up to
    0.10 deg/s on its next recording), so this is the usual fix for a bias fitted on another
    recording.

    Args:
        t: (N,) sample times (s).
        gyr: (N, 3) calibrated gyroscope output (rad/s).
        seconds: the length of the initial rest (s), > 0.

    Raises:
        ValueError: fewer than 2 samples in the stretch, or a per-axis standard deviation above
            :data:`REST_GYR_STD_MAX` (the device moved).
    """
    t = np.asarray(t, np.float64)
    g = np.asarray(gyr, np.float64)[t - t[0] < seconds]
    if len(g) < 2:
        raise ValueError(f"the first {seconds:g} s hold {len(g)} sample(s); a rest needs two or more")
    sd = g.std(axis=0)
    if sd.max() > REST_GYR_STD_MAX:
        raise ValueError(f"the first {seconds:g} s are not at rest: the calibrated gyro varies by "
                         f"{np.degrees(sd.max()):.3g} deg/s (std; at most {np.degrees(REST_GYR_STD_MAX):.2g} at rest)")
    return g.mean(axis=0)
