"""The discrepancy vocabulary (CONVENTIONS.md) as nested extensions of the baseline sensor model.

Per sensor the baseline is the thesis's model ``y = diag(s) x + b`` (``"diag"``, eq. 4.6) or
``y = S x + b`` (``"affine"``, eq. 2.3), with ``x`` the reference input. Here ``y`` is the sensor
output converted with the datasheet ("spec") values into physical units (g or rad/s), so
``s ~ 1`` and ``b ~ 0`` and every effect parameter comes out in the physical units of the
vocabulary table. Every effect parameter set to zero gives back the baseline exactly.

The full extended model, for one sensor (``dT = T - T0``, ``tc = t - t_mid``)::

    f_ref, w_ref, dw/dt  at  t + 1e-6 s tc                   (clock_skew s ppm, band-limited stretch)

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

Each effect is one record of :mod:`jaxcal.diagnose.vocabulary` (its forward step, inverse,
units, plausible range, the motion that excites it); the chain above is those records' ``forward``
steps in the order of their ``stage``, and the tables here (``UNITS``, ``PLAUSIBLE_RANGE``,
``LAYOUT``, ...) are derived from them. Parameters of all smooth effects of one sensor live in one
flat vector (``theta``); the ``LAYOUT`` tables give each effect's slice, so code that fits a subset uses a 0/1 mask on the
flat vector (one compiled function for every subset).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.constants import G0  # noqa: F401 - re-exported (E.G0), as before the records
from jaxcal.diagnose import vocabulary as V
from jaxcal.diagnose.resample import shift_signal, stretch_signal

__all__ = [
    "OFFDIAG",
    "UNITS",  # noqa: F822 - derived on access (__getattr__)
    "PLAUSIBLE",  # noqa: F822 - derived on access (__getattr__)
    "PLAUSIBLE_RANGE",  # noqa: F822 - derived on access (__getattr__)
    "EXCITE",  # noqa: F822 - derived on access (__getattr__)
    "implausibility",
    "SATURATION",
    "EFFECT_NAMES",  # noqa: F822 - derived on access (__getattr__)
    "Slot",
    "LAYOUT",  # noqa: F822 - derived on access (__getattr__)
    "N_THETA",  # noqa: F822 - derived on access (__getattr__)
    "slot",
    "effect_mask",
    "theta_from_params",
    "params_from_theta",
    "Inputs",
    "as_jax",
    "shift_signal",
    "stretch_signal",
    "retimed",
    "sensor_input",
    "effects_forward",
    "N_BASE",
    "baseline_apply",
    "identity_beta",
    "model_output",
    "regressors",
    "linearized",
    "linearized_baseline",
]

OFFDIAG = V.OFFDIAG  # off-diagonal (row, col) entries of the misalignment matrix, in parameter order
SATURATION = "saturation"
_DERIVED = ("UNITS", "PLAUSIBLE", "PLAUSIBLE_RANGE", "EXCITE", "EFFECT_NAMES", "LAYOUT", "N_THETA")


def __getattr__(name: str):
    """The tables keyed by effect, derived from the records of :mod:`jaxcal.diagnose.vocabulary`
    whenever they are read (so a registered effect is in them):

    * ``UNITS[(effect, sensor)]``: the parameter's unit;
    * ``PLAUSIBLE[(effect, sensor)]``: a size an engineer would call plausible for a MEMS IMU; a
      minimum detectable size above it means the recording cannot reveal the effect ("not excited");
    * ``PLAUSIBLE_RANGE[(effect, sensor)]``: the largest |component| an estimate may have and still
      be a name (CONVENTIONS.md "plausible range"); beyond it ``diagnose`` reports a
      misspecification warning instead;
    * ``EXCITE[effect]``: the motion or conditions that excite a smooth effect;
    * ``EFFECT_NAMES``: the vocabulary's names; ``LAYOUT[sensor]``: the :class:`Slot` of each smooth
      effect in the sensor's flat ``theta``, in the order of the forward chain; ``N_THETA[sensor]``.
    """
    if name not in _DERIVED:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    reg = V.REGISTRY.values()
    if name == "UNITS":
        return {(e.name, s): e.units[s] for e in reg for s in e.sensors}
    if name == "PLAUSIBLE":
        return {(e.name, s): v for e in reg for s, v in e.detectable.items()}
    if name == "PLAUSIBLE_RANGE":
        return {(e.name, s): v for e in reg for s, v in e.plausible_range.items()}
    if name == "EXCITE":
        return {e.name: e.excites for e in reg if e.stage is not None}
    if name == "EFFECT_NAMES":
        return tuple(e.name for e in reg)
    if name == "LAYOUT":
        return {s: _layout(s) for s in ("acc", "gyr")}
    return {s: _n_theta(s) for s in ("acc", "gyr")}


def implausibility(sensor: str, name: str, theta) -> float:
    """Largest |component| of effect ``name`` in ``theta`` over its plausible range
    (``PLAUSIBLE_RANGE``; > 1: outside the range; 0 for effects without a range).

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        name: effect name.
        theta: (P,) flat effect parameters of ``sensor``.
    """
    lim = V.get(name).plausible_range.get(sensor) if name in V.REGISTRY else None
    if lim is None:
        return 0.0
    sl = slot(sensor, name)
    v = np.asarray(theta, np.float64)[sl.start : sl.start + sl.size]
    return float(np.max(np.abs(v)) / lim)


class Slot(NamedTuple):
    """Where one effect's parameters sit in the flat ``theta`` of its sensor."""

    name: str
    param: str
    shape: tuple[int, ...]
    start: int
    size: int


