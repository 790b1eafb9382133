"""The discrepancy vocabulary (CONVENTIONS.md) as nested extensions of the baseline sensor model.

Per sensor the baseline is the thesis's model ``y = diag(s) x + b`` (``"diag"``, eq. 4.6) or
``y = S x + b`` (``"affine"``, eq. 2.3), with ``x`` the reference input. Here ``y`` is the sensor
output converted with the datasheet ("spec") values into physical units (g or rad/s), so
``s ~ 1`` and ``b ~ 0`` and every effect parameter comes out in the physical units of the
vocabulary table. Every effect parameter set to zero gives back the baseline exactly.

The full extended model, for one sensor (``dT = T - T0``, ``tc = t - t_mid``)::

    x_in  = f_ref + (dw/dt x r + w x (w x r)) / g0          (acc: lever_arm r)
    x_in  = w_ref + G f_ref                                  (gyr: g_sensitivity G)
    x1(t) = x_in(t - tau)                                    (time_offset tau, band-limited shift)
    x2    = x1 + k2 * x1**2                                  (scale_nonlinearity k2)
    x3    = (I + m) x2                                       (misalignment m, zero diagonal)
    u     = (1 + kts dT) * x3 + ktb dT + d tc                (temperature_scale, temperature_bias, bias_drift)
    y     = s * u + b   or   S u + b                         (baseline)

and ``saturation`` clips the raw output to ``[-limit, +limit]`` LSB (handled on raw counts, not
here). ``T0`` is fixed to the recording's mean temperature and ``t_mid`` to its mid time; both
only re-parametrise the baseline bias/scale. Effects of both sensors are separate candidates.

Parameters of all smooth effects of one sensor live in one flat vector (``theta``); the
:data:`LAYOUT` tables give each effect's slice, so code that fits a subset uses a 0/1 mask on the
flat vector (one compiled function for every subset).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.constants import G0

__all__ = [
    "OFFDIAG",
    "UNITS",
    "PLAUSIBLE",
    "PLAUSIBLE_RANGE",
    "EXCITE",
    "implausible",
    "SATURATION",
    "EFFECT_NAMES",
    "Slot",
    "LAYOUT",
    "N_THETA",
    "slot",
    "effect_mask",
    "theta_from_params",
    "params_from_theta",
    "Inputs",
    "as_jax",
    "shift_signal",
    "sensor_input",
    "effects_forward",
    "N_BASE",
    "baseline_apply",
    "identity_beta",
    "model_output",
    "regressors",
]

# effect name -> (parameter name, shape) for the smooth effects of each sensor, in model order.
_ACC_EFFECTS: tuple[tuple[str, str, tuple[int, ...]], ...] = (
    ("lever_arm", "r", (3,)),
    ("time_offset", "tau", ()),
    ("scale_nonlinearity", "k2", (3,)),
    ("misalignment", "m", (6,)),
    ("temperature_scale", "k", (3,)),
    ("temperature_bias", "k", (3,)),
    ("bias_drift", "d", (3,)),
)
_GYR_EFFECTS: tuple[tuple[str, str, tuple[int, ...]], ...] = (
    ("g_sensitivity", "G", (9,)),
    ("time_offset", "tau", ()),
    ("scale_nonlinearity", "k2", (3,)),
    ("misalignment", "m", (6,)),
    ("temperature_scale", "k", (3,)),
    ("temperature_bias", "k", (3,)),
    ("bias_drift", "d", (3,)),
)

# Off-diagonal (row, col) entries of the misalignment matrix, in parameter order.
OFFDIAG = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))

# Units of each effect's parameter, per sensor (for reports).
UNITS = {
    ("lever_arm", "acc"): "m",
    ("g_sensitivity", "gyr"): "(rad/s)/g",
    ("misalignment", "acc"): "rad",
    ("misalignment", "gyr"): "rad",
    ("scale_nonlinearity", "acc"): "1/g",
    ("scale_nonlinearity", "gyr"): "1/(rad/s)",
    ("time_offset", "acc"): "s",
    ("time_offset", "gyr"): "s",
    ("temperature_bias", "acc"): "g/degC",
    ("temperature_bias", "gyr"): "(rad/s)/degC",
    ("temperature_scale", "acc"): "1/degC",
    ("temperature_scale", "gyr"): "1/degC",
    ("bias_drift", "acc"): "g/s",
    ("bias_drift", "gyr"): "(rad/s)/s",
    ("saturation", "acc"): "LSB",
    ("saturation", "gyr"): "LSB",
}

# Sizes an engineer would call plausible for a MEMS IMU; a minimum detectable size above these
# means the recording cannot reveal the effect (used only for "not excited" warnings).
PLAUSIBLE = {
    ("lever_arm", "acc"): 0.05,
    ("g_sensitivity", "gyr"): 3e-3,
    ("misalignment", "acc"): 0.01,
    ("misalignment", "gyr"): 0.01,
    ("scale_nonlinearity", "acc"): 0.01,
    ("scale_nonlinearity", "gyr"): 0.01,
    ("time_offset", "acc"): 0.01,
    ("time_offset", "gyr"): 0.01,
    ("temperature_bias", "acc"): 1e-3,
    ("temperature_bias", "gyr"): 5e-4,
    ("temperature_scale", "acc"): 5e-4,
    ("temperature_scale", "gyr"): 5e-4,
    ("bias_drift", "acc"): 1e-5,
    ("bias_drift", "gyr"): 1e-5,
}

# The plausible range of each effect on a real MEMS IMU and rig: the largest |component| an
# estimate may have and still be a name (CONVENTIONS.md "plausible range"). An estimate outside
# it is not a physical effect of that size but a model that does not fit (a frame, clock or
# reference problem, or a noise model the data contradict); ``diagnose`` then reports a
# misspecification warning instead of naming it. Misalignment includes the frame rotation between
# a mocap body and the sensor that a ``diag`` baseline leaves to it (10 deg = 0.17 rad).
PLAUSIBLE_RANGE = {
    ("lever_arm", "acc"): 1.0,  # m
    ("g_sensitivity", "gyr"): 0.02,  # (rad/s)/g
    ("misalignment", "acc"): 0.2,  # rad
    ("misalignment", "gyr"): 0.2,  # rad
    ("scale_nonlinearity", "acc"): 0.05,  # 1/g
    ("scale_nonlinearity", "gyr"): 0.05,  # 1/(rad/s)
    ("time_offset", "acc"): 2.0,  # s
    ("time_offset", "gyr"): 2.0,  # s
    ("temperature_bias", "acc"): 0.01,  # g/degC
    ("temperature_bias", "gyr"): 0.01,  # (rad/s)/degC
    ("temperature_scale", "acc"): 0.01,  # 1/degC
    ("temperature_scale", "gyr"): 0.01,  # 1/degC
    ("bias_drift", "acc"): 1e-3,  # g/s
    ("bias_drift", "gyr"): 1e-3,  # (rad/s)/s
}

# Motion/conditions that excite each effect (used in warnings).
EXCITE = {
    "lever_arm": "angular acceleration and rates about several axes (a constant rate makes a lever arm look like a bias)",
    "g_sensitivity": "orientations that put gravity along each axis",
    "misalignment": "inputs on every axis",
    "scale_nonlinearity": "large inputs of both signs on every axis",
    "time_offset": "changing inputs (angular acceleration); with none a time offset is unobservable",
    "temperature_bias": "a temperature change that is not monotonic in time (heat and cool)",
    "temperature_scale": "a temperature change while the inputs are large",
    "bias_drift": "a longer recording",
}


def implausible(sensor: str, name: str, theta) -> float:
    """Largest |component| of effect ``name`` in ``theta`` over its :data:`PLAUSIBLE_RANGE`
    (> 1: outside the range; 0 for effects without a range).

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        name: effect name.
        theta: (P,) flat effect parameters of ``sensor``.
    """
    lim = PLAUSIBLE_RANGE.get((name, sensor))
    if lim is None:
        return 0.0
    sl = slot(sensor, name)
    v = np.asarray(theta, np.float64)[sl.start : sl.start + sl.size]
    return float(np.max(np.abs(v)) / lim)


SATURATION = "saturation"
EFFECT_NAMES = (
    "lever_arm",
    "g_sensitivity",
    "misalignment",
    "scale_nonlinearity",
    "time_offset",
    "temperature_bias",
    "temperature_scale",
    "bias_drift",
    "saturation",
)


class Slot(NamedTuple):
    """Where one effect's parameters sit in the flat ``theta`` of its sensor."""

    name: str
    param: str
    shape: tuple[int, ...]
    start: int
    size: int


