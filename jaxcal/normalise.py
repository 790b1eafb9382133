"""Input normalisation of raw counts into [-1, 1] (thesis eq. 3.6-3.7)."""

from __future__ import annotations

from typing import NamedTuple

from jaxtyping import Float, Real

from jaxcal.arrays import Array
from jaxcal.sensor import Diag

__all__ = [
    "Bounds",
    "bounds_from_spec",
    "normalise",
    "denormalise",
]


class Bounds(NamedTuple):
    """Raw-count reading at the negative (``lo``) and positive (``hi``) end of the range."""

    lo: Float[Array, "3"]
    hi: Float[Array, "3"]


def bounds_from_spec(spec: Diag, full_range: float) -> Bounds:
    """Eq. 3.6: ``a_max = r s + b``, ``a_min = -r s + b`` for a sensor of range ``+-r`` units.

    ``full_range`` is 2 (g) for the thesis's accelerometer, 250 deg/s in rad/s for the gyroscope.

    Args:
        spec: datasheet model (``s`` LSB per unit, ``b`` LSB).
        full_range: ``r`` of the ``+-r`` range, in physical units (see above).
    """
    return Bounds(lo=-full_range * spec.s + spec.b, hi=full_range * spec.s + spec.b)


def normalise(y: Real[Array, "... 3"], bounds: Bounds) -> Float[Array, "... 3"]:
    """Eq. 3.7: ``y_norm = 2 (y - a_min) / (a_max - a_min) - 1``.

    Args:
        y: (..., 3) raw counts (LSB).
        bounds: eq. 3.6 bounds of the sensor.
    """
    return 2.0 * (y - bounds.lo) / (bounds.hi - bounds.lo) - 1.0


def denormalise(u: Float[Array, "... 3"], bounds: Bounds) -> Float[Array, "... 3"]:
    """Inverse of :func:`normalise`.

    Args:
        u: (..., 3) normalised values in ``[-1, 1]``.
        bounds: the bounds used by :func:`normalise`.
    """
    return (u + 1.0) * 0.5 * (bounds.hi - bounds.lo) + bounds.lo