def _layout(sensor: str) -> tuple[Slot, ...]:
    """The :class:`Slot` of every smooth effect of ``sensor``, in the order of the forward chain."""
    out, i = [], 0
    for e in V.smooth(sensor):
        out.append(Slot(e.name, e.param, () if e.shape == () else (e.size,), i, e.size))
        i += e.size
    return tuple(out)


def _n_theta(sensor: str) -> int:
    return sum(e.size for e in V.smooth(sensor))


def slot(sensor: str, name: str) -> Slot:
    """The :class:`Slot` of effect ``name`` for ``sensor`` (KeyError if it does not apply).

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        name: effect name.
    """
    for sl in _layout(sensor):
        if sl.name == name:
            return sl
    raise KeyError(f"effect {name!r} does not apply to sensor {sensor!r}")


def effect_mask(sensor: str, names) -> np.ndarray:
    """0/1 float mask over ``theta`` selecting the parameters of the effects ``names``.

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        names: effect names (``"saturation"`` is skipped).
    """
    m = np.zeros(_n_theta(sensor))
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
    th = np.zeros(_n_theta(sensor))
    for name, p in params.items():
        if name == SATURATION:
            continue
        sl = slot(sensor, name)
        th[sl.start : sl.start + sl.size] = V.get(name).to_flat(p[sl.param])
    return th


def params_from_theta(sensor: str, name: str, theta) -> dict[str, object]:
    """``{param: value}`` of effect ``name`` from flat ``theta`` (matrices as nested lists).

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        name: effect name.
        theta: (P,) flat effect parameters.
    """
    sl = slot(sensor, name)
    return {sl.param: V.get(name).public(np.asarray(theta)[sl.start : sl.start + sl.size])}


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


def retimed(sensor: str, theta: Float[Array, " Q"], inp: Inputs) -> Inputs:
    """The reference signals with the time maps of ``sensor``'s effects applied (records with a
    ``retime`` step: ``clock_skew``), before every other step of the chain.

    Args:
        sensor: ``"acc"`` or ``"gyr"`` (static).
        theta: (Q,) flat effect parameters.
        inp: reference signals.
    """
    i = 0
    for e in V.smooth(sensor):
        if e.retime is not None:
            inp = e.retime(theta[i : i + e.size], inp)
        i += e.size
    return inp


def _apply_steps(sensor: str, theta, inp: Inputs, coupled: bool):
    x = inp.f if sensor == "acc" else inp.w
    i = 0
    for e in V.smooth(sensor):
        if e.coupled == coupled and e.forward is not None:
            x = e.forward(theta[i : i + e.size], x, inp)
        i += e.size
    return x


def sensor_input(sensor: str, theta: Float[Array, " Q"], inp: Inputs) -> Float[Array, "N 3"]:
    """The physical input the sensor sees before its own errors: the reference on the IMU's clock
    (:func:`retimed`), then the coupled effects (lever arm / g-sensitivity).

    Args:
        sensor: ``"acc"`` or ``"gyr"`` (static).
        theta: (Q,) flat effect parameters.
        inp: reference signals.
    """
    return _apply_steps(sensor, theta, retimed(sensor, theta, inp), True)


def effects_forward(sensor: str, theta: Float[Array, " Q"], inp: Inputs) -> Float[Array, "N 3"]:
    """``u`` of the module docstring: the input after every smooth effect, before the baseline
    (each record's ``forward`` step in the order of the chain).

    Args:
        sensor: ``"acc"`` or ``"gyr"`` (static).
        theta: (Q,) flat effect parameters.
        inp: reference signals.
    """
    x = sensor_input(sensor, theta, inp)
    i = 0
    for e in V.smooth(sensor):
        if not e.coupled and e.forward is not None:
            x = e.forward(theta[i : i + e.size], x, inp)
        i += e.size
    return x


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


def _linearized(
    kind: str, sensor: str, beta, theta, inp: Inputs, y
) -> tuple[Float[Array, "N 3 B"], Float[Array, "N 3 Q"], Float[Array, "N 3"]]:
    """:func:`regressors` and the residual ``y - model_output`` at ``(beta, theta)``; compiled as
    :data:`linearized` (``kind`` and ``sensor`` static), one executable per recording length serves
    every stage that linearises, refits or pools. Evaluated op by op instead, the resampling chain
    of :func:`effects_forward` took about 0.7 s a call on a 6000-sample recording.

    Args:
        kind: ``"diag"`` or ``"affine"`` (static).
        sensor: ``"acc"`` or ``"gyr"`` (static).
        beta: (B,) baseline parameters.
        theta: (Q,) effect parameters.
        inp: reference signals.
        y: (N, 3) sensor output (physical units).
    """
    jb, jt = regressors(kind, sensor, beta, theta, inp)
    return jb, jt, y - model_output(kind, sensor, beta, theta, inp)


def _linearized_baseline(kind: str, sensor: str, beta, theta, inp: Inputs, y) -> tuple[Float[Array, "N 3 B"], Float[Array, "N 3"]]:
    """:func:`_linearized` with the baseline's columns only (``theta`` held fixed):
    ``(J_beta, y - model_output)``; compiled as :data:`linearized_baseline`. Arguments as
    :func:`_linearized`'s.
    """
    u = effects_forward(sensor, theta, inp)
    jb = jax.jacfwd(lambda b: baseline_apply(kind, b, u))(beta)
    return jb, y - baseline_apply(kind, beta, u)


#: :func:`_linearized` compiled (``kind``, ``sensor`` static): ``(J_beta, J_theta, y - model_output)``.
linearized = jax.jit(_linearized, static_argnames=("kind", "sensor"))
#: :func:`_linearized_baseline` compiled (``kind``, ``sensor`` static): ``(J_beta, y - model_output)``.
linearized_baseline = jax.jit(_linearized_baseline, static_argnames=("kind", "sensor"))
