"""What the poses determine: relative singular values of the multipos fits' first-order designs.

:func:`observability` reads them at a fit; :func:`check_observable` refuses a recording that
leaves a combination below :data:`OBSERVABLE_TOL`, saying what to record.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxcal.multipos.data import OBSERVABLE_TOL, MultiposData, VerticalTurns
from jaxcal.precision import float64
from jaxcal.rotation import hat
from jaxcal.sensor import LinearCal

__all__ = ["Observability", "observability", "check_observable"]


class Observability(NamedTuple):
    """What the poses determine, at a fit (numpy). ``acc_sv`` (6,): singular values, relative to the
    largest, of the accelerometer's first-order design ``[u * u, u]`` (rows: the calibrated
    gravity direction ``u`` of each pose in use; columns: the three scales and three biases that
    ``| |f| - 1 |`` sees; the cross-axis terms are held by the ridge). ``gyr_sv`` (9,): the same for
    the gyro matrix ``G``, from the first-order rows ``[u_{j+1}]_x (Y_j^T kron I)`` of every usable
    transition (``Y_j`` its integrated calibrated rate; the gravity direction is blind to the
    rotation about itself) and ``Y_k^T kron I`` of every vertical turn. ``spread_deg``: largest
    angle between a pose's raw (uncalibrated) output direction and their mean."""

    acc_sv: np.ndarray
    gyr_sv: np.ndarray
    spread_deg: float


@float64
def observability(data: MultiposData, acc: LinearCal, gyr: LinearCal, *, acc_w: np.ndarray | None = None,
                  gyr_w: np.ndarray | None = None, turns: VerticalTurns | None = None) -> Observability:
    """:class:`Observability` of the calibrations ``acc`` and ``gyr`` (e.g. a fit's) on ``data``
    (weights as in :func:`~jaxcal.multipos.fit.fit_prepared`; a zero leaves a pose or transition
    out). A relative singular value near 0 is a parameter combination the recording does not
    determine: the fit put it wherever the start or the ridge left it.

    Args:
        data: prepared poses and transitions.
        acc: accelerometer calibration (the gravity directions are read through it).
        gyr: gyroscope calibration (the point the gyro design is linearised at).
        acc_w: (P,) weight per pose (default ones).
        gyr_w: (J,) weight per transition (default ones).
        turns: optional :class:`~jaxcal.multipos.data.VerticalTurns` (their rows join the gyro design).
    """
    a, b = np.asarray(acc.A), np.asarray(acc.b)
    g, bg = np.asarray(gyr.A), np.asarray(gyr.b)
    P = len(data.pose_acc)
    aw = np.ones(P) if acc_w is None else np.asarray(acc_w)
    gw = (np.ones(P - 1) if gyr_w is None else np.asarray(gyr_w)) * np.asarray(data.seg_ok)
    f = (np.asarray(data.pose_acc) - b) @ a.T
    u = f / np.linalg.norm(f, axis=1, keepdims=True)
    ua = u[aw > 0]
    acc_sv = np.linalg.svd(np.concatenate([ua * ua, ua], 1), compute_uv=False)
    raw = np.asarray(data.pose_acc)[aw > 0]  # as the sensor reads them: a bad fit cannot spread them
    raw = raw / np.linalg.norm(raw, axis=1, keepdims=True)
    mean = raw.mean(0) / max(np.linalg.norm(raw.mean(0)), 1e-12)
    spread = float(np.degrees(np.arccos(np.clip(raw @ mean, -1.0, 1.0))).max())
    rows = [np.zeros((1, 9))]
    sy, sdt = np.asarray(data.sy).sum(1), np.asarray(data.sdt).sum(1)
    u_next = np.asarray(hat(jnp.asarray(u[1:])))
    for j in np.flatnonzero(gw > 0):
        y = (sy[j] - bg * sdt[j]) @ g.T
        rows.append(u_next[j] @ np.kron(y[None, :], np.eye(3)))
    if turns is not None:
        for k in np.flatnonzero(np.asarray(turns.seg_ok)):
            y = (np.asarray(turns.y_int[k]) - bg * float(turns.dt_sum[k])) @ g.T
            rows.append(np.kron(y[None, :], np.eye(3)))
    gyr_sv = np.linalg.svd(np.concatenate(rows), compute_uv=False)
    rel = lambda x: x / x[0] if x[0] > 0 else x  # noqa: E731
    return Observability(rel(acc_sv), rel(gyr_sv), spread)


def check_observable(obs: Observability, tol: float = OBSERVABLE_TOL) -> None:
    """Raise ``ValueError`` (saying what is missing and what to record) when a relative singular
    value of :class:`Observability` is below ``tol``: a calibration with undetermined parameters
    would be written as if it were one.

    Args:
        obs: :func:`observability` of the fit.
        tol: relative singular value below which a combination counts as undetermined.
    """
    msgs = []
    n_acc = int((obs.acc_sv < tol).sum())
    if n_acc:
        msgs.append(f"the static poses leave {n_acc} of the accelerometer's 6 scale/bias combinations undetermined "
                    f"(relative singular values {np.array2string(obs.acc_sv, precision=3)}; their raw directions lie "
                    f"within {obs.spread_deg:.1f} deg of their mean): hold the IMU still in at least six directions, "
                    "e.g. on each of its six faces")
    n_gyr = int((obs.gyr_sv < tol).sum())
    if n_gyr:
        msgs.append(f"the rotations between the poses leave {n_gyr} of the gyro matrix's 9 combinations undetermined "
                    f"(relative singular values {np.array2string(obs.gyr_sv, precision=3)}): turn the IMU about each of "
                    "its axes between poses, or add whole turns about the vertical (--turns)")
    if msgs:
        raise ValueError(f"cannot calibrate this recording: {'; '.join(msgs)} (tolerance {tol})")
