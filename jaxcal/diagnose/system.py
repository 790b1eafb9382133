"""The data a sensor's diagnosis works on, and the whitened least-squares systems of its tests.

:class:`SensorData` (one sensor of a prepared recording), :class:`SelectConfig` (test level and
search settings), :class:`System` (whitened Gram matrices per time block, :func:`build_system`)
and its solves (:func:`rss`). Re-exported from :mod:`jaxcal.diagnose.select`, where they lived.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxcal.diagnose import effects as E
from jaxcal.diagnose.whiten import ARModel, apply_filter, fill_index, gap_ok, row_ok

__all__ = ["SensorData", "SelectConfig", "System", "build_system", "rss"]


class SensorData(NamedTuple):
    """One sensor of a recording, ready for diagnosis (numpy, float64).

    ``y``: (N, 3) output in physical units via the spec values (``raw = y * spec_scale +
    spec_bias``); ``raw``: (N, 3) counts (LSB) or None when the recording is already physical;
    ``inp``: :class:`~jaxcal.diagnose.effects.Inputs`; ``valid``: (N,) bool; ``block``: (N,) int
    contiguous time-block id used for cross-validation.
    """

    sensor: str
    y: np.ndarray
    raw: np.ndarray | None
    spec_scale: np.ndarray
    spec_bias: np.ndarray
    inp: E.Inputs
    valid: np.ndarray
    block: np.ndarray
    has_temp: bool


class SelectConfig(NamedTuple):
    """Test level and search settings of :func:`jaxcal.diagnose.core.diagnose_sensor`.

    Host-side settings: the selection runs in numpy, so no field is traced or compiled.

    Attributes:
        alpha: family-wise false-discovery level per recording (Bonferroni over its candidates).
        power: detection probability that defines the minimum detectable size.
        max_lag_s: coarse time-offset search range (s).
        max_ar_order: largest AR order of the noise model.
        confound_threshold: canonical correlation above which two effects are called confounded.
        max_passes: noise-model / selection iterations.
        rw_pooled: one random-walk level per sensor (its axes share it).
        rw_slack: profile log-likelihood slack of that level (1.92: upper end of a ~95 % interval).
        random_walk: allow the random-walk stage in the noise model; off for rows that are separate
            rests (a walk across the gaps between rests would take each rest's level for noise).
        band_pool: effects whose intervals include the disagreement of their frequency bands
            (:mod:`jaxcal.diagnose.band_pool`); the reference-free mode pools the accelerometer's
            motion effects, which unmodelled translational acceleration can move.
        exclude: effects not tested in this mode (``clock_skew`` against the IMU's own gyroscope,
            which shares the accelerometer's clock).
        huber: outlier threshold (robust sd) of the joint refit's one Huber-reweighted pass
            (:func:`jaxcal.diagnose.refit.refit`: mocap glitches, shocks); None: plain least squares.
            The reference-free mode uses None: its heavy tails are the motion's own translational
            acceleration, and one reweighting pass from a solve that can stop at its step cap is not
            equivariant (measured on BROAD 07 20-50 s: a concealed 2.5 ms delay read 2.90 ms with
            the pass, 2.47 ms without; ``results/field_diagnose.md``).
    """

    alpha: float = 0.05  # family-wise false-discovery level per recording (Bonferroni)
    power: float = 0.8  # power that defines the minimum detectable size
    max_lag_s: float = 0.5  # coarse time-offset search range (s)
    max_ar_order: int = 64
    confound_threshold: float = 0.95
    max_passes: int = 3
    rw_pooled: bool = True  # one random-walk level per sensor (axes share it)
    rw_slack: float = 1.92  # upper end of the ~95 % profile interval of that level (conservative)
    random_walk: bool = True  # False: AR noise model only (rows that are separate rests)
    band_pool: tuple[str, ...] = ()  # effects whose intervals count their between-band variance
    exclude: tuple[str, ...] = ()  # effects not tested (without a reference: clock_skew, one clock)
    huber: float | None = 3.0  # joint refit's Huber threshold (robust sd); None: plain least squares


# ----------------------------------------------------------------------------- systems


class System(NamedTuple):
    """Normal equations per time block: whitened (``G``, ``g``, ``zz``: (K, Q, Q), (K, Q), (K,))
    and unwhitened (``Gu``, ``gu``, ``zzu``, physical units) with row counts ``nu`` (K,)."""

    G: np.ndarray
    g: np.ndarray
    zz: np.ndarray
    Gu: np.ndarray
    gu: np.ndarray
    zzu: np.ndarray
    nu: np.ndarray

    @property
    def G_all(self) -> np.ndarray:
        return self.G.sum(0)

    @property
    def g_all(self) -> np.ndarray:
        return self.g.sum(0)

    @property
    def zz_all(self) -> float:
        return float(self.zz.sum())


def build_system(x: np.ndarray, z: np.ndarray, ars: list[ARModel], fit_rows: np.ndarray, block: np.ndarray) -> System:
    """Whiten each axis of ``x`` (N, 3, Q) and ``z`` (N, 3) with its AR model; Grams per block.

    A whitened row belongs to a block only if its whole filter window lies inside that block.

    Args:
        x: (N, 3, Q) regressors.
        z: (N, 3) residual.
        ars: per-axis noise models (3).
        fit_rows: (N,) bool, the rows used.
        block: (N,) int time-block ids.
    """
    q = x.shape[2]
    nb = int(block.max()) + 1
    G, g, zz = np.zeros((nb, q, q)), np.zeros((nb, q)), np.zeros(nb)
    Gu, gu, zzu, nu = np.zeros((nb, q, q)), np.zeros((nb, q)), np.zeros(nb), np.zeros(nb)
    fi = fill_index(fit_rows)
    for i in range(3):
        xi = np.where(fit_rows[:, None], x[:, i, :], 0.0)
        zi = np.where(fit_rows, z[:, i], 0.0)
        xw = apply_filter(x[fi, i, :], ars[i])
        zw = apply_filter(z[fi, i], ars[i])
        ok = gap_ok(fit_rows, ars[i].memory)
        for k in range(nb):
            inb = block == k
            rows = ok & row_ok(inb, ars[i].order)
            a, b = xw[rows], zw[rows]
            G[k] += a.T @ a
            g[k] += a.T @ b
            zz[k] += float(b @ b)
            rows = fit_rows & inb
            a, b = xi[rows], zi[rows]
            Gu[k] += a.T @ a
            gu[k] += a.T @ b
            zzu[k] += float(b @ b)
            nu[k] += rows.sum()
    return System(G, g, zz, Gu, gu, zzu, nu)


def _solve(G: np.ndarray, g: np.ndarray, cols: list[int]) -> np.ndarray:
    """Least squares from normal equations on ``cols``; columns the whitening annihilated (e.g.
    the bias under a random-walk noise model) get 0 and are left to the caller."""
    a = G[np.ix_(cols, cols)]
    d = np.diag(a)
    keep = d > 1e-12 * max(float(d.max()), 1e-300)
    th = np.zeros(len(cols))
    if keep.any():
        ak = a[np.ix_(keep, keep)]
        scale = np.sqrt(np.diag(ak))
        an = ak / scale[:, None] / scale[None, :]
        th[keep] = np.linalg.lstsq(an + 1e-12 * np.eye(int(keep.sum())), g[cols][keep] / scale, rcond=None)[0] / scale
    return th


def rss(G: np.ndarray, g: np.ndarray, zz: float, cols: list[int], th: np.ndarray) -> float:
    """Residual sum of squares ``|z - X_cols th|^2`` from the normal equations.

    Args:
        G: (Q, Q) Gram ``X^T X``.
        g: (Q,) ``X^T z``.
        zz: ``z^T z``.
        cols: the columns in the model.
        th: the solution on ``cols``.
    """
    return float(zz - 2.0 * th @ g[cols] + th @ G[np.ix_(cols, cols)] @ th)
