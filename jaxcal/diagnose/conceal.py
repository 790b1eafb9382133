"""Effects of the vocabulary concealed into real recordings with known truth (no reference needed
but for ``lever_arm``, which moves the reference point: :func:`jaxcal.diagnose.stress.conceal_lever_arm`),
and effects sized at a multiple of a null report's minimum detectable size.

Re-exported from :mod:`jaxcal.diagnose.stress`, where they lived.
"""

from __future__ import annotations

import jax
import numpy as np

from jaxcal.diagnose import effects as E
from jaxcal.recording import Recording

__all__ = [
    "conceal",
    "conceal_clock_skew",
    "conceal_drift",
    "conceal_gsens",
    "conceal_gsens_cal",
    "conceal_lever_arm_gyro",
    "conceal_misalignment",
    "conceal_shift",
    "effect_at_mds",
]


# ----------------------------------------------------------------------------- concealed IMU effects


def conceal_shift(rec: Recording, tau: float, sensors: tuple[str, ...] = ("acc", "gyr")) -> Recording:
    """Delay the IMU streams ``sensors`` by ``tau`` s (band-limited shift): they read x(t - tau).

    Uses :func:`jaxcal.diagnose.effects.shift_signal` with the median step; the first/last
    ``|tau| / dt`` samples are reflections. Truth: that sensor's time_offset += tau.

    Args:
        rec: the recording.
        tau: delay (s); positive: the streams lag.
        sensors: the streams to delay.
    """
    dt = float(np.median(np.diff(rec.t)))
    return rec.replace(**{k: np.asarray(E.shift_signal(jax.numpy.asarray(getattr(rec, k)), jax.numpy.asarray(tau), dt), np.float64)
                          for k in sensors})


def conceal_gsens(rec: Recording, G: np.ndarray) -> Recording:
    """Gyro reads ``+ G f`` with ``f`` the measured specific force (g), ``G`` (3, 3) or (9,) in
    (rad/s)/g. Truth: g_sensitivity += G (to first order; ``f`` is the measured, not the true, force).

    Args:
        rec: the recording (``acc`` in g, ``gyr`` in rad/s).
        G: (3, 3) or (9,) g-sensitivity ((rad/s)/g).
    """
    return rec.replace(gyr=rec.gyr + rec.acc @ np.asarray(G).reshape(3, 3).T)


def conceal_lever_arm_gyro(rec: Recording, r: np.ndarray, gyr_cal=None, acc_cal=None) -> Recording:
    """Move the accelerometer by ``r`` (m, body frame) on the same rigid body, from the recording's
    own gyroscope: ``f += (dw/dt x r + w x (w x r)) / g0`` with ``w`` the (calibrated) gyroscope and
    ``dw/dt`` its five-point derivative. Needs no reference; truth: lever_arm += r (reference-free
    mode; the added term carries the gyro's noise and any gyro calibration error, to first order).

    Args:
        rec: the recording (``acc`` in g, or LSB with ``acc_lsb_per_g``; ``gyr`` in rad/s unless
            ``gyr_cal`` is given).
        r: (3,) displacement (m).
        gyr_cal: optional :class:`~jaxcal.sensor.LinearCal` turning ``gyr`` into rad/s.
        acc_cal: optional :class:`~jaxcal.sensor.LinearCal` of ``acc``: the added force (g) enters
            its output as ``A^-1 add``.
    """
    from jaxcal.diagnose.kinematics import derivative5, lever_force

    w = np.asarray(rec.gyr, np.float64) if gyr_cal is None else np.asarray(gyr_cal.apply(np.asarray(rec.gyr, np.float64)))
    dt = float(np.median(np.diff(rec.t)))
    r = np.asarray(r, np.float64)
    add = lever_force(w, derivative5(w, dt), r)
    if acc_cal is not None:
        add = np.linalg.solve(np.asarray(acc_cal.A, np.float64), add.T).T
    elif rec.acc_unit == "LSB":
        if rec.acc_lsb_per_g is None:
            raise ValueError("conceal_lever_arm_gyro: raw accelerometer counts need acc_lsb_per_g")
        add = add * np.broadcast_to(np.asarray(rec.acc_lsb_per_g, np.float64), (3,))
    return rec.replace(acc=np.asarray(rec.acc, np.float64) + add)


