"""Input normalisation of raw counts into [-1, 1] (thesis eq. 3.6-3.7)."""

from __future__ import annotations

from typing import NamedTuple

from jaxtyping import Array, Float

from jaxcal.sensor import Diag


class Bounds(NamedTuple):
    """Raw-count reading at the negative (``lo``) and positive (``hi``) end of the range."""

    lo: Float[Array, "3"]
    hi: Float[Array, "3"]


def bounds_from_spec(spec: Diag, full_range: float) -> Bounds:
    """Eq. 3.6: ``a_max = r s + b``, ``a_min = -r s + b`` for a sensor of range ``+-r`` units.

    ``full_range`` is 2 (g) for the thesis's accelerometer, 250 deg/s in rad/s for the gyroscope.
    """
    return Bounds(lo=-full_range * spec.s + spec.b, hi=full_range * spec.s + spec.b)


def normalise(y: Float[Array, "... 3"], bounds: Bounds) -> Float[Array, "... 3"]:
    """Eq. 3.7: ``y_norm = 2 (y - a_min) / (a_max - a_min) - 1``."""
    return 2.0 * (y - bounds.lo) / (bounds.hi - bounds.lo) - 1.0


def denormalise(u: Float[Array, "... 3"], bounds: Bounds) -> Float[Array, "... 3"]:
    """Inverse of :func:`normalise`."""
    return (u + 1.0) * 0.5 * (bounds.hi - bounds.lo) + bounds.lo
