"""Locating a mismatch: residual breakdowns by axis, time segment, motion regime, temperature
and frequency band, plus residual whiteness and Allan deviation.

All inputs are numpy arrays; residuals are in the sensor's physical unit (g or rad/s). Each
breakdown reports the RMS per bin and its ratio to the overall RMS, so "where the mismatch lives"
is the bin with the largest ratio (with enough samples).
"""

from __future__ import annotations

import numpy as np

from jaxcal.allan import overlapping_adev
from jaxcal.diagnose.whiten import ljung_box

__all__ = [
    "band_power",
    "allan_deviation",
    "breakdown",
    "whiteness",
]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")


def _bins(resid, rows, key, edges, labels):
    out = []
    for lo, hi, lab in zip(edges[:-1], edges[1:], labels):
        m = rows & (key >= lo) & (key < hi)
        out.append({"bin": lab, "n": int(m.sum()), "rms": _rms(resid[m])})
    return out


def band_power(resid: np.ndarray, rows: np.ndarray, dt: float, edges=(0.0, 0.1, 1.0, 10.0, np.inf)) -> list[dict]:
    """RMS of the residual per frequency band (periodogram of the valid-masked residual, all axes)
    and the share a white residual of the same RMS would put there (``white_share``).

    Args:
        resid: (N, 3) residual.
        rows: (N,) bool, the rows used.
        dt: sample interval (s).
        edges: band edges (Hz); bands above Nyquist are dropped.
    """
    r = np.where(rows[:, None], resid - resid[rows].mean(0), 0.0)
    n = len(r)
    spec = np.abs(np.fft.rfft(r, axis=0)) ** 2
    freq = np.fft.rfftfreq(n, dt)
    tot = spec[1:].sum()
    nyq = 0.5 / dt
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        if lo >= nyq:
            break
        hi_c = min(hi, nyq + 1e-9)
        m = (freq > lo) & (freq <= hi_c)
        share = float(spec[m].sum() / tot) if tot > 0 else float("nan")
        out.append({"band_hz": [float(lo), float(min(hi, nyq))], "share": share,
                    "white_share": float((min(hi, nyq) - lo) / nyq), "rms": _rms(resid[rows]) * np.sqrt(share)})
    return out


def allan_deviation(x: np.ndarray, dt: float, n_taus: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of a (N,) rate-like series at octave-spaced ``tau = m dt`` (s),
    ``m = 1, 2, 4, ...`` while ``2 m < N // 3``: :func:`jaxcal.allan.overlapping_adev` at those
    cluster sizes.

    Args:
        x: (N,) rate-like series.
        dt: sample interval (s).
        n_taus: caps the octaves at ``n_taus + 8`` (the length also limits them).
    """
    x = np.asarray(x, np.float64)
    n = len(x)
    ms = []
    m = 1
    while 2 * m < n // 3 and len(ms) < n_taus + 8:
        ms.append(m)
        m *= 2
    if not ms:
        return np.array([]), np.array([])
    m = np.asarray(ms)
    res = overlapping_adev(x, 1.0 / dt, taus=m * dt)
    return m * dt, res.adev[:, 0]


def breakdown(resid: np.ndarray, rows: np.ndarray, t: np.ndarray, w: np.ndarray, wdot: np.ndarray,
              temp: np.ndarray | None, dt: float, n_segments: int = 10) -> dict:
    """Where the residual (N, 3) lives: per axis, time segment, rate/angular-acceleration regime,
    temperature bin and frequency band; plus the single most elevated bin (``"where"``).

    Args:
        resid: (N, 3) residual.
        rows: (N,) bool, the rows used.
        t: (N,) times (s).
        w: (N, 3) body rate (rad/s).
        wdot: (N, 3) angular acceleration (rad/s^2).
        temp: (N,) temperature (degC); None: no temperature bins.
        dt: sample interval (s).
        n_segments: equal time segments.
    """
    overall = _rms(resid[rows])
    out: dict = {"rms": overall, "axis": [_rms(resid[rows, i]) for i in range(3)]}
    seg = np.minimum((np.arange(len(t)) * n_segments) // len(t), n_segments - 1)
    out["segment"] = [{"bin": f"{t[seg == k][0]:.1f}-{t[seg == k][-1]:.1f} s", "n": int((rows & (seg == k)).sum()),
                       "rms": _rms(resid[rows & (seg == k)])} for k in range(n_segments)]
    wn = np.linalg.norm(w, axis=1)
    out["rate"] = _bins(resid, rows, wn, [0, 0.05, 1.0, np.inf], ["static (<0.05 rad/s)", "slow (0.05-1 rad/s)", "fast (>1 rad/s)"])
    an = np.linalg.norm(wdot, axis=1)
    out["ang_acc"] = _bins(resid, rows, an, [0, 0.5, 5.0, np.inf], ["<0.5 rad/s^2", "0.5-5 rad/s^2", ">5 rad/s^2"])
    if temp is not None:
        q = np.quantile(temp[rows], [0, 0.2, 0.4, 0.6, 0.8, 1.0])
        q[-1] += 1e-9
        out["temperature"] = _bins(resid, rows, temp, q, [f"{a:.1f}-{b:.1f} degC" for a, b in zip(q[:-1], q[1:])])
    out["band"] = band_power(resid, rows, dt)
    best = None
    for k in ("segment", "rate", "ang_acc", "temperature"):
        for b in out.get(k, []):
            if b["n"] >= max(50, rows.sum() // 50) and np.isfinite(b["rms"]):
                ratio = b["rms"] / overall if overall > 0 else 1.0
                if best is None or ratio > best[0]:
                    best = (ratio, k, b["bin"])
    band = max(out["band"], key=lambda b: b["share"] / max(b["white_share"], 1e-12))
    out["where"] = {"breakdown": best[1] if best else None, "bin": best[2] if best else None,
                    "rms_ratio": best[0] if best else None,
                    "band_hz": band["band_hz"], "band_excess": band["share"] / max(band["white_share"], 1e-12)}
    return out


def whiteness(resid: np.ndarray, rows: np.ndarray, dt: float) -> dict:
    """Ljung-Box Q (20 lags, per axis; ~20 if white) and Allan deviation of the residual.

    Args:
        resid: (N, 3) residual.
        rows: (N,) bool, the rows used.
        dt: sample interval (s).
    """
    r = resid[rows]
    taus, _ = allan_deviation(r[:, 0], dt)
    return {"ljung_box_q20": [ljung_box(r[:, i]) for i in range(3)],
            "adev_tau_s": taus.tolist(), "adev": [allan_deviation(r[:, i], dt)[1].tolist() for i in range(3)]}