def conceal_gsens_cal(rec: Recording, G: np.ndarray, acc_cal, gyr_cal) -> Recording:
    """Gyro reads ``+ G f`` with ``f`` the accelerometer calibrated by ``acc_cal`` (g) and the
    added rate entering the gyro's output through ``gyr_cal`` (``A_g^-1 G f``): the g-sensitivity
    of :func:`conceal_gsens` for a recording in any units. Truth: g_sensitivity += G (first order).

    Args:
        rec: the recording.
        G: (3, 3) or (9,) g-sensitivity ((rad/s)/g).
        acc_cal, gyr_cal: :class:`~jaxcal.sensor.LinearCal` of the two sensors.
    """
    f = np.asarray(acc_cal.apply(np.asarray(rec.acc, np.float64)))
    add = f @ np.asarray(G, np.float64).reshape(3, 3).T
    return rec.replace(gyr=np.asarray(rec.gyr, np.float64) + np.linalg.solve(np.asarray(gyr_cal.A, np.float64), add.T).T)


def conceal_misalignment(rec: Recording, sensor: str, m6: np.ndarray) -> Recording:
    """Sensor reads ``(I + m) y`` (``m`` off-diagonal, entries ``m6`` in ``E.OFFDIAG`` order).

    Truth: misalignment about m (to first order in m and the as-recorded scale error).

    Args:
        rec: the recording.
        sensor: ``"acc"`` or ``"gyr"``.
        m6: (6,) off-diagonal entries of ``m``, in ``E.OFFDIAG`` order.
    """
    mm = np.zeros((3, 3))
    for k, (i, j) in enumerate(E.OFFDIAG):
        mm[i, j] = m6[k]
    y = getattr(rec, sensor)
    return rec.replace(**{sensor: y + y @ mm.T})


def conceal_drift(rec: Recording, sensor: str, d: np.ndarray) -> Recording:
    """Sensor reads ``+ d (t - t_mid)`` (a linear bias drift, ``d`` (3,) unit/s, ``t_mid`` the
    recording's mid time). Truth: bias_drift += d (up to the baseline's scale).

    Args:
        rec: the recording.
        sensor: ``"acc"`` or ``"gyr"``.
        d: (3,) drift rate (the sensor's unit per s).
    """
    t = rec.t
    return rec.replace(**{sensor: getattr(rec, sensor) + np.outer(t - 0.5 * (t[0] + t[-1]), d)})


def conceal(rec: Recording, sensor: str, name: str, v: np.ndarray) -> Recording:
    """Conceal vocabulary effect ``name`` of ``sensor`` with flat parameters ``v``.

    ``lever_arm`` (acc; v = r), ``time_offset`` (v = [tau]), ``g_sensitivity`` (gyr; v = G flat),
    ``misalignment`` (v = m6), ``bias_drift`` (v = d), ``clock_skew`` (v = [ppm]; the reference's clock,
    so both sensors). Raises KeyError for any other name.

    Args:
        rec: the recording (``acc``/``gyr`` in g and rad/s; a pose for ``lever_arm``).
        sensor: ``"acc"`` or ``"gyr"``.
        name: the vocabulary effect (``docs/CONVENTIONS.md``).
        v: flat parameters of the effect (vocabulary units).
    """
    if name == "lever_arm":
        from jaxcal.diagnose.stress import conceal_lever_arm  # the reference point moved (stress's geometry)

        return conceal_lever_arm(rec, v)
    if name == "time_offset":
        return conceal_shift(rec, float(v[0]), (sensor,))
    if name == "g_sensitivity":
        return conceal_gsens(rec, v)
    if name == "misalignment":
        return conceal_misalignment(rec, sensor, v)
    if name == "bias_drift":
        return conceal_drift(rec, sensor, v)
    if name == "clock_skew":  # the reference's clock: both sensors
        return conceal_clock_skew(rec, float(v[0]))
    raise KeyError(name)


