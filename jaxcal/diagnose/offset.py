"""Stage 1 of a sensor's diagnosis: the coarse time offset, and the baseline fits it rests on.

:func:`coarse_offset` cross-correlates the sensor with its reference over ``+-max_lag_s`` (or
takes the lag another sensor on the same clock found), keeps it when the whitened baseline residual
falls significantly (a likelihood-ratio test), and refines it to a fraction of a sample; it hands
on an :class:`Offset` (the linearisation offset, the candidates, what enters the selection
preselected). :class:`Start` says where a pass starts (:mod:`jaxcal.diagnose.stages`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import stats

from jaxcal.diagnose import effects as E
from jaxcal.diagnose.select import Decision, SelectConfig, SensorData, candidates, coarse_lag, critical_value, linearize_baseline
from jaxcal.diagnose.whiten import apply_filter, fill_index, fit_ar, gap_ok

__all__ = ["Start", "Offset", "coarse_offset", "theta_with_tau", "edge_count", "edge_rows", "baseline_resid"]


class Start(NamedTuple):
    """Where one pass starts: ``lag_hint`` the coarse lag (samples) another sensor on the same
    clock found; ``relin`` ``(tau, decision)``: linearised at a refit time offset named by an
    earlier pass; ``no_offset``: the time offset dropped from the candidates (it did not lower the
    held-out rms); ``edge_shift`` (s): how far a clock skew named by an earlier pass moves the
    recording's ends on the reference's clock, trimmed from the fitted rows as well; ``skew_lin``
    ``(ppm, decision)``: linearised at that clock skew (``None``: at 0)."""

    lag_hint: int | None = None
    relin: tuple[float, Decision] | None = None
    no_offset: bool = False
    edge_shift: float = 0.0
    skew_lin: tuple[float, Decision] | None = None


class Offset(NamedTuple):
    """Stage 1: the linearisation offset ``tau_lin`` (s), the coarse search's ``(stat, log10 p)``
    when it found one, the candidates, those entering the selection preselected, warnings, and
    ``skew_lin``: the clock skew (ppm) the pass is linearised at, preselected (``None``: at 0).
    Decided here once; stages 2 and 3 read it."""

    tau_lin: float
    coarse: tuple[float, float] | None
    candidates: list[str]
    preselected: list[str]
    warnings: list[str]
    skew_lin: float | None = None


def coarse_offset(kind: str, sd: SensorData, cfg: SelectConfig, level: float, start: Start,
                  force: tuple[str, ...] = ()) -> Offset:
    """Stage 1: cross-correlation over ``+-cfg.max_lag_s`` (or another sensor's lag), then a
    likelihood-ratio check of the whitened baseline residual; refined to a fraction of a sample.

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        sd: the sensor's prepared data.
        cfg: test level and search settings.
        level: the test level (Bonferroni: ``cfg.alpha`` over the recording's tests).
        start: where this pass starts.
        force: effects estimated whatever the tests say.
    """
    s = sd.sensor
    dt = float(sd.inp.dt)
    warnings: list[str] = []
    cands = candidates(kind, sd, cfg.exclude)
    if start.no_offset:
        cands = [c for c in cands if c != "time_offset"]
    pre: list[str] = []
    tau_lin, coarse, lag = 0.0, None, 0
    if start.relin is not None:
        tau_lin = float(start.relin[0])
        pre.append("time_offset")
    elif not start.no_offset:
        x_in = np.asarray(sd.inp.f if s == "acc" else sd.inp.w)
        max_lag = int(min(cfg.max_lag_s / dt, len(sd.y) // 10))
        lag = coarse_lag(sd.y, x_in, sd.valid, max_lag)
        if start.lag_hint is not None and abs(start.lag_hint) <= max_lag:
            # the other sensor runs on the same clock and its lag is the sharper: an accelerometer's
            # cross-correlation is dominated by slow gravity, and effects the baseline leaves out (a lever
            # arm at high rates) swamp any comparison of lags by baseline fit; the likelihood-ratio check
            # below still decides whether this sensor has the offset at all
            lag = int(start.lag_hint)
    if lag != 0:
        tau_c = lag * dt
        rows = edge_rows(sd.valid, tau_c, dt)
        r0, _ = baseline_resid(kind, sd, theta_with_tau(s, 0.0), rows)
        r1, _ = baseline_resid(kind, sd, theta_with_tau(s, tau_c), rows)
        ars = [fit_ar(r1[:, i], rows, cfg.max_ar_order) for i in range(3)]
        stat = _whitened_rss(r0, ars, rows) - _whitened_rss(r1, ars, rows)
        if stat > critical_value(level, 1):
            coarse = (float(stat), float(stats.chi2.logsf(stat, 1) / np.log(10)))
            tau_lin = _refine_tau(kind, sd, tau_c, ars, rows, dt)
            pre.append("time_offset")
            warnings.append(f"{s}: coarse search found a large time offset of {tau_lin * 1e3:.1f} ms ({lag} samples, refined to a fraction of a sample); refined below")
    skew_lin = None
    if start.skew_lin is not None and "clock_skew" in cands:
        skew_lin = float(start.skew_lin[0])
        pre.append("clock_skew")  # after the time offset: the held-out path adds the linearisation point's effects first
    pre += [c for c in force if c not in pre and c in cands]
    return Offset(tau_lin, coarse, cands, pre, warnings, skew_lin)


def edge_count(tau: float, dt: float, shift: float = 0.0, margin: int = 3) -> int:
    """Rows trimmed at each end by :func:`edge_rows`: ``ceil((|tau| + shift) / dt) + margin``."""
    return int(np.ceil((abs(tau) + shift) / dt)) + margin


def theta_with_tau(sensor: str, tau: float, skew: float = 0.0) -> np.ndarray:
    """The effect parameters of a linearisation point: time offset ``tau`` (s) and clock skew
    ``skew`` (ppm), every other effect at zero."""
    th = np.zeros(E.N_THETA[sensor])
    th[E.slot(sensor, "time_offset").start] = tau
    if skew != 0.0:
        th[E.slot(sensor, "clock_skew").start] = skew
    return th


def edge_rows(valid: np.ndarray, tau: float, dt: float, shift: float = 0.0) -> np.ndarray:
    """``valid`` without the rows at either end that a time shift of ``|tau| + shift`` (s) moves
    past the reference's ends (the band-limited shift and stretch reflect there), plus 3 rows.

    Args:
        valid: (N,) bool, rows with a reference.
        tau: the time offset (s).
        dt: sample interval (s).
        shift: a further shift of the ends (s), a clock skew's ``|s| max |t - t_mid|``.
    """
    m = valid.copy()
    e = edge_count(tau, dt, shift)
    m[:e] = False
    m[-e:] = False
    return m


def baseline_resid(kind, sd, theta, rows):
    x, z = linearize_baseline(kind, sd, E.identity_beta(kind), theta)
    nb = E.N_BASE[kind]
    a = x[rows].reshape(-1, nb)
    d = np.linalg.lstsq(a, z[rows].reshape(-1), rcond=None)[0]
    return z - x @ d, E.identity_beta(kind) + d


def _whitened_rss(resid, ars, rows):
    tot = 0.0
    fi = fill_index(rows)
    for i in range(3):
        ok = gap_ok(rows, ars[i].memory)
        u = apply_filter(resid[fi, i], ars[i])[ok]
        tot += float(u @ u)
    return tot


def _refine_tau(kind: str, sd: SensorData, tau_c: float, ars, rows: np.ndarray, dt: float) -> float:
    """Sub-sample refinement of a coarse time offset: whitened baseline RSS at ``tau_c + k dt / 2``
    (k = -2..2), parabola through the smallest value and its neighbours, clamped to +-1 sample."""
    s = sd.sensor
    ks = np.arange(-2, 3) * 0.5
    v = np.array([_whitened_rss(baseline_resid(kind, sd, theta_with_tau(s, tau_c + k * dt), rows)[0], ars, rows) for k in ks])
    i = int(np.clip(np.argmin(v), 1, len(ks) - 2))
    a, b, c = v[i - 1], v[i], v[i + 1]
    den = a - 2 * b + c
    off = 0.5 * (a - c) / den if den > 0 else 0.0
    return float(tau_c + (ks[i] + 0.5 * np.clip(off, -1.0, 1.0)) * dt)