def _layout(table) -> tuple[Slot, ...]:
    out, i = [], 0
    for name, param, shape in table:
        size = int(np.prod(shape)) if shape else 1
        out.append(Slot(name, param, shape, i, size))
        i += size
    return tuple(out)


LAYOUT: dict[str, tuple[Slot, ...]] = {"acc": _layout(_ACC_EFFECTS), "gyr": _layout(_GYR_EFFECTS)}
N_THETA = {s: sum(sl.size for sl in LAYOUT[s]) for s in LAYOUT}


def slot(sensor: str, name: str) -> Slot:
    """The :class:`Slot` of effect ``name`` for ``sensor`` (KeyError if it does not apply).

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        name: effect name.
    """
    for sl in LAYOUT[sensor]:
        if sl.name == name:
            return sl
    raise KeyError(f"effect {name!r} does not apply to sensor {sensor!r}")


def effect_mask(sensor: str, names) -> np.ndarray:
    """0/1 float mask over ``theta`` selecting the parameters of the effects ``names``.

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        names: effect names (``"saturation"`` is skipped).
    """
    m = np.zeros(N_THETA[sensor])
    for n in names:
        if n == SATURATION:
            continue
        sl = slot(sensor, n)
        m[sl.start : sl.start + sl.size] = 1.0
    return m


