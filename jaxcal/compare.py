"""Paired comparison of two calibrations scored on the same items (poses, motions, sequences).

A table that lists one mean per method hides whether a difference is larger than the spread of
the items it averages. :func:`paired_comparison` answers that for per-item errors ``a`` (method
under test) and ``b`` (the peer) scored on the same items: the mean and median of ``a - b``, a
bootstrap confidence interval of each (items resampled with replacement, pairs kept together),
and an exact two-sided sign test of "neither method is more often better".
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from jaxcal.arrays import Array

__all__ = [
    "PairedComparison",
    "sign_test_p",
    "paired_comparison",
]


class PairedComparison(NamedTuple):
    """``a - b`` over ``n`` paired items: ``mean_diff`` and ``median_diff`` (difference of the two
    medians), their bootstrap percentile intervals ``ci_mean`` / ``ci_median`` at ``level``,
    ``wins`` (items where ``a < b``), ``losses`` (``a > b``) and the sign test's ``sign_p``."""

    n: int
    mean_diff: float
    median_diff: float
    ci_mean: tuple[float, float]
    ci_median: tuple[float, float]
    wins: int
    losses: int
    sign_p: float
    level: float

    def verdict(self, stat: str = "mean") -> str:
        """``"better"`` / ``"worse"`` when the interval of ``stat`` (``"mean"`` or ``"median"``)
        excludes 0, else ``"tie"`` (the items cannot tell the two apart)."""
        lo, hi = self.ci_mean if stat == "mean" else self.ci_median
        return "better" if hi < 0 else "worse" if lo > 0 else "tie"


def sign_test_p(wins: int, losses: int) -> float:
    """Exact two-sided sign test (ties dropped): ``P(min count <= observed)`` under p = 1/2.

    Args:
        wins: items where the method under test is better (``a < b``).
        losses: items where it is worse (``a > b``); ties are not counted.
    """
    n = wins + losses
    if n == 0:
        return 1.0
    k = min(wins, losses)
    return min(1.0, 2.0 * sum(math.comb(n, i) for i in range(k + 1)) / 2.0**n)


@partial(jax.jit, static_argnames=("n_boot",))
def _bootstrap(key: Array, a: Float[Array, " N"], b: Float[Array, " N"], n_boot: int) -> tuple[Array, Array]:
    idx = jax.random.randint(key, (n_boot, a.shape[0]), 0, a.shape[0])
    ra, rb = a[idx], b[idx]
    return jnp.mean(ra - rb, axis=1), jnp.median(ra, axis=1) - jnp.median(rb, axis=1)


def paired_comparison(a: Float[Array, " Na"], b: Float[Array, " Nb"], key: Array, n_boot: int = 10000,
                      level: float = 0.95) -> PairedComparison:
    """Compare per-item errors ``a`` and ``b`` (same items, same order; NaNs not allowed).

    Args:
        a: (N,) errors of the method under test.
        b: (N,) errors of the peer on the same items.
        key: PRNG key of the bootstrap.
        n_boot: bootstrap resamples.
        level: confidence level of the intervals.
    """
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape or a.ndim != 1 or len(a) < 2:
        raise ValueError(f"paired_comparison needs two 1-D arrays of the same length >= 2, got {a.shape} and {b.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError("paired_comparison: errors must be finite (drop unscored items first)")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    m, md = (np.asarray(x) for x in _bootstrap(key, jnp.asarray(a), jnp.asarray(b), n_boot))
    q = [(1 - level) / 2, (1 + level) / 2]
    d = a - b
    wins, losses = int(np.sum(d < 0)), int(np.sum(d > 0))
    return PairedComparison(len(a), float(d.mean()), float(np.median(a) - np.median(b)),
                            tuple(float(x) for x in np.quantile(m, q)), tuple(float(x) for x in np.quantile(md, q)),
                            wins, losses, sign_test_p(wins, losses), level)
