"""Where a pose-derived reference can be trusted: sensor and reference compared by frequency.

A reference differentiated from motion capture is exact at low frequency and noise at high
frequency (marker jitter, time-stamp jitter, dropouts). Two spectral measures, per axis, between
the sensor's output ``y`` and the reference ``x`` derived with almost no smoothing:

* the magnitude-squared **coherence** ``|S_xy|^2 / (S_xx S_yy)``: where the two agree at all. It
  falls where either is noisy, and vibration makes the *sensor* noisy, which the noise model
  handles; so coherence is reported, not used to choose the band;
* the **reference gain** ``|H|_F / sqrt(3)`` of the multivariate H1 transfer estimate
  ``H = S_yx S_xx^-1`` (:func:`reference_gain`). Noise in the sensor leaves it unbiased, a rotation
  between the frames or a delay between the clocks leaves its size unchanged, and noise in the
  reference (errors in variables) pulls it below 1 by exactly the attenuation
  ``S_ss / (S_ss + N_xx)`` that would bias every estimate. Where it stays above ``threshold`` the
  reference is trustworthy.

Both are unchanged when either signal is filtered, so they can be computed before the smoothing
the diagnosis then chooses: the Gaussian kernel whose half-power frequency sits at the lowest
sensor's trusted edge (:func:`choose_sigma`). Both streams are then filtered alike with that
kernel (:func:`jaxcal.diagnose.core.prepare`).

Spectra are Welch averages over Hann windows that lie wholly inside valid stretches (gaps are
skipped, not filled).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Band", "coherence", "coherent_edge", "reference_gain", "choose_sigma", "HALF_POWER"]

HALF_POWER = float(np.sqrt(np.log(2.0)) / (2.0 * np.pi))  # Gaussian of width sigma: |H(f)|^2 = 1/2 at f = HALF_POWER / sigma


class Band(NamedTuple):
    """The band a diagnosis used: ``sigma_s`` kernel width (the smallest, which sets the decimation),
    ``band_hz`` (0, its half-power frequency),
    per sensor the coherent edge (Hz, lowest axis) and per-axis edges, and the reason in words."""

    sigma_s: float
    band_hz: tuple[float, float]
    edge_hz: dict
    axis_edge_hz: dict
    reason: str
    freq_hz: np.ndarray
    coherence: dict
    sigma_by_sensor: dict | None = None  # per sensor kernel width (s); ``sigma_s`` is the smallest


def _spectra(y: np.ndarray, x: np.ndarray, valid: np.ndarray, dt: float, seg_s: float = 2.0):
    """Welch auto/cross spectra ``(freq, S_yy, S_xx, S_xy)`` (F, C) over Hann windows of ``seg_s``
    seconds, half overlapping, using only windows whose every sample is ``valid``; None when
    fewer than 4 windows qualify."""
    n = len(y)
    m = max(16, int(round(seg_s / dt)))
    freq = np.fft.rfftfreq(m, dt)
    c = y.shape[1]
    if n < m:
        return None
    win = np.hanning(m)
    bad = np.concatenate([[0], np.cumsum(~np.asarray(valid, bool))])
    starts = [s for s in range(0, n - m + 1, m // 2) if bad[s + m] - bad[s] == 0]
    if len(starts) < 4:
        return None
    sxx = np.zeros((len(freq), c))
    syy = np.zeros((len(freq), c))
    sxy = np.zeros((len(freq), c), complex)
    for s in starts:
        ys = y[s : s + m] - y[s : s + m].mean(0)
        xs = x[s : s + m] - x[s : s + m].mean(0)
        fy = np.fft.rfft(ys * win[:, None], axis=0)
        fx = np.fft.rfft(xs * win[:, None], axis=0)
        syy += np.abs(fy) ** 2
        sxx += np.abs(fx) ** 2
        sxy += fy * np.conj(fx)
    return freq, syy, sxx, sxy


def coherence(y: np.ndarray, x: np.ndarray, valid: np.ndarray, dt: float, seg_s: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis magnitude-squared coherence of ``y`` and ``x`` (N, C): ``(freq (F,), coh (F, C))``
    (Welch, :func:`_spectra`; zeros when too few valid windows).

    Args:
        y: (N, C) sensor output.
        x: (N, C) reference.
        valid: (N,) bool, samples whose reference exists.
        dt: sample interval (s).
        seg_s: Welch window length (s).
    """
    sp = _spectra(y, x, valid, dt, seg_s)
    if sp is None:
        m = max(16, int(round(seg_s / dt)))
        return np.fft.rfftfreq(m, dt), np.zeros((m // 2 + 1, y.shape[1]))
    freq, syy, sxx, sxy = sp
    with np.errstate(invalid="ignore", divide="ignore"):
        coh = np.abs(sxy) ** 2 / (sxx * syy)
    return freq, np.nan_to_num(coh, nan=0.0)


def reference_gain(y: np.ndarray, x: np.ndarray, valid: np.ndarray, dt: float, seg_s: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """The reference's gain against the sensor by frequency: ``(freq (F,), gain (F,))``.

    Multivariate H1 transfer estimate ``H(f) = S_yx S_xx^-1`` (3x3 per bin, Welch, :func:`_spectra`'s
    windows) and ``gain = |H|_F / sqrt(3)``: 1 for a sensor that reads the reference through any
    rotation (and any delay: both only rotate or phase-shift ``H``), below 1 by the
    errors-in-variables attenuation where the reference carries its own noise. The sensors' outputs
    are in physical units via their datasheet values, so their own scale is 1 to a few percent;
    sensor noise (vibration) leaves the estimate unbiased. Zeros when too few valid windows.

    Args:
        y: (N, 3) sensor output (physical units).
        x: (N, 3) reference.
        valid: (N,) bool, samples whose reference exists.
        dt: sample interval (s).
        seg_s: Welch window length (s).
    """
    n = len(y)
    m = max(16, int(round(seg_s / dt)))
    freq = np.fft.rfftfreq(m, dt)
    if n < m:
        return freq, np.zeros(len(freq))
    win = np.hanning(m)
    bad = np.concatenate([[0], np.cumsum(~np.asarray(valid, bool))])
    starts = [s for s in range(0, n - m + 1, m // 2) if bad[s + m] - bad[s] == 0]
    if len(starts) < 4:
        return freq, np.zeros(len(freq))
    syx = np.zeros((len(freq), 3, 3), complex)
    sxx = np.zeros((len(freq), 3, 3), complex)
    for s in starts:
        fy = np.fft.rfft((y[s : s + m] - y[s : s + m].mean(0)) * win[:, None], axis=0)
        fx = np.fft.rfft((x[s : s + m] - x[s : s + m].mean(0)) * win[:, None], axis=0)
        syx += fy[:, :, None] * np.conj(fx[:, None, :])
        sxx += fx[:, :, None] * np.conj(fx[:, None, :])
    reg = 1e-12 * np.maximum(np.trace(sxx, axis1=1, axis2=2).real, 1e-300)[:, None, None] * np.eye(3)
    h = syx @ np.linalg.inv(sxx + reg)
    return freq, np.sqrt(np.sum(np.abs(h) ** 2, axis=(1, 2)) / 3.0)


def coherent_edge(freq: np.ndarray, coh: np.ndarray, threshold: float = 0.8, smooth: int = 3) -> np.ndarray:
    """Per axis, the frequency (Hz) below which a measure (coherence or reference gain) stays at or
    above ``threshold``: the first bin above 0.5 Hz where a ``smooth``-bin running mean falls below it.

    Args:
        freq: (F,) bin frequencies (Hz).
        coh: (F, C) the measure per axis.
        threshold: level the measure must keep.
        smooth: bins in the running mean.
    """
    out = np.zeros(coh.shape[1])
    start = max(1, int(np.searchsorted(freq, 0.25)))  # never the DC bin (windows are mean-removed)
    h = smooth // 2
    for i in range(coh.shape[1]):
        c = coh[start:, i]
        cp = np.concatenate([np.repeat(c[:1], h), c, np.repeat(c[-1:], h)])  # edge-padded, not zero-padded
        cs = np.convolve(cp, np.ones(smooth) / smooth, "valid")
        below = np.flatnonzero(cs < threshold)
        out[i] = freq[start + below[0]] if below.size else freq[-1]
    return out


def choose_sigma(pairs: dict, valid: np.ndarray, dt: float, sigma_range: tuple[float, float] = (0.01, 0.1),
                 threshold: float = 0.95, lag_s: float = 0.0) -> Band:
    """The smoothing kernel width whose half-power frequency is the lowest trusted edge (where the
    reference gain :func:`reference_gain` falls below ``threshold``; per-axis coherence edges are
    reported beside it).

    Args:
        pairs: ``{sensor: (y (N, 3) measured, x (N, 3) reference derived with almost no smoothing)}``.
        valid: (N,) samples whose reference exists.
        dt: sample interval (s).
        sigma_range: clip of the chosen width (s): at least the pose noise's own smoothing, at most
            what still resolves the motion.
        lag_s: clock offset already removed from the pairs (reported).
        threshold: reference gain that counts as trustworthy (0.95: the reference's own noise is
            at most 5 % of its signal power there, so estimates are attenuated by at most 5 % at the
            band edge and far less inside it, where the kernel puts its weight).
    """
    edges, axis_edges, cohs = {}, {}, {}
    freq = np.zeros(0)
    for s, (y, x) in pairs.items():
        freq, coh = coherence(y, x, valid, dt)
        _, gain = reference_gain(y, x, valid, dt)
        axis_edges[s] = coherent_edge(freq, coh, threshold).tolist()  # coherence, per axis: reported only
        edges[s] = float(coherent_edge(freq, gain[:, None], threshold, smooth=5)[0])
        cohs[s] = {"coherence": coh, "reference_gain": gain}
    if not edges:
        raise ValueError("no sensor to measure the coherent band with")
    # The gyroscope judges the pose: its reference (the rotation's derivative) differs from what it
    # reads only by the pose's noise and effects of a few parts per thousand. The accelerometer's
    # reference gain also drops wherever a lever arm or time offset, the very effects to estimate,
    # makes it read other physics, so it is reported but chooses the band only without a gyroscope.
    worst = "gyr" if "gyr" in edges else min(edges, key=edges.get)
    lo = edges[worst]
    sigma = float(np.clip(HALF_POWER / max(lo, 1e-9), *sigma_range))
    # per sensor: the accelerometer's reference (the position's second derivative) is noisier than
    # the rotation's first derivative, so it may need a wider kernel, never a narrower one
    by_sensor = {s: max(sigma, float(np.clip(HALF_POWER / max(e, 1e-9), *sigma_range))) if s != worst else sigma
                 for s, e in edges.items()}
    reason = (f"the pose-derived reference keeps >= {threshold:g} of its gain against the sensor (|H1|, the "
              "errors-in-variables attenuation) up to "
              + ", ".join(f"{s} {edges[s]:.1f} Hz (coherence >= {threshold:g} up to {', '.join(f'{v:.1f}' for v in axis_edges[s])} Hz per axis)"
                          for s in edges)
              + (f" (after removing a {lag_s * 1e3:.0f} ms clock offset)" if lag_s else "")
              + "; the Gaussian kernel puts its half-power point at each sensor's edge (the gyroscope's at least): sigma "
              + ", ".join(f"{s} {v * 1e3:.0f} ms" for s, v in by_sensor.items())
              + (" - clipped to the allowed widths" if not sigma_range[0] < HALF_POWER / max(lo, 1e-9) < sigma_range[1] else ""))
    return Band(sigma, (0.0, HALF_POWER / sigma), edges, axis_edges, reason, freq, cohs, by_sensor)