def theta_from_params(sensor: str, params: dict[str, dict[str, np.ndarray]]) -> np.ndarray:
    """Flat ``theta`` from ``{effect: {param: value}}`` (missing effects are zero).

    ``misalignment.m`` may be given as the (3, 3) matrix (its diagonal is ignored) or the 6
    off-diagonal entries; ``g_sensitivity.G`` as (3, 3) or 9 row-major entries.

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        params: ``{effect: {param: value}}``.
    """
    th = np.zeros(N_THETA[sensor])
    for name, p in params.items():
        if name == SATURATION:
            continue
        sl = slot(sensor, name)
        v = np.asarray(p[sl.param], dtype=np.float64)
        if name == "misalignment" and v.shape == (3, 3):
            v = np.array([v[i, j] for i, j in OFFDIAG])
        th[sl.start : sl.start + sl.size] = v.reshape(-1)
    return th


def params_from_theta(sensor: str, name: str, theta) -> dict[str, object]:
    """``{param: value}`` of effect ``name`` from flat ``theta`` (matrices as nested lists).

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        name: effect name.
        theta: (P,) flat effect parameters.
    """
    sl = slot(sensor, name)
    v = np.asarray(theta)[sl.start : sl.start + sl.size]
    if name == "misalignment":
        m = np.zeros((3, 3))
        for k, (i, j) in enumerate(OFFDIAG):
            m[i, j] = v[k]
        return {sl.param: m.tolist()}
    if name == "g_sensitivity":
        return {sl.param: v.reshape(3, 3).tolist()}
    if sl.shape == ():
        return {sl.param: float(v[0])}
    return {sl.param: v.tolist()}


class Inputs(NamedTuple):
    """Reference signals of one recording, all (N, ...) on a uniform time grid.

    ``f`` specific force (g), ``w`` body rate (rad/s), ``wdot`` angular acceleration (rad/s^2),
    ``tc`` time from the recording's middle (s), ``dT`` temperature minus its mean (degC, zeros
    without a temperature channel), ``dt`` sample interval (s); optional ``ww`` the centripetal
    operator ``[w]x [w]x`` smoothed as a product (a pose-derived reference: the sensor's smoothed
    output holds the smoothed product, not the product of smoothed rates, which differ at high rates).
    """

    f: Float[Array, "N 3"]
    w: Float[Array, "N 3"]
    wdot: Float[Array, "N 3"]
    tc: Float[Array, " N"]
    dT: Float[Array, " N"]
    dt: Float[Array, ""]
    ww: Float[Array, "N 3 3"] | None = None  # smoothed [w]x[w]x (the centripetal operator); None: from ``w``


def as_jax(inp: Inputs, dtype=jnp.float64) -> Inputs:
    """``inp`` with every present field a JAX array of ``dtype`` (absent optional fields stay None).

    Args:
        inp: reference signals (numpy or JAX).
        dtype: dtype of every field.
    """
    return Inputs(*[None if a is None else jnp.asarray(a, dtype) for a in inp])


def shift_signal(x: Float[Array, "N C"], tau: Float[Array, ""], dt: float | Float[Array, ""]) -> Float[Array, "N C"]:
    """``x(t - tau)`` by a band-limited (Fourier) shift of the even extension of ``x``.

    Differentiable in ``tau`` at every value (sub-sample and many-sample shifts alike); the even
    extension avoids the wrap-around jump of a plain circular shift. The first/last ``|tau|/dt``
    samples are extrapolated by reflection, so fits should drop them.

    Args:
        x: (N, C) signal.
        tau: shift (s; positive delays).
        dt: sample interval (s).
    """
    n = x.shape[0]
    xe = jnp.concatenate([x, x[::-1]], axis=0)
    spec = jnp.fft.rfft(xe, axis=0)
    freq = jnp.fft.rfftfreq(2 * n, d=dt)
    phase = jnp.exp(-2j * jnp.pi * freq * tau)
    return jnp.fft.irfft(spec * phase[:, None], n=2 * n, axis=0)[:n].astype(x.dtype)


