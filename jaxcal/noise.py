"""Noise parameters of a static stretch of a recording: the report behind ``jaxcal noise``.

Pure functions on a :class:`~jaxcal.recording.Recording` (no file I/O; ``jaxcal.cli.noise`` writes
the files): the static stretch (given, or the longest interval :mod:`jaxcal.static` finds), each
sensor in SI units (accelerometer m/s^2, gyroscope rad/s, from ``acc_unit``/``gyr_unit`` or the
datasheet scales ``acc_lsb_per_g``/``gyr_lsb_per_rads``), its overlapping Allan deviation per axis
with chi-square intervals (:mod:`jaxcal.allan`), the noise processes fitted jointly over all cluster
times with a selected model and intervals (:mod:`jaxcal.gmwm`: white noise density N, random walk K,
and bias instability B, quantisation, rate ramp, Gauss-Markov where selected), the slope-line
reading (:func:`jaxcal.allan.fit_noise`) as a second opinion, and the Kalibr / OpenVINS noise keys. :func:`allan_figure`
returns a matplotlib ``Figure`` (built without pyplot: no global state).

Combining axes: Kalibr and OpenVINS take one number per sensor; each key holds the largest value
over the three axes (:func:`jaxcal.formats.noise_yaml.kalibr_imu_yaml`), the conservative choice for a filter.
Where the model selected has no random walk (``K`` NaN on an axis: a stretch too short to see it), the
number written is an upper bound instead: ``min over tau of adev_hi(tau) sqrt(3 / tau)`` (every
Allan variance is at least ``K^2 tau / 3``; ``adev_hi`` is the upper end of the ADEV interval), and
the report says so (``K_is_bound``).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from jaxtyping import Float

from jaxcal.allan import (
    AllanResult,
    NoiseParams,
    adev_interval,
    edf_oadev,
    fit_noise,
    overlapping_adev,
)
from jaxcal.arrays import Array
from jaxcal.constants import G0
from jaxcal.formats.noise_yaml import kalibr_imu_yaml, kalibr_yaml_text, openvins_imu_chain, openvins_yaml_text
from jaxcal.gmwm import CANDIDATES, GmwmConfig, advice_lines, fit_json, gmwm_axes, noise_params, record_advice
from jaxcal.recording import Recording, RecordingError

__all__ = [
    "SI_UNITS",
    "STATIC_GYR_STD_MAX",
    "STATIC_ACC_STD_MAX",
    "SensorNoise",
    "NoiseReport",
    "sensor_si",
    "quantisation_step",
    "implausible_noise",
    "static_stretch",
    "not_static_reason",
    "adev_ci",
    "sensor_noise",
    "noise_report",
    "report_json",
    "summary_lines",
    "kalibr_yaml_text",
    "openvins_yaml_text",
    "allan_figure",
    "gauss_markov_adev",
]

SI_UNITS = {
    "acc": {"signal": "m/s^2", "N": "m/s^2/sqrt(Hz)", "B": "m/s^2", "K": "m/s^3/sqrt(Hz)"},
    "gyr": {"signal": "rad/s", "N": "rad/s/sqrt(Hz)", "B": "rad/s", "K": "rad/s^2/sqrt(Hz)"},
}
"""SI units of the signal and of N, B, K per sensor (Kalibr's units)."""

STATIC_GYR_STD_MAX = np.radians(2.0)
"""Largest per-axis gyro standard deviation (rad/s) of a stretch called static: 2 deg/s, about 6x
the white noise of a 0.01 deg/s/sqrt(Hz) gyro at 1 kHz; a hand-held or moving IMU is far above it."""

STATIC_ACC_STD_MAX = 0.05 * G0
"""Largest per-axis accelerometer standard deviation (m/s^2) of a stretch called static: 0.05 g."""

_AXES = ("x", "y", "z")


class SensorNoise(NamedTuple):
    """One sensor's Allan analysis (SI units, :data:`SI_UNITS`).

    Attributes:
        allan: :func:`jaxcal.allan.overlapping_adev` result.
        adev_lo: (T, C) lower ends of the ADEV intervals (:func:`adev_ci`).
        adev_hi: (T, C) upper ends.
        params: N, B, K with intervals from the GMWM fits (:func:`jaxcal.gmwm.noise_params`; NaN where
            the selected model lacks the process): the values the YAML keys are made from.
        K_bound: (C,) upper bound on K where ``params.K`` is NaN (module docstring), else ``params.K``.
        slope: the slope-line reading, :func:`jaxcal.allan.fit_noise` (a second opinion).
        gmwm: per axis, :class:`jaxcal.gmwm.GmwmFit` (model selected, every parameter with its interval).
    """

    allan: AllanResult
    adev_lo: np.ndarray
    adev_hi: np.ndarray
    params: NoiseParams
    K_bound: np.ndarray
    slope: NoiseParams
    gmwm: tuple


class NoiseReport(NamedTuple):
    """The report of one static stretch.

    Attributes:
        start: first sample index of the stretch.
        stop: one past its last sample index.
        t_start: its start time (s, the recording's clock).
        t_end: its end time (s).
        how: how the stretch was chosen (one sentence).
        fs: sample rate used (Hz).
        dt_spread: largest relative deviation of a time step from the median step in the stretch.
        sensors: ``{"acc": SensorNoise, "gyr": SensorNoise}`` (those analysed).
        conversion: per sensor, how the samples became SI units.
        kalibr: Kalibr ``imu.yaml`` dict (both sensors analysed), else None.
        openvins: OpenVINS ``kalibr_imu_chain.yaml`` dict, else None.
        warnings: one-line notes (uneven time steps, short stretch, K bounds).
        advice: per sensor, per axis, :func:`jaxcal.gmwm.record_advice` (how long to record).
    """

    start: int
    stop: int
    t_start: float
    t_end: float
    how: str
    fs: float
    dt_spread: float
    sensors: dict
    conversion: dict
    kalibr: dict | None
    openvins: dict | None
    warnings: list
    advice: dict


def sensor_si(rec: Recording, sensor: str) -> tuple[np.ndarray, str]:
    """One sensor of a recording in SI units (m/s^2 or rad/s) and how it got there.

    The bias is not subtracted (the Allan deviation removes the mean). Raises
    :class:`~jaxcal.recording.RecordingError` for raw counts without the datasheet scale.

    Args:
        rec: the recording.
        sensor: ``"acc"`` or ``"gyr"``.
    """
    y = getattr(rec, sensor)
    if y is None:
        raise RecordingError(f"no '{sensor}' in the recording (--sensors names it)")
    y = np.asarray(y, np.float64)
    if sensor == "acc":
        if rec.acc_unit == "g":
            return y * G0, "acc_unit 'g' times 9.80665 m/s^2"
        if rec.acc_lsb_per_g is None:
            raise RecordingError(
                "accelerometer in raw counts (LSB) without 'acc_lsb_per_g': give the datasheet scale as --acc-lsb-per-g "
                "(LSB/g) or add it to the recording (or store acc in g, with the recording key 'acc_unit' = 'g')"
            )
        return y / np.asarray(rec.acc_lsb_per_g, np.float64) * G0, "LSB / acc_lsb_per_g times 9.80665 m/s^2"
    if rec.gyr_unit == "rad/s":
        return y, "gyr_unit 'rad/s'"
    if rec.gyr_lsb_per_rads is None:
        raise RecordingError(
            "gyroscope in raw counts (LSB) without 'gyr_lsb_per_rads': give the datasheet scale as --gyr-lsb-per-rads "
            "(LSB/(rad/s)) or add it to the recording (or store gyr in rad/s, with the recording key 'gyr_unit' = 'rad/s')"
        )
    return y / np.asarray(rec.gyr_lsb_per_rads, np.float64), "LSB / gyr_lsb_per_rads"


def not_static_reason(acc_si: np.ndarray | None, gyr_si: np.ndarray | None) -> str | None:
    """Why a stretch is not static (a per-axis std above :data:`STATIC_GYR_STD_MAX` or
    :data:`STATIC_ACC_STD_MAX`), or None.

    Args:
        acc_si: (n, 3) accelerometer (m/s^2) over the stretch, or None.
        gyr_si: (n, 3) gyroscope (rad/s) over the stretch, or None.
    """
    if gyr_si is not None:
        s = float(np.max(np.std(gyr_si, axis=0)))
        if s > STATIC_GYR_STD_MAX:
            return f"gyroscope std {np.degrees(s):.3g} deg/s exceeds {np.degrees(STATIC_GYR_STD_MAX):.3g} deg/s"
    if acc_si is not None:
        s = float(np.max(np.std(acc_si, axis=0)))
        if s > STATIC_ACC_STD_MAX:
            return f"accelerometer std {s / G0:.3g} g exceeds {STATIC_ACC_STD_MAX / G0:.3g} g"
    return None


def static_stretch(rec: Recording, sensors: tuple[str, ...] = ("acc", "gyr"), min_duration: float = 10.0) -> tuple[int, int, str]:
    """The longest static interval of a recording, ``[start, stop)`` sample indices and a sentence saying so.

    :func:`jaxcal.static.detect_static` (imu_tk's variance detector, threshold 2x the first
    10 s, gyro gate when a gyroscope is present, 1 s window) finds the candidates; the longest is
    trimmed by half a window at each end and must pass :func:`not_static_reason` (the detector's
    threshold is relative, so a recording that never rests would otherwise pass). Raises
    :class:`~jaxcal.recording.RecordingError` when no interval of ``min_duration`` seconds remains.

    Args:
        rec: the recording (``acc`` needed).
        sensors: sensors checked for rest (SI conversion must succeed for each).
        min_duration: shortest acceptable stretch (s).
    """
    from jaxcal.static import detect_static

    if rec.acc is None:
        raise RecordingError("no accelerometer to find a static stretch with; give --start and --end")
    t = np.asarray(rec.t, np.float64)
    init = min(10.0, 0.5 * float(t[-1] - t[0]))
    try:
        det = detect_static(t, np.asarray(rec.acc, np.float64), k=2.0, init_duration=init, window=1.0, min_duration=min_duration,
                            gyr=None if rec.gyr is None else np.asarray(rec.gyr, np.float64))
    except ValueError as e:
        raise RecordingError(f"no static stretch found ({e}); give --start and --end") from None
    iv = det.intervals
    if iv.shape[0] == 0:
        raise RecordingError(f"no static stretch of at least {min_duration:g} s found; give --start and --end")
    dt = float(np.median(np.diff(t)))
    half = int(round(0.5 / dt))
    lens = iv[:, 1] - iv[:, 0]
    for j in np.argsort(-lens, kind="stable"):
        a, b = int(iv[j, 0]), int(iv[j, 1])
        a, b = (a + half if a > 0 else a), (b - half if b < rec.n else b)
        if t[b - 1] - t[a] < min_duration:
            continue
        data = {s: sensor_si(rec, s)[0][a:b] for s in sensors}
        if not_static_reason(data.get("acc"), data.get("gyr")) is None:
            how = (f"the longest static interval found by jaxcal.static.detect_static ({len(iv)} found; "
                   f"{t[a] - t[0]:.2f} to {t[b - 1] - t[0]:.2f} s after the first sample)")
            return a, b, how
    raise RecordingError(f"no static stretch of at least {min_duration:g} s found (the detector's candidates move); "
                         "give --start and --end")


def adev_ci(res: AllanResult, level: float = 0.95) -> tuple[Float[np.ndarray, "T C"], Float[np.ndarray, "T C"]]:
    """Chi-square interval of each ADEV point, with the EDF of the noise that dominates there.

    The noise type at each tau is read off the local log-log slope ``mu`` of the ADEV (centred
    differences over neighbouring taus): ``alpha = round(-(2 mu + 1))`` clipped to {0, -1, -2}
    (white, flicker, random-walk FM; NIST SP 1065 Table 5 via :func:`jaxcal.allan.edf_oadev`).

    Args:
        res: :func:`jaxcal.allan.overlapping_adev` result.
        level: two-sided confidence level.

    Returns:
        ``(lo, hi)``, each ``(T, C)``.
    """
    lt, la = np.log(res.taus), np.log(np.maximum(res.adev, 1e-300))
    if lt.size > 1:
        slope = np.gradient(la, lt, axis=0)
    else:
        slope = np.full_like(la, -0.5)
    alpha = np.clip(np.round(-(2.0 * slope + 1.0)), -2, 0).astype(int)
    edf = np.empty_like(res.adev)
    for a in (0, -1, -2):
        e = edf_oadev(res.n_phase, res.m, a)[:, None] * np.ones((1, res.adev.shape[1]))
        edf = np.where(alpha == a, e, edf)
    return adev_interval(res.adev, np.maximum(edf, 1.0), level)


def sensor_noise(x: Float[Array, "N C"], fs: float, taus_per_decade: int = 10, level: float = 0.95) -> SensorNoise:
    """Allan analysis of one sensor's static samples (any unit; SI for the Kalibr keys).

    The ADEV is computed up to ``m = N // 2`` (plotted, written); the GMWM (:func:`jaxcal.gmwm.gmwm_axes`,
    dyadic cluster sizes) and the slope-line reading use ``m <= N // 4`` only: beyond, a point holds
    fewer than ``N / 2`` overlapping terms (EDF about 1 to 2). An axis with N below the quantisation floor
    ``q / sqrt(12 fs)`` (a filter's roll-off read as QN or a short GM) is refitted without QN and GM.

    Args:
        x: (N, C) rate samples.
        fs: sample rate (Hz).
        taus_per_decade: number of log-spaced cluster times per decade.
        level: two-sided confidence level of every interval.
    """
    res = overlapping_adev(x, fs, per_decade=taus_per_decade)
    lo, hi = adev_ci(res, level)
    keep = res.m <= max(1, (res.n_phase - 1) // 4)  # fit where EDF >= ~2 (the last taus hold one or two terms)
    sub = AllanResult(res.taus[keep], res.m[keep], res.adev[keep], res.n_terms[keep], res.n_phase)
    fits = gmwm_axes(x, fs, GmwmConfig(level=level))
    floor = quantisation_step(x) / np.sqrt(12.0 * fs)
    if any(f.get("N")[0] < q for f, q in zip(fits, floor)):  # short taus read as QN or GM: refit without them
        no_qn = gmwm_axes(x, fs, GmwmConfig(candidates=tuple(c for c in CANDIDATES if not {"QN", "GM"} & set(c)), level=level))
        fits = tuple(g if f.get("N")[0] < q else f for f, g, q in zip(fits, no_qn, floor))
    p = noise_params(fits)
    bound = np.min(hi[keep] * np.sqrt(3.0 / sub.taus)[:, None], axis=0)
    return SensorNoise(res, lo, hi, p, np.where(np.isfinite(p.K), p.K, bound), fit_noise(sub, level=level), fits)


def quantisation_step(x: Float[Array, "N C"]) -> Float[np.ndarray, " C"]:
    """Per axis, the smallest positive difference between two distinct sample values (the output's
    resolution: one LSB for counts; about 0 for float data with noise below its resolution)."""
    x = np.asarray(x, np.float64)
    out = np.zeros(x.shape[1])
    for c in range(x.shape[1]):
        d = np.diff(np.unique(x[:, c]))
        d = d[d > 0]
        out[c] = float(d.min()) if d.size else 0.0
    return out


def implausible_noise(s: str, x: Float[Array, "N C"], noise: SensorNoise, fs: float, unit: str) -> str | None:
    """Why one sensor's noise figures must not be written, or None (issue 27: a stuck sensor wrote
    densities of 2e-27 into ``imu.yaml``, which a filter would trust absolutely).

    Refused: an axis whose every sample is identical (a stuck or constant sensor: no noise can be
    measured), a density that is not finite and positive, one implying a per-sample spread
    ``N sqrt(fs)`` over 3 x the stretch's own standard deviation, and a white noise density below the
    quantisation floor ``q / sqrt(12 fs)`` (q: the output's resolution; the rounding alone puts
    that much white noise on every sample, so a smaller density was not resolved).

    Args:
        s: ``"acc"`` or ``"gyr"``.
        x: (N, 3) the stretch in SI units.
        noise: :func:`sensor_noise`'s result on it.
        fs: sample rate (Hz).
        unit: the SI unit of ``x`` (for the message).
    """
    x = np.asarray(x, np.float64)
    axes = "xyz"
    for c in range(x.shape[1]):
        if np.ptp(x[:, c]) == 0.0:
            return (f"{s} axis {axes[c]} never changes over the stretch (every sample {x[0, c]:.6g} {unit}): a stuck "
                    "sensor or a constant file; its noise cannot be measured")
    q = quantisation_step(x)
    floor = q / np.sqrt(12.0 * fs)
    N = np.asarray(noise.params.N, np.float64)
    for c in range(x.shape[1]):
        if not (np.isfinite(N[c]) and N[c] > 0):
            return f"{s} axis {axes[c]}: white noise density {N[c]:.3g} could not be measured on this stretch"
        sd = float(np.std(x[:, c]))
        if N[c] * np.sqrt(fs) > 3.0 * sd:
            return (f"{s} axis {axes[c]}: white noise density {N[c]:.3g} {unit}/sqrt(Hz) implies a sample spread of "
                    f"{N[c] * np.sqrt(fs):.3g} {unit} at {fs:g} Hz, over 3 x the stretch's own {sd:.3g}: the fit does not "
                    "describe these samples (a wrong sample rate?)")
        if N[c] < floor[c]:
            return (f"{s} axis {axes[c]}: white noise density {N[c]:.3g} {unit}/sqrt(Hz) is below the quantisation floor "
                    f"{floor[c]:.3g} (resolution {q[c]:.3g} {unit} at {fs:g} Hz): the output barely changes, so its noise "
                    "is not resolved (a stuck sensor, or the wrong datasheet scale?)")
    return None


def noise_report(
    rec: Recording,
    sensors: tuple[str, ...] = ("acc", "gyr"),
    start: float | None = None,
    end: float | None = None,
    topic: str = "/imu0",
    taus_per_decade: int = 10,
    level: float = 0.95,
    target: float = 0.1,
) -> NoiseReport:
    """Noise parameters of a recording's static stretch (the ``jaxcal noise`` report).

    Raises :class:`~jaxcal.recording.RecordingError` (one line) for bad input: raw counts without a
    datasheet scale, a stretch outside the recording or shorter than 100 samples, no static stretch.

    Args:
        rec: the recording.
        sensors: sensors to analyse (``acc``, ``gyr``).
        start: stretch start (s, the recording's clock); None with ``end`` None: the longest static interval.
        end: stretch end (s); None: the end of the recording (when ``start`` is given).
        topic: Kalibr ``rostopic``.
        taus_per_decade: cluster times per decade.
        level: confidence level of the intervals.
        target: relative interval half-width whose record length the report predicts.
    """
    for s in sensors:
        x = sensor_si(rec, s)[0]  # refuse missing scale metadata before any work
        ptp = np.ptp(x, axis=0)
        if ptp.min() == 0.0:  # a stuck sensor: refused before the static detector calls it moving
            c = int(np.argmin(ptp))
            raise RecordingError(f"{s} axis {'xyz'[c]} never changes over the recording (every sample {x[0, c]:.6g} "
                                 f"{SI_UNITS[s]['signal']}): a stuck sensor or a constant file; its noise cannot be measured")
    t = np.asarray(rec.t, np.float64)
    if start is None and end is None:
        a, b, how = static_stretch(rec, sensors)
    else:
        s0 = float(t[0]) if start is None else float(start)
        s1 = float(t[-1]) if end is None else float(end)
        if s0 < t[0] - 1e-9 or s1 > t[-1] + 1e-9:
            raise RecordingError(f"--start {s0:g} / --end {s1:g} s lie outside the recording ({t[0]:g} to {t[-1]:g} s)")
        if s1 <= s0:
            raise RecordingError(f"--end {s1:g} s is not after --start {s0:g} s")
        a, b = int(np.searchsorted(t, s0, "left")), int(np.searchsorted(t, s1, "right"))
        how = f"--start/--end: {t[a]:g} to {t[b - 1]:g} s"
    if b - a < 100:
        raise RecordingError(f"the static stretch holds {b - a} samples; at least 100 are needed")
    data = {s: sensor_si(rec, s)[0][a:b] for s in sensors}
    warnings: list[str] = []
    why = not_static_reason(data.get("acc"), data.get("gyr"))
    if why:
        warnings.append(f"the stretch does not look static ({why}); the numbers include motion")
    dts = np.diff(t[a:b])
    dt = float(np.median(dts))
    fs = float(rec.fs) if rec.fs else 1.0 / dt
    spread = float(np.max(np.abs(dts - dt)) / dt)
    if spread > 0.1:
        warnings.append(f"time steps vary by up to {100 * spread:.0f} % of the median; the Allan deviation assumes even spacing")
    for s in sensors:  # a stuck axis first: its Allan deviation is 0
        if np.ptp(data[s], axis=0).min() == 0.0:
            c = int(np.argmin(np.ptp(data[s], axis=0)))
            raise RecordingError(f"{s} axis {'xyz'[c]} never changes over the {t[b - 1] - t[a]:.1f} s stretch (every sample "
                                 f"{data[s][0, c]:.6g} {SI_UNITS[s]['signal']}): a stuck sensor or a constant file; its noise cannot be measured")
    res = {s: sensor_noise(data[s], fs, taus_per_decade, level) for s in sensors}
    for s in sensors:
        why = implausible_noise(s, data[s], res[s], fs, SI_UNITS[s]["signal"])
        if why:
            raise RecordingError(why)
    dur = float(t[b - 1] - t[a])
    for s, r in res.items():
        if not np.all(np.isfinite(r.params.K)):
            warnings.append(f"{s}: the model selected on the {dur:.0f} s stretch has no random walk on some axes (too short to "
                            "see it); the K written is an upper bound (min over tau of adev_hi sqrt(3/tau))")
    kal = ov = None
    if "acc" in res and "gyr" in res:
        pa = res["acc"].params._replace(K=res["acc"].K_bound)
        pg = res["gyr"].params._replace(K=res["gyr"].K_bound)
        kal = kalibr_imu_yaml(pa, pg, fs, topic)
        ov = openvins_imu_chain(pa, pg, fs, topic)
    conv = {s: sensor_si(rec, s)[1] for s in sensors}
    advice = {s: [record_advice(f, target) for f in r.gmwm] for s, r in res.items()}
    return NoiseReport(a, b, float(t[a]), float(t[b - 1]), how, fs, spread, res, conv, kal, ov, warnings, advice)


def _floats(a) -> list:
    return [None if not np.isfinite(v) else float(v) for v in np.asarray(a, np.float64).ravel()]


def _slope_json(p: NoiseParams, j: int) -> dict[str, Any]:
    return {k: _floats(getattr(p, k)[j])[0] for k in ("N", "B", "K")} | {
        f"{k}_interval": _floats([getattr(p, k + "_lo")[j], getattr(p, k + "_hi")[j]]) for k in ("N", "B", "K")} | {
        f"tau_{k}_s": _floats(getattr(p, "tau_" + k)[j])[0] for k in ("N", "B", "K")}


def report_json(rep: NoiseReport, source: str = "") -> dict[str, Any]:
    """The ``noise.json`` dict of a report (NaN written as null).

    Args:
        rep: :func:`noise_report` result.
        source: the recording's path (recorded as given).
    """
    out: dict[str, Any] = {
        "recording": source,
        "stretch": {"start_index": rep.start, "stop_index": rep.stop, "t_start_s": rep.t_start, "t_end_s": rep.t_end,
                    "duration_s": rep.t_end - rep.t_start, "how": rep.how},
        "fs_hz": rep.fs,
        "dt_max_relative_deviation": rep.dt_spread,
        "level": next(iter(rep.sensors.values())).params.level,
        "model": "AVAR(tau) = N^2/tau + 3 Q^2/tau^2 + (2 ln2/pi) B^2 + K^2 tau/3 + R^2 tau^2/2 + Gauss-Markov (IEEE Std 952); "
                 "the processes selected by WVIC and fitted jointly over all dyadic cluster times (GMWM, jaxcal.gmwm); B, K null "
                 "where the model selected lacks them",
        "estimator": "gmwm",
        "second_opinion": "slope_line: N read at tau ~ 1 s, B = min ADEV / 0.664, K on the +1/2 line (jaxcal.allan.fit_noise)",
        "combine_axes": "imu.yaml / openvins_noise.yaml hold the largest value over the three axes (conservative)",
        "sensors": {},
        "imu_yaml": rep.kalibr,
        "warnings": list(rep.warnings),
    }
    for s, r in rep.sensors.items():
        p = r.params
        axes = {}
        for j in range(r.allan.adev.shape[1]):
            ax = _AXES[j] if j < 3 else str(j)
            axes[ax] = {
                "N": _floats(p.N[j])[0], "N_interval": _floats([p.N_lo[j], p.N_hi[j]]), "tau_N_s": _floats(p.tau_N[j])[0],
                "B": _floats(p.B[j])[0], "B_interval": _floats([p.B_lo[j], p.B_hi[j]]), "tau_B_s": _floats(p.tau_B[j])[0],
                "K": _floats(p.K[j])[0], "K_interval": _floats([p.K_lo[j], p.K_hi[j]]), "tau_K_s": _floats(p.tau_K[j])[0],
                "K_upper_bound": _floats(r.K_bound[j])[0], "K_is_bound": bool(not np.isfinite(p.K[j])),
                "adev": _floats(r.allan.adev[:, j]), "adev_lo": _floats(r.adev_lo[:, j]), "adev_hi": _floats(r.adev_hi[:, j]),
                "gmwm": fit_json(r.gmwm[j], rep.advice[s][j]), "slope_line": _slope_json(r.slope, j),
            }
        out["sensors"][s] = {"units": SI_UNITS[s], "conversion": rep.conversion[s], "taus_s": _floats(r.allan.taus),
                             "n_terms": [int(v) for v in r.allan.n_terms], "axes": axes}
    return out


def summary_lines(rep: NoiseReport) -> list[str]:
    """A short human summary: N, B, K per sensor (largest over axes) in SI and the usual units.

    Args:
        rep: :func:`noise_report` result.
    """
    lines = [f"stretch {rep.t_start:.2f} to {rep.t_end:.2f} s ({rep.t_end - rep.t_start:.0f} s, {rep.stop - rep.start} samples "
             f"at {rep.fs:.4g} Hz): {rep.how}"]
    for s, r in rep.sensors.items():
        p = r.params
        fitted_b = bool(np.isfinite(p.B).any())  # else the slope line's B, labelled
        n, b, k = float(np.max(p.N)), float(np.nanmax(p.B) if fitted_b else np.max(r.slope.B)), float(np.max(r.K_bound))
        kb = "<= " if not np.all(np.isfinite(p.K)) else ""
        u = SI_UNITS[s]
        if s == "gyr":
            usual = (f"{np.degrees(n) * 60:.3g} deg/sqrt(h), {np.degrees(b) * 3600:.3g} deg/h, "
                     f"{kb}{np.degrees(k) * 3600 * 60:.3g} deg/h/sqrt(h)")
        else:
            usual = f"{n / G0 * 1e6:.3g} ug/sqrt(Hz), {b / G0 * 1e6:.3g} ug, {kb}{k / G0 * 1e6:.3g} ug/s/sqrt(Hz)"
        models = ", ".join(sorted({"+".join(f.model) for f in r.gmwm}))
        lines.append(f"{s}: N {n:.3g} {u['N']}, B{'' if fitted_b else ' (slope line)'} {b:.3g} {u['B']}, K {kb}{k:.3g} {u['K']} "
                     f"({usual}; largest over axes; model {models})")
        lines += advice_lines(s, rep.advice[s])
    return lines + [f"warning: {w}" for w in rep.warnings]


def gauss_markov_adev(taus: Float[Array, " T"], sigma: float, tau_b: float) -> Float[np.ndarray, " T"]:
    """Allan deviation of a first-order Gauss-Markov rate of stationary std ``sigma`` and correlation time ``tau_b``.

    ``AVAR(T) = sigma^2 (tau_b/T)^2 (2 T/tau_b - 3 + 4 exp(-T/tau_b) - exp(-2 T/tau_b))`` (continuous
    time). Its maximum, about ``0.62 sigma`` at ``T ~ 1.9 tau_b``, is what a bias-instability read
    (``min ADEV / 0.664``) can be compared with: a Gauss-Markov process has no flicker floor.

    Args:
        taus: cluster times (s).
        sigma: stationary standard deviation.
        tau_b: correlation time (s).
    """
    u = np.asarray(taus, np.float64) / tau_b
    return sigma * np.sqrt(np.maximum((2 * u - 3 + 4 * np.exp(-u) - np.exp(-2 * u)) / u**2, 0.0))


def allan_figure(rep: NoiseReport, title: str = ""):
    """Log-log Allan deviation per sensor and axis with interval bars, the GMWM model and its N and K lines.

    Returns a ``matplotlib.figure.Figure`` (no pyplot; save it with ``fig.savefig``).

    Args:
        rep: :func:`noise_report` result.
        title: figure title.
    """
    from matplotlib.figure import Figure

    sens = list(rep.sensors)
    fig = Figure(figsize=(6.0 * len(sens), 4.6), layout="constrained")
    axs = fig.subplots(1, len(sens), squeeze=False)[0]
    colors = ("C0", "C1", "C2", "C3")
    for ax, s in zip(axs, sens):
        r = rep.sensors[s]
        p, taus = r.params, r.allan.taus
        for j in range(r.allan.adev.shape[1]):
            c = colors[j % 4]
            y = r.allan.adev[:, j]
            ax.errorbar(taus, y, yerr=[y - r.adev_lo[:, j], r.adev_hi[:, j] - y], fmt="o-", ms=2.5, lw=0.8, elinewidth=0.6,
                        capsize=1.5, color=c, label=f"{_AXES[j] if j < 3 else j}")
            ax.plot(taus, p.N[j] / np.sqrt(taus), "--", color=c, lw=0.7, alpha=0.8)
            g = r.gmwm[j]
            ax.plot(g.m / g.fs, np.sqrt(g.avar_model), ":", color=c, lw=1.0)
            kk = r.K_bound[j]
            ax.plot(taus, kk * np.sqrt(taus / 3.0), ls="-." if np.isfinite(p.K[j]) else (0, (1, 3)), color=c, lw=0.7, alpha=0.8)
        lo, hi = np.nanmin(r.adev_lo), np.nanmax(r.adev_hi)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylim(lo / 2.0, hi * 2.0)
        ax.set_xlabel("cluster time tau [s]")
        ax.set_ylabel(f"Allan deviation [{SI_UNITS[s]['signal']}]")
        ax.set_title(f"{s}: GMWM model (:), its N (--) and K (-.; dotted = upper bound)", fontsize=9)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=8, loc="lower left")  # loc="best" warns (a stderr line) when placing it is slow
    if title:
        fig.suptitle(title, fontsize=10)
    return fig
