"""Rich-motion recordings with concealed vocabulary effects (for the discrepancy benchmark).

Motion: static holds of ``hold_s`` seconds alternating with smooth rotations (sum of three
random sinusoids per axis, peak rate about ``w_peak`` rad/s, windowed by ``sin^2``) and a small
translational acceleration; orientation ``R_{n+1} = R_n Exp(w_n dt)``; specific force
``f = R^T (a + e_z)`` g; angular acceleration is the exact time derivative (``jax.jvp``).
Temperature: ``"cycle"`` (heat and cool, ``T0 + A sin^2(pi t / T)``), ``"ramp"`` (monotonic) or
``"none"``. Sensor: the thesis's baseline per axis ``raw = round(s (u + n) + b)`` with
``u = effects_forward(theta, inputs)`` (zero ``theta``: the baseline), white noise ``n`` and an
optional bias random walk, optional saturation at ``+-limit`` LSB. Recordings come out as
:class:`jaxcal.recording.Recording` (raw counts in LSB with the datasheet scale and zero bias).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.diagnose import effects as E
from jaxcal.recording import Recording, recording_from_dict
from jaxcal.rotation import integrate_orientation, random_rotation

__all__ = ["RichConfig", "motion", "simulate_recording", "simulate_batch"]


class RichConfig(NamedTuple):
    """Settings of a simulated rich-motion recording (units in the names).

    Static: :func:`motion` and the sensor model take it as a static argument (a new value recompiles).

    Attributes:
        n: samples per recording.
        fs: sampling rate (Hz).
        w_peak: peak rotation rate of the oscillation (rad/s).
        a_peak_g: peak translational acceleration (g).
        hold_s: length of each static hold and of each moving window (s).
        temp_profile: ``"cycle"``, ``"ramp"`` or ``"none"`` (see the module docstring).
        temp_base_c: base temperature ``T0`` (degC).
        temp_amp_c: temperature swing ``A`` (degC).
        acc_noise_g, gyr_noise_rads: white-noise std per axis (g, rad/s).
        acc_rw_g_per_sqrt_s, gyr_rw_rads_per_sqrt_s: bias random walk (g/sqrt(s), (rad/s)/sqrt(s)); 0: none.
        acc_lsb_per_g, gyr_lsb_per_rads: datasheet scales (LSB per g, LSB per rad/s).
        scale_tol: true scale per axis uniform within ``+-scale_tol`` (relative) of the datasheet.
        acc_bias_max_lsb, gyr_bias_max_lsb: true bias per axis uniform in ``+-`` this (LSB).
    """

    n: int = 20000
    fs: float = 100.0
    w_peak: float = 3.0
    a_peak_g: float = 0.2
    hold_s: float = 2.5
    temp_profile: str = "cycle"
    temp_base_c: float = 25.0
    temp_amp_c: float = 15.0
    acc_noise_g: float = 3e-3
    gyr_noise_rads: float = 1e-3
    acc_rw_g_per_sqrt_s: float = 0.0
    gyr_rw_rads_per_sqrt_s: float = 0.0
    acc_lsb_per_g: float = 16384.0
    gyr_lsb_per_rads: float = 7505.747
    scale_tol: float = 0.03
    acc_bias_max_lsb: float = 400.0
    gyr_bias_max_lsb: float = 300.0


def _gate(t, hold):
    ph = jnp.mod(t, 2 * hold)
    return jnp.where(ph < hold, 0.0, jnp.sin(jnp.pi * (ph - hold) / hold) ** 2)


@partial(jax.jit, static_argnames=("cfg",))
def motion(key: jax.Array, cfg: RichConfig) -> tuple[E.Inputs, Float[Array, " N"]]:
    """Reference motion ``Inputs`` (f, w, wdot, tc, dT, dt) and the temperature (N,) of one recording.

    Args:
        key: PRNG key (traced; :func:`simulate_batch` vmaps over keys).
        cfg: :class:`RichConfig` (static: a new value recompiles).
    """
    k1, k2, k3, k4, k5, k6 = jax.random.split(key, 6)
    dt = 1.0 / cfg.fs
    t = jnp.arange(cfg.n) * dt
    fr = jax.random.uniform(k1, (3, 3), minval=0.3, maxval=1.5)
    ph = jax.random.uniform(k2, (3, 3), maxval=2 * jnp.pi)
    amp = jax.random.uniform(k3, (3, 3), minval=0.2, maxval=1.0)
    amp = amp / amp.sum(0, keepdims=True) * cfg.w_peak * jax.random.uniform(k6, (1, 3), minval=0.5, maxval=1.0)
    fa = jax.random.uniform(k4, (3, 3), minval=0.3, maxval=1.5)
    aa = jax.random.uniform(k5, (3, 3), minval=-1.0, maxval=1.0) * cfg.a_peak_g / 3.0

    # a net turn about a random axis in every moving window (about 90 deg), so the holds visit
    # many orientations; plus the oscillation
    n_seg = int(cfg.n / cfg.fs / (2 * cfg.hold_s)) + 2
    axes = jax.random.normal(jax.random.fold_in(key, 11), (n_seg, 3))
    axes = axes / jnp.linalg.norm(axes, axis=1, keepdims=True) * (jnp.pi / cfg.hold_s)

    def rate(tt):
        s = jnp.sum(amp * jnp.sin(2 * jnp.pi * fr * tt + ph), axis=0)
        seg = jnp.floor(tt / (2 * cfg.hold_s)).astype(jnp.int32)
        return _gate(tt, cfg.hold_s) * (s + axes[seg])

    def lin_acc(tt):
        return _gate(tt, cfg.hold_s) * jnp.sum(aa * jnp.sin(2 * jnp.pi * fa * tt), axis=0)

    w = jax.vmap(rate)(t)
    wdot = jax.vmap(lambda tt: jax.jvp(rate, (tt,), (1.0,))[1])(t)
    r0 = random_rotation(jax.random.fold_in(key, 7))
    rs = integrate_orientation(r0, w[:-1], dt)
    a = jax.vmap(lin_acc)(t)
    f = jnp.einsum("nji,nj->ni", rs, a + jnp.array([0.0, 0.0, 1.0]))
    dur = cfg.n * dt
    if cfg.temp_profile == "cycle":
        temp = cfg.temp_base_c + cfg.temp_amp_c * jnp.sin(jnp.pi * t / dur) ** 2
    elif cfg.temp_profile == "ramp":
        temp = cfg.temp_base_c + cfg.temp_amp_c * t / dur
    else:
        temp = jnp.full_like(t, cfg.temp_base_c)
    tc = t - 0.5 * (t[0] + t[-1])
    return E.Inputs(f, w, wdot, tc, temp - jnp.mean(temp), jnp.asarray(dt)), temp


@partial(jax.jit, static_argnames=("cfg", "sensor"))
def _sensor_raw(key, cfg: RichConfig, sensor: str, theta, inp: E.Inputs):
    ks, kb, kn, kr = jax.random.split(key, 4)
    spec = cfg.acc_lsb_per_g if sensor == "acc" else cfg.gyr_lsb_per_rads
    bmax = cfg.acc_bias_max_lsb if sensor == "acc" else cfg.gyr_bias_max_lsb
    sig = cfg.acc_noise_g if sensor == "acc" else cfg.gyr_noise_rads
    rw = cfg.acc_rw_g_per_sqrt_s if sensor == "acc" else cfg.gyr_rw_rads_per_sqrt_s
    s = spec * (1.0 + jax.random.uniform(ks, (3,), minval=-cfg.scale_tol, maxval=cfg.scale_tol))
    b = jax.random.uniform(kb, (3,), minval=-bmax, maxval=bmax)
    u = E.effects_forward(sensor, theta, inp)
    noise = sig * jax.random.normal(kn, u.shape)
    walk = jnp.cumsum(rw * jnp.sqrt(inp.dt) * jax.random.normal(kr, u.shape), axis=0)
    return s * (u + noise + walk) + b, s, b


def _assemble(cfg: RichConfig, inp: E.Inputs, temp, sensors: dict, saturation: dict) -> tuple[Recording, dict]:
    """:class:`Recording` and truth of one simulated recording from its motion and, per sensor,
    ``(raw, scale, bias, theta)`` (raw unrounded): LSB rounding, then optional clipping."""
    rec = {"t": np.arange(cfg.n) / cfg.fs, "fs": cfg.fs, "acc_ref": np.asarray(inp.f), "gyr_ref": np.asarray(inp.w),
           "acc_lsb_per_g": cfg.acc_lsb_per_g, "gyr_lsb_per_rads": cfg.gyr_lsb_per_rads,
           "acc_bias_lsb": 0.0, "gyr_bias_lsb": 0.0}
    if cfg.temp_profile != "none":
        rec["temp"] = np.asarray(temp)
    truth: dict = {"theta": {}, "scale": {}, "bias": {}, "wdot": np.asarray(inp.wdot)}
    for sensor, (raw, sc, b, theta) in sensors.items():
        raw = np.round(np.asarray(raw, np.float64))
        if sensor in saturation:
            lim = float(saturation[sensor])
            raw = np.clip(raw, -lim, lim)
        rec[sensor] = raw
        truth["theta"][sensor] = theta
        truth["scale"][sensor] = np.asarray(sc)
        truth["bias"][sensor] = np.asarray(b)
    return recording_from_dict(rec, "simulated recording"), truth


def simulate_recording(key: jax.Array, cfg: RichConfig, effects: dict | None = None,
                       saturation: dict | None = None) -> tuple[Recording, dict]:
    """One recording (raw in LSB, reference ``acc_ref``/``gyr_ref``, ``temp``) and its hidden truth.

    Args:
        key: PRNG key.
        cfg: :class:`RichConfig` (static: a new value recompiles).
        effects: ``{(sensor, name): {param: value}}`` concealed smooth effects (vocabulary units).
        saturation: ``{sensor: limit_lsb}``.

    Returns:
        ``(rec, truth)``: the :class:`~jaxcal.recording.Recording` and
        ``{"theta": {sensor: flat}, "scale": {sensor: (3,)}, "bias": {sensor: (3,)}, "wdot": (N, 3)}``.
    """
    effects = effects or {}
    km, ka, kg = jax.random.split(key, 3)
    inp, temp = motion(km, cfg)
    sensors = {}
    for sensor, k in (("acc", ka), ("gyr", kg)):
        theta = E.theta_from_params(sensor, {name: p for (s, name), p in effects.items() if s == sensor})
        sensors[sensor] = (*_sensor_raw(k, cfg, sensor, jnp.asarray(theta, jnp.float32), inp), theta)
    return _assemble(cfg, inp, temp, sensors, saturation or {})


def simulate_batch(keys: jax.Array, cfg: RichConfig, thetas: dict[str, np.ndarray] | None = None,
                   saturation: list[dict] | None = None) -> list[tuple[Recording, dict]]:
    """Many recordings at once: :func:`simulate_recording` vmapped over seeds (and effect sizes).

    Args:
        keys: (S, 2) PRNG keys, one per recording (recording ``i`` equals
            ``simulate_recording(keys[i], cfg, ...)`` up to float rounding).
        cfg: :class:`RichConfig` shared by all (static).
        thetas: ``{sensor: (S, P)}`` flat effect parameters per recording
            (:func:`jaxcal.diagnose.effects.theta_from_params`); missing sensors: no effect.
        saturation: per recording ``{sensor: limit_lsb}`` (or None).

    Returns:
        ``[(rec, truth), ...]`` as :func:`simulate_recording` returns them.
    """
    keys = jnp.asarray(keys)
    n_rec = keys.shape[0]
    thetas = thetas or {}
    saturation = saturation or [{}] * n_rec
    ks = jax.vmap(lambda k: jax.random.split(k, 3))(keys)
    inp, temp = jax.vmap(lambda k: motion(k, cfg))(ks[:, 0])
    out = {}
    for j, sensor in ((1, "acc"), (2, "gyr")):
        th = np.zeros((n_rec, E.N_THETA[sensor])) if sensor not in thetas else np.asarray(thetas[sensor], np.float64)
        raw = jax.vmap(lambda k, t, i: _sensor_raw(k, cfg, sensor, t, i))(ks[:, j], jnp.asarray(th, jnp.float32), inp)
        out[sensor] = (*(np.asarray(a) for a in raw), th)
    return [_assemble(cfg, jax.tree_util.tree_map(lambda a: a[r], inp), temp[r],
                      {s: tuple(a[r] for a in v) for s, v in out.items()}, saturation[r]) for r in range(n_rec)]