def _split(sensor: str, theta):
    return {sl.name: theta[sl.start : sl.start + sl.size] for sl in LAYOUT[sensor]}


def sensor_input(sensor: str, theta: Float[Array, " Q"], inp: Inputs) -> Float[Array, "N 3"]:
    """The physical input the sensor sees before its own errors (lever arm / g-sensitivity).

    Args:
        sensor: ``"acc"`` or ``"gyr"`` (static).
        theta: (Q,) flat effect parameters.
        inp: reference signals.
    """
    p = _split(sensor, theta)
    if sensor == "acc":
        r = p["lever_arm"]
        cen = jnp.cross(inp.w, jnp.cross(inp.w, r)) if inp.ww is None else jnp.einsum("nij,j->ni", inp.ww, r)
        rot = jnp.cross(inp.wdot, r) + cen
        return inp.f + rot / G0
    g = p["g_sensitivity"].reshape(3, 3)
    return inp.w + inp.f @ g.T


def effects_forward(sensor: str, theta: Float[Array, " Q"], inp: Inputs) -> Float[Array, "N 3"]:
    """``u`` of the module docstring: the input after every smooth effect, before the baseline.

    Args:
        sensor: ``"acc"`` or ``"gyr"`` (static).
        theta: (Q,) flat effect parameters.
        inp: reference signals.
    """
    p = _split(sensor, theta)
    x = sensor_input(sensor, theta, inp)
    x = shift_signal(x, p["time_offset"][0], inp.dt)
    x = x + p["scale_nonlinearity"] * x * x
    m = p["misalignment"]
    mm = jnp.zeros((3, 3), x.dtype)
    for k, (i, j) in enumerate(OFFDIAG):
        mm = mm.at[i, j].set(m[k])
    x = x + x @ mm.T
    dT = inp.dT[:, None]
    return (1.0 + p["temperature_scale"] * dT) * x + p["temperature_bias"] * dT + p["bias_drift"] * inp.tc[:, None]


N_BASE = {"diag": 6, "affine": 12}


def baseline_apply(kind: str, beta: Float[Array, " B"], u: Float[Array, "N 3"]) -> Float[Array, "N 3"]:
    """Baseline ``y = diag(s) u + b`` (``beta = [s, b]``) or ``y = S u + b`` (``beta = [S.ravel(), b]``).

    Args:
        kind: ``"diag"`` or ``"affine"`` (static).
        beta: (B,) baseline parameters.
        u: (N, 3) input after the effects.
    """
    if kind == "diag":
        return beta[:3] * u + beta[3:6]
    return u @ beta[:9].reshape(3, 3).T + beta[9:12]


def identity_beta(kind: str) -> np.ndarray:
    """Baseline parameters of a perfect sensor (unit scale, zero bias)."""
    if kind == "diag":
        return np.array([1.0, 1, 1, 0, 0, 0])
    return np.concatenate([np.eye(3).ravel(), np.zeros(3)])


def model_output(kind: str, sensor: str, beta, theta, inp: Inputs) -> Float[Array, "N 3"]:
    """Full extended model output (physical units, before saturation and rounding).

    Args:
        kind: ``"diag"`` or ``"affine"`` (static).
        sensor: ``"acc"`` or ``"gyr"`` (static).
        beta: (B,) baseline parameters.
        theta: (Q,) flat effect parameters.
        inp: reference signals.
    """
    return baseline_apply(kind, beta, effects_forward(sensor, theta, inp))


def regressors(kind: str, sensor: str, beta, theta, inp: Inputs) -> tuple[Float[Array, "N 3 B"], Float[Array, "N 3 Q"]]:
    """Jacobians of the model output w.r.t. baseline and effect parameters, by forward-mode autodiff.

    These are the candidate regressors: around ``theta`` (usually zero, i.e. the baseline) the
    output changes by ``J_beta d_beta + J_theta d_theta``.

    Args:
        kind: ``"diag"`` or ``"affine"`` (static).
        sensor: ``"acc"`` or ``"gyr"`` (static).
        beta: (B,) baseline parameters (linearisation point).
        theta: (Q,) effect parameters (linearisation point).
        inp: reference signals.
    """
    jb = jax.jacfwd(lambda b: model_output(kind, sensor, b, theta, inp))(beta)
    jt = jax.jacfwd(lambda th: model_output(kind, sensor, beta, th, inp))(theta)
    return jb, jt
