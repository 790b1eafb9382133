"""Multipos inputs: the static poses and the motions between them, summed once from a recording.

:func:`prepare` turns a recording plus its static intervals into :class:`MultiposData` (pose means
and the second-order Magnus block sums of every transition); :func:`prepare_known` and
:func:`prepare_turns` do the same for sections of known rotation and for whole turns about the
vertical. Numpy in, padded arrays out; everything downstream is pure JAX.
:func:`calibrated_acc_sums` (block sums of the calibrated specific force) and
:data:`OBSERVABLE_TOL` are shared by the later stages (``acc``, ``gyro``, ``fit``, ``observe``).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Bool, Float
from numpy.typing import ArrayLike

from jaxcal.arrays import Array
from jaxcal.precision import float64
from jaxcal.rotation import exp_so3
from jaxcal.sensor import LinearCal

__all__ = [
    "OBSERVABLE_TOL",
    "MultiposData",
    "prepare",
    "KnownRotations",
    "prepare_known",
    "VerticalTurns",
    "rests_around",
    "prepare_turns",
    "turns_from_times",
    "calibrated_acc_sums",
]

#: relative singular value below which a parameter combination counts as undetermined by the poses
#: (:func:`~jaxcal.multipos.observe.check_observable`, :func:`~jaxcal.multipos.acc.fit_acc_determined`)
OBSERVABLE_TOL = 0.02


class MultiposData(NamedTuple):
    """Padded arrays of one recording (see :func:`prepare`). ``P`` poses, ``J = P - 1``
    transitions of at most ``L`` blocks. Units are the recording's (raw or physical).

    A transition is cut into blocks of ``block`` samples; with ``a_i = y_i dt_i`` (the gyro's rate
    point times the step) a block stores ``sy = sum a_i``, ``sdt = sum dt_i``,
    ``c0 = sum_{i<j} a_i x a_j``, ``p1 = sum_{i<j} dt_i a_j`` and ``p2 = sum_{i<j} a_i dt_j``. For
    any calibration ``w = G (y - b)`` the block's rotation vector to second order (Magnus / BCH,
    error O(|w dt|^3) per block) is ``G (sy - b sdt) + cof(G) (c0 - b x p1 + b x p2) / 2``, using
    ``(G u) x (G v) = cof(G) (u x v)``: raw data are summed once, every fit step is cheap.
    """

    pose_acc: Float[Array, "P 3"]  # mean accelerometer output per static pose
    pose_gyr: Float[Array, "P 3"]  # mean gyroscope output per static pose
    pose_n: Float[Array, " P"]  # samples per pose
    sy: Float[Array, "J L 3"]
    sdt: Float[Array, "J L"]
    c0: Float[Array, "J L 3"]
    p1: Float[Array, "J L 3"]
    p2: Float[Array, "J L 3"]
    sacc: Float[Array, "J L 3"]  # block sums of accelerometer output * dt (g-sensitivity)
    seg_ok: Bool[Array, " J"]  # False: transition unusable (saturated gyro)


def _segment_sums(
    t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, spans: list, midpoint: bool, block: int, gyr_limit: float | None
) -> tuple[dict, np.ndarray, np.ndarray]:
    """Block sums (see :class:`MultiposData`) of the integration spans ``[a, b]`` (sample ``a`` to
    sample ``b``), padded to a common number of blocks; and the usable flag of each span."""
    J = len(spans)
    L = max(1, max(-(-(b - a) // block) for a, b in spans))
    out = {k: np.zeros((J, L, 3)) for k in ("sy", "c0", "p1", "p2", "sacc")}
    sdt = np.zeros((J, L))
    seg_ok = np.ones(J, bool)
    for j, (a, b) in enumerate(spans):
        n = b - a
        y = 0.5 * (gyr[a:b] + gyr[a + 1 : b + 1]) if midpoint else gyr[a:b]
        f = 0.5 * (acc[a:b] + acc[a + 1 : b + 1]) if midpoint else acc[a:b]
        dt = t[a + 1 : b + 1] - t[a:b]
        pad = (-n) % block
        y = np.concatenate([y, np.zeros((pad, 3))]).reshape(-1, block, 3)
        f = np.concatenate([f, np.zeros((pad, 3))]).reshape(-1, block, 3)
        dt = np.concatenate([dt, np.zeros(pad)]).reshape(-1, block)
        av = y * dt[..., None]
        ca = np.cumsum(av, axis=1) - av  # sum_{i<j} a_i, at j
        cd = (np.cumsum(dt, axis=1) - dt)[..., None]  # sum_{i<j} dt_i, at j
        nb = av.shape[0]
        out["sy"][j, :nb] = av.sum(1)
        out["c0"][j, :nb] = np.cross(ca, av).sum(1)
        out["p1"][j, :nb] = (cd * av).sum(1)
        out["p2"][j, :nb] = (ca * dt[..., None]).sum(1)
        out["sacc"][j, :nb] = (f * dt[..., None]).sum(1)
        sdt[j, :nb] = dt.sum(1)
        if gyr_limit is not None and np.any(np.abs(gyr[a : b + 1]) >= gyr_limit):
            seg_ok[j] = False
    return out, sdt, seg_ok


def prepare(
    t: np.ndarray,
    acc: np.ndarray,
    gyr: np.ndarray,
    intervals: ArrayLike,
    *,
    gyr_limit: float | None = None,
    midpoint: bool = True,
    block: int = 8,
    spans: ArrayLike | None = None,
) -> MultiposData:
    """Pose means and padded transition segments (numpy; shapes depend on the data).

    Args:
        t: (N,) times (s), increasing, uneven allowed.
        acc, gyr: (N, 3) outputs (LSB or physical).
        intervals: (P, 2) static ``[start, stop)`` sample indices, in time order.
        gyr_limit: if given, a transition with any ``|gyr| >= gyr_limit`` is marked unusable.
        midpoint: rate point of step ``n`` is ``(y_n + y_{n+1}) / 2`` (else ``y_n``).
        block: samples per integration block (1: exact per-sample product, first order).
        spans: optional (P - 1, 2) integration spans ``[a, b]`` of the transitions (default: from
            the last sample of pose ``j`` to the first of pose ``j + 1``). Pass them when the pose
            means use only part of a static hold (e.g. a time split), so that the transitions
            start and end where the body really moved.
    """
    t = np.asarray(t, np.float64)
    acc = np.asarray(acc, np.float64)
    gyr = np.asarray(gyr, np.float64)
    iv = np.asarray(intervals, np.int64).reshape(-1, 2)
    if len(iv) < 2:
        raise ValueError("multipos needs at least two static intervals")
    pose_acc = np.stack([acc[a:b].mean(0) for a, b in iv])
    pose_gyr = np.stack([gyr[a:b].mean(0) for a, b in iv])
    pose_n = (iv[:, 1] - iv[:, 0]).astype(np.float64)
    # transition j: from the last sample of pose j to the first sample of pose j + 1
    if spans is None:
        spans = [(iv[j, 1] - 1, iv[j + 1, 0]) for j in range(len(iv) - 1)]
    else:
        spans = [(int(a), int(b)) for a, b in np.asarray(spans).reshape(-1, 2)]
        if len(spans) != len(iv) - 1:
            raise ValueError(f"spans: need {len(iv) - 1} transitions, got {len(spans)}")
    out, sdt, seg_ok = _segment_sums(t, acc, gyr, spans, midpoint, block, gyr_limit)
    return MultiposData(pose_acc, pose_gyr, pose_n, out["sy"], sdt, out["c0"], out["p1"], out["p2"],
                        out["sacc"], seg_ok)


class KnownRotations(NamedTuple):
    """Sections of known body rotation (e.g. a closed 360 deg turn on a turntable or against a
    table edge): block sums as in :class:`MultiposData` for ``K`` sections, and the known rotation
    ``R`` (K, 3, 3) of each, in the physical convention: ``R = R(t_0)^T R(t_1)`` (body frame, the
    product ``prod Exp(w dt)`` the gyro must integrate to). A closed turn has ``R = I``."""

    sy: Float[Array, "K L 3"]
    sdt: Float[Array, "K L"]
    c0: Float[Array, "K L 3"]
    p1: Float[Array, "K L 3"]
    p2: Float[Array, "K L 3"]
    sacc: Float[Array, "K L 3"]
    R: Float[Array, "K 3 3"]
    seg_ok: Bool[Array, " K"]


@float64
def prepare_known(
    t: np.ndarray,
    acc: np.ndarray,
    gyr: np.ndarray,
    spans: ArrayLike,
    rotvecs: ArrayLike,
    *,
    gyr_limit: float | None = None,
    midpoint: bool = True,
    block: int = 8,
) -> KnownRotations:
    """Known-rotation sections (numpy). ``spans`` (K, 2): first and last sample ``[a, b]`` of each
    section; ``rotvecs`` (K, 3): its known body rotation vector (rad; ``exp_so3`` of it is ``R``);
    a closed turn of any whole number of revolutions is ``0`` (or ``2 pi`` times the axis).

    Args:
        t: (N,) times (s), increasing.
        acc, gyr: (N, 3) outputs (LSB or physical).
        spans: (K, 2) first and last sample ``[a, b]`` of each section.
        rotvecs: (K, 3) known body rotation vector of each section (rad).
        gyr_limit: if given, a section with any ``|gyr| >= gyr_limit`` is marked unusable.
        midpoint: midpoint rates (else the left sample).
        block: samples per integration block.
    """
    t = np.asarray(t, np.float64)
    acc = np.asarray(acc, np.float64)
    gyr = np.asarray(gyr, np.float64)
    sp = [(int(a), int(b)) for a, b in np.asarray(spans).reshape(-1, 2)]
    out, sdt, ok = _segment_sums(t, acc, gyr, sp, midpoint, block, gyr_limit)
    r = np.asarray(exp_so3(jnp.asarray(np.asarray(rotvecs, np.float64).reshape(-1, 3))))
    return KnownRotations(out["sy"], sdt, out["c0"], out["p1"], out["p2"], out["sacc"], r, ok)


class VerticalTurns(NamedTuple):
    """Whole turns about the vertical, e.g. the IMU turned flat on a table (the rotations of
    Ferraris' protocol), used **without labels**: during such a turn the body rotation axis is the
    gravity direction in the body frame and stays fixed, so the integrated rate is exactly
    ``angle * u`` (either sense), with ``u`` the unit gravity direction measured at rest next to
    the turn. Three turns about independent axes fix the gyro matrix on their own (see
    :func:`turn_init`); with gravity carrying they pin its scales about vertical axes.

    ``y_int`` (K, 3): ``sum y dt`` over the turn (midpoint rates; gyro units * s); ``dt_sum`` (K,):
    its duration; ``rest_acc`` (K, 3): mean accelerometer output at the adjacent rests;
    ``angle`` (K,): the magnitude of the turn (rad, ``2 pi`` per revolution); ``seg_ok`` (K,):
    False if the gyro saturated."""

    y_int: Float[Array, "K 3"]
    dt_sum: Float[Array, " K"]
    rest_acc: Float[Array, "K 3"]
    angle: Float[Array, " K"]
    seg_ok: Bool[Array, " K"]


def rests_around(spans: ArrayLike, n: int, gap: int, n_samples: int | None = None) -> list[list[tuple[int, int]]]:
    """Rest windows next to each span ``[a, b]``: ``n`` samples ending ``gap`` before ``a`` and ``n``
    samples starting ``gap`` after ``b`` (clipped to the recording's ``n_samples`` when given), as
    ``[start, stop)`` pairs.

    Args:
        spans: (K, 2) ``[a, b]`` of each span.
        n: samples per rest window.
        gap: samples between a span and its rest windows.
        n_samples: the recording's length, to clip to; None: no clipping at the end.
    """
    end = np.iinfo(np.int64).max if n_samples is None else n_samples
    out = []
    for a, b in np.asarray(spans, np.int64).reshape(-1, 2):
        w = [(max(0, a - gap - n), max(0, a - gap)), (min(end, b + gap + 1), min(end, b + gap + 1 + n))]
        out.append([(int(x), int(y)) for x, y in w if y > x])
    return out


def prepare_turns(
    t: np.ndarray,
    acc: np.ndarray,
    gyr: np.ndarray,
    spans: ArrayLike,
    rests: list,
    *,
    revolutions: Any = 1,
    gyr_limit: float | None = None,
    midpoint: bool = True,
) -> VerticalTurns:
    """Vertical turns (numpy). ``spans`` (K, 2): first and last sample ``[a, b]`` of each turn;
    ``rests``: per turn, a list of static ``[start, stop)`` windows whose mean accelerometer output
    gives the turning axis (e.g. :func:`rests_around`); ``revolutions``: whole turns per section
    (scalar or (K,)). Raises if a turn has no rest samples.

    Args:
        t: (N,) times (s), increasing.
        acc, gyr: (N, 3) outputs (LSB or physical).
        spans: (K, 2) first and last sample ``[a, b]`` of each turn.
        rests: per turn, a list of static ``[start, stop)`` windows giving its axis.
        revolutions: whole turns per section, scalar or (K,).
        gyr_limit: if given, a turn with any ``|gyr| >= gyr_limit`` is marked unusable.
        midpoint: midpoint rates (else the left sample).
    """
    t = np.asarray(t, np.float64)
    acc = np.asarray(acc, np.float64)
    gyr = np.asarray(gyr, np.float64)
    sp = [(int(a), int(b)) for a, b in np.asarray(spans).reshape(-1, 2)]
    if len(rests) != len(sp):
        raise ValueError(f"rests: need one list of windows per turn ({len(sp)}), got {len(rests)}")
    rest_acc = []
    for (a, b), win in zip(sp, rests):
        idx = np.concatenate([np.arange(x, y) for x, y in win]) if win else np.zeros(0, np.int64)
        if idx.size == 0:
            raise ValueError(f"turn [{a}, {b}]: no rest samples to take the turning axis from")
        rest_acc.append(acc[idx].mean(0))
    # the integrated rate sum(y dt) over a turn is the sum of its first-order block sums
    out, sdt, ok = _segment_sums(t, acc, gyr, sp, midpoint, 8, gyr_limit)
    angle = 2 * np.pi * np.broadcast_to(np.asarray(revolutions, np.float64), (len(sp),))
    return VerticalTurns(out["sy"].sum(1), sdt.sum(1), np.asarray(rest_acc), angle.copy(), ok)


def turns_from_times(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, times: Any, rest: float = 1.0,
                     gyr_limit: float | None = None) -> VerticalTurns:
    """:class:`VerticalTurns` from turn start/end times ``times`` (K, 2) in seconds; each turn's axis
    is read from ``rest`` seconds of rest just before and just after it (5 samples away).

    Args:
        t: (N,) times (s), increasing.
        acc, gyr: (N, 3) outputs (LSB or physical).
        times: (K, 2) start and end of each turn (s).
        rest: seconds of rest read on each side of a turn.
        gyr_limit: if given, a turn with any ``|gyr| >= gyr_limit`` is marked unusable.
    """
    t = np.asarray(t, np.float64)
    tt = np.asarray(times, np.float64).reshape(-1, 2)
    if np.any(tt[:, 1] <= tt[:, 0]) or tt.min() < t[0] or tt.max() > t[-1]:
        raise ValueError(f"--turns: each needs start < end inside the recording [{t[0]:.3f}, {t[-1]:.3f}] s, got {tt.tolist()}")
    spans = np.stack([np.searchsorted(t, tt[:, 0]), np.minimum(np.searchsorted(t, tt[:, 1]), len(t) - 1)], 1)
    n = max(1, int(round(rest / float(np.median(np.diff(t))))))
    return prepare_turns(t, acc, gyr, spans, rests_around(spans, n, 5, len(t)), gyr_limit=gyr_limit)


def calibrated_acc_sums(acc: LinearCal, d: MultiposData | KnownRotations) -> Float[Array, "J L 3"]:
    """Block sums of the calibrated specific force ``sum A (y_acc - b) dt`` of every transition (or
    known-rotation section) from its raw sums ``sacc`` and ``sdt``: the g-sensitivity term of the
    gyro model ``w = G (y - b) - G_s f`` (see :class:`MultiposData`). Pure JAX.

    Args:
        acc: accelerometer calibration (applied form).
        d: block sums of the transitions (:class:`MultiposData`) or sections (:class:`KnownRotations`).
    """
    return (d.sacc - acc.b * d.sdt[..., None]) @ acc.A.T