def conceal_clock_skew(rec: Recording, ppm: float) -> Recording:
    """Make the reference clock run ``1 + ppm 1e-6`` times as fast as the IMU's about the
    recording's middle time ``c``: the reference motion of grid time ``u`` becomes that of
    ``c + (u - c) / (1 + ppm 1e-6)``, so the IMU stamped ``t`` saw the motion the reference stamps
    ``c + (1 + ppm 1e-6) (t - c)``. The IMU streams are not touched.

    Rate references (``acc_ref``, ``gyr_ref``) are resampled by a not-a-knot cubic spline (held at
    the ends), a pose on the grid by the reference's own interpolation
    (:func:`jaxcal.diagnose.stress.shift_reference_clock`'s: linear position, slerp), and a track
    ``gt_t`` is re-stamped ``c + (1 + ppm 1e-6) (gt_t - c)``. Values are not rescaled (a rate in
    the reference's seconds would be ``1 + ppm 1e-6`` smaller: the baseline's scale).

    Truth: clock_skew += ppm for both sensors (CONVENTIONS.md), held at the middle ``c``.

    Args:
        rec: the recording (a rate or pose reference).
        ppm: the skew (ppm; positive: the reference clock runs fast).
    """
    from scipy.interpolate import CubicSpline

    from jaxcal.diagnose.stress import _sampler  # the reference's own interpolation, gaps and all

    t = np.asarray(rec.t, np.float64)
    c = 0.5 * (t[0] + t[-1])
    q = np.clip(c + (t - c) / (1.0 + ppm * 1e-6), t[0], t[-1])
    changes = {k: CubicSpline(t, np.asarray(getattr(rec, k), np.float64), axis=0)(q)
               for k in ("acc_ref", "gyr_ref") if getattr(rec, k) is not None}
    if rec.pos_ref is not None and rec.quat_ref is not None:
        p, qq, ok = _sampler(rec, None)(q)
        changes.update(pos_ref=p, quat_ref=qq, ref_valid=ok)
        if rec.gt_t is not None:
            changes["gt_t"] = c + (1.0 + ppm * 1e-6) * (np.asarray(rec.gt_t, np.float64) - c)
    return rec.replace(**changes)


# ----------------------------------------------------------------------------- effects sized by a null report


def effect_at_mds(rng: np.random.Generator, null_report: dict, sensor: str, name: str, m: float,
                  y: np.ndarray) -> tuple[dict, dict, np.ndarray]:
    """An effect of ``m`` times its minimum detectable size, in a random direction of its parameters.

    The size comes from the null report's detectability entry (``mds``: Fisher matrix, detectable
    components, noncentrality ``lambda_star``), so the injected effect is ``m`` x MDS along a random
    direction of the detectable components. Saturation: a clipping limit ``m`` x the detectable depth
    below the model's noiseless peak (or the observed peak of ``y``).

    Args:
        rng: numpy generator for the direction.
        null_report: :func:`jaxcal.diagnose.diagnose_recording`'s report of the recording without it.
        sensor, name: the vocabulary effect (``docs/CONVENTIONS.md``).
        m: size in multiples of the MDS.
        y: (N, 3) the sensor's output (the saturation fallback peak).

    Returns:
        ``(effects, saturation, truth)``: the simulator's effect parameters ``{(sensor, name): params}``,
        the saturation limits ``{sensor: limit}``, and the flat true parameters.
    """
    md = null_report["sensors"][sensor]["mds"][name]
    if name == "saturation":
        # the depth is below the model's noiseless peak (the observed peak sits a few noise sd above it)
        peak = float(md.get("predicted_peak_lsb", np.max(np.abs(y))))
        lim = float(np.floor(peak - m * md["depth_lsb"]))
        return {}, {sensor: lim}, np.array([lim])
    F = np.asarray(md["fisher"])
    comp = np.asarray(md["components"])
    v = rng.standard_normal(len(comp)) * comp
    u = v / np.linalg.norm(v)
    th = m * np.sqrt(md["lambda_star"] / float(u @ F @ u)) * u
    sl = E.slot(sensor, name)
    params = {sl.param: th if sl.shape != () else th[:1]}
    flat = np.zeros(E.N_THETA[sensor])
    flat[sl.start : sl.start + sl.size] = th
    return {(sensor, name): params}, {}, flat[sl.start : sl.start + sl.size]

