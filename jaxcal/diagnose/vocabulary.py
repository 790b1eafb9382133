"""The discrepancy vocabulary (CONVENTIONS.md): one :class:`Effect` record per effect, and the registry.

A record holds everything jaxcal knows about one effect: its parameter (name, size, shape in the
report and the model file), the sensors it applies to, its units, the size an engineer would call
plausible (``detectable``: a minimum detectable size above it means the recording cannot reveal the
effect) and the plausible range of an estimate (``plausible_range``: beyond it an estimate is a
misspecification, never a name), the motion that excites it, its step of the forward model
(``forward``, JAX, at its ``stage`` of the chain of :mod:`jaxcal.diagnose.effects`) and its
inverse (``inverse``, numpy, used by the ``diagnosed`` method's ``apply``).

Every table keyed by effect (``effects.UNITS``, ``PLAUSIBLE``, ``PLAUSIBLE_RANGE``, ``EXCITE``,
``LAYOUT``, ``EFFECT_NAMES``, ``methods.diagnosed.CARRIED`` ...) is derived from :data:`REGISTRY`.
Adding an effect is one record and one line, ``register(MY_EFFECT)`` (see
``tests/toy_effect.py``); the selection, intervals, report and ``diagnosed`` model pick it up.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Float
from scipy.interpolate import CubicSpline

from jaxcal.arrays import Array
from jaxcal.constants import G0
from jaxcal.diagnose.resample import shift_signal, stretch_signal

__all__ = [
    "Effect",
    "InverseContext",
    "REGISTRY",
    "register",
    "unregister",
    "get",
    "smooth",
    "invert_nonlinearity",
    "unshift",
    "OFFDIAG",
]

# Off-diagonal (row, col) entries of the misalignment matrix, in parameter order.
OFFDIAG = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))


class InverseContext(NamedTuple):
    """What an inverse step may use besides its own input: the recording's times ``t`` (N,), its
    sequences ``slices``, and ``dT`` (N, 1) its temperature minus the model's ``T0`` (None when no
    carried effect needs the temperature)."""

    t: np.ndarray
    slices: list[slice]
    dT: np.ndarray | None


def _flat(v) -> np.ndarray:
    return np.asarray(v, np.float64).reshape(-1)


@dataclass(frozen=True)
class Effect:
    """One effect of the vocabulary.

    Args:
        name: the effect's name (report ``name``, model-file key).
        param: its parameter's name (report ``params`` / ``stderr`` key).
        size: number of flat parameters in the sensor's ``theta``.
        shape: the parameter's shape in the report and the model file (``()``: a scalar).
        sensors: the sensors it applies to, ``("acc", "gyr")`` order.
        units: unit of the parameter per sensor.
        detectable: per sensor, a size an engineer would call plausible (a smallest detectable size
            above it: "not excited"); empty: no such warning.
        plausible_range: per sensor, the largest |component| an estimate may have and still be a name.
        excites: the motion or conditions that excite it (said in warnings).
        stage: its place in the forward chain (-1: the reference's clock, 0: the physical input, 1:
            time, 2: scale nonlinearity, 3: misalignment, 4-6: temperature and drift terms); ``None``: not a smooth
            effect (saturation, handled on raw counts).
        forward: ``(p, x, inp) -> x``, the step of the forward model (JAX; ``p`` its flat
            parameters, ``x`` (N, 3) the input so far, ``inp`` the :class:`~jaxcal.diagnose.effects.Inputs`).
        retime: ``(p, inp) -> inp``, a time map of the reference signals applied before every other
            step (``clock_skew``; its ``forward`` is None).
        inverse: ``(p, x, ctx) -> x``, that step undone (numpy; ``p`` in ``shape``,
            :class:`InverseContext`); None: not inverted on its own.
        coupled: acts on the physical input through the other sensor (lever arm, g-sensitivity):
            the ``diagnosed`` method inverts such effects jointly, after every per-sensor step.
        needs: recording channels its inverse needs (``"temp"``: the model also stores ``T0``).
        not_carried: why a ``diagnosed`` model does not carry it ("" when it does or cannot be named).
        to_flat: public value (report / model file) -> flat parameters; default ravel.
        from_flat: flat parameters -> public value (nested lists or a float); default reshape.
    """

    name: str
    param: str
    size: int
    shape: tuple[int, ...]
    sensors: tuple[str, ...]
    units: dict[str, str]
    detectable: dict[str, float]
    plausible_range: dict[str, float]
    excites: str
    stage: float | None
    forward: Callable[[Any, Any, Any], Any] | None = None
    inverse: Callable[[np.ndarray, np.ndarray, InverseContext], np.ndarray] | None = None
    retime: Callable[[Any, Any], Any] | None = None
    coupled: bool = False
    needs: tuple[str, ...] = ()
    not_carried: str = ""
    to_flat: Callable[[Any], np.ndarray] = field(default=_flat)
    from_flat: Callable[[np.ndarray], Any] | None = None

    @property
    def carried(self) -> bool:
        """A ``diagnosed`` model carries it and its ``apply`` inverts it."""
        return self.inverse is not None or self.coupled

    def public(self, flat) -> Any:
        """The report's / model file's value of the flat parameters ``flat``."""
        v = np.asarray(flat)
        if self.from_flat is not None:
            return self.from_flat(v)
        if self.shape == ():
            return float(v[0])
        return v.reshape(self.shape).tolist()


REGISTRY: dict[str, Effect] = {}
"""The vocabulary, in the order of CONVENTIONS.md's table (filled by :func:`register` below)."""


def register(effect: Effect) -> Effect:
    """Add ``effect`` to :data:`REGISTRY` (refused if its name is taken); returns it."""
    if effect.name in REGISTRY:
        raise ValueError(f"effect {effect.name!r} is already registered")
    REGISTRY[effect.name] = effect
    return effect


def unregister(name: str) -> None:
    """Remove the effect ``name`` from :data:`REGISTRY` (a test's toy effect)."""
    REGISTRY.pop(name, None)


def get(name: str) -> Effect:
    """The record of effect ``name`` (KeyError if it is not in the vocabulary)."""
    return REGISTRY[name]


def smooth(sensor: str) -> list[Effect]:
    """The smooth effects of ``sensor`` in the order of the forward chain (stage, then registry
    order): the layout of its flat ``theta``."""
    es = [e for e in REGISTRY.values() if e.stage is not None and sensor in e.sensors]
    return sorted(es, key=lambda e: e.stage)


# ----------------------------------------------------------------------------- forward steps (JAX)


def _lever_arm(r, x, inp):
    cen = jnp.cross(inp.w, jnp.cross(inp.w, r)) if inp.ww is None else jnp.einsum("nij,j->ni", inp.ww, r)
    rot = jnp.cross(inp.wdot, r) + cen
    return x + rot / G0


def _g_sensitivity(g, x, inp):
    return x + inp.f @ g.reshape(3, 3).T


def _time_offset(tau, x, inp):
    return shift_signal(x, tau[0], inp.dt)


def _clock_skew(s_ppm, inp):
    """The reference signals on the IMU's clock: ``f, w, dw/dt`` (and ``ww``) at ``t + 1e-6 s tc``,
    one stretch of all their channels."""
    parts = [inp.f, inp.w, inp.wdot] + ([] if inp.ww is None else [inp.ww.reshape(-1, 9)])
    out = stretch_signal(jnp.concatenate(parts, axis=1), s_ppm[0] * 1e-6, inp.tc, inp.dt)
    ww = None if inp.ww is None else out[:, 9:].reshape(inp.ww.shape)
    return inp._replace(f=out[:, :3], w=out[:, 3:6], wdot=out[:, 6:9], ww=ww)


def _scale_nonlinearity(k2, x, inp):
    return x + k2 * x * x


def _misalignment(m, x, inp):
    mm = jnp.zeros((3, 3), x.dtype)
    for k, (i, j) in enumerate(OFFDIAG):
        mm = mm.at[i, j].set(m[k])
    return x + x @ mm.T


def _temperature_scale(k, x, inp):
    return (1.0 + k * inp.dT[:, None]) * x


def _temperature_bias(k, x, inp):
    return x + k * inp.dT[:, None]


def _bias_drift(d, x, inp):
    return x + d * inp.tc[:, None]


# ----------------------------------------------------------------------------- inverse steps (numpy)


def invert_nonlinearity(x2: Float[Array, "N 3"], k2: Float[Array, " 3"]) -> Float[Array, "N 3"]:
    """The root through the origin of ``x1 + k2 x1**2 = x2`` per axis, ``2 x2 / (1 + sqrt(1 + 4 k2 x2))``
    (exact for ``k2 = 0``); beyond the fold (``1 + 4 k2 x2 < 0``) the fold ``-1 / (2 k2)``.

    Args:
        x2: (N, 3) output of the nonlinearity.
        k2: (3,) quadratic coefficients.
    """
    k2 = np.broadcast_to(np.asarray(k2, np.float64), (3,))
    disc = 1.0 + 4.0 * k2 * x2
    root = 2.0 * x2 / (1.0 + np.sqrt(np.maximum(disc, 0.0)))
    with np.errstate(divide="ignore"):
        fold = np.where(k2 != 0.0, -0.5 / np.where(k2 != 0.0, k2, 1.0), 0.0)
    return np.where(disc < 0.0, np.broadcast_to(fold, x2.shape), root)


def unshift(x1: Float[Array, "N 3"], t: Float[Array, " N"], tau: float, slices: list[slice]) -> Float[Array, "N 3"]:
    """``x1(t + tau)`` at every sample (undo a delay ``tau``): a not-a-knot cubic spline through each
    sequence's samples, the edge sample held where ``t + tau`` leaves the sequence.

    Args:
        x1: (N, 3) delayed signal.
        t: (N,) sample times (s).
        tau: the delay (s; positive: the sensor reads late).
        slices: contiguous sequences (:func:`jaxcal.recording.sequence_slices`).
    """
    out = np.array(x1, np.float64, copy=True)
    for sl in slices:
        ts = t[sl]
        if len(ts) < 2:
            continue
        q = np.clip(ts + tau, ts[0], ts[-1])
        out[sl] = CubicSpline(ts, x1[sl], axis=0)(q)
    return out


def _misalignment_inverse(m, x, ctx):
    m = np.asarray(m, np.float64) * (1.0 - np.eye(3))
    return np.linalg.solve(np.eye(3) + m, x.T).T


def _misalignment_from_flat(v):
    m = np.zeros((3, 3))
    for k, (i, j) in enumerate(OFFDIAG):
        m[i, j] = v[k]
    return m.tolist()


def _misalignment_to_flat(v):
    v = np.asarray(v, np.float64)
    return np.array([v[i, j] for i, j in OFFDIAG]) if v.shape == (3, 3) else v.reshape(-1)


BOTH = ("acc", "gyr")

# ----------------------------------------------------------------------------- the records

LEVER_ARM = Effect(
    "lever_arm", "r", 3, (3,), ("acc",), {"acc": "m"}, {"acc": 0.05}, {"acc": 1.0},
    "angular acceleration and rates about several axes (a constant rate makes a lever arm look like a bias)",
    0.0, _lever_arm, coupled=True)
G_SENSITIVITY = Effect(
    "g_sensitivity", "G", 9, (3, 3), ("gyr",), {"gyr": "(rad/s)/g"}, {"gyr": 3e-3}, {"gyr": 0.02},
    "orientations that put gravity along each axis", 0.0, _g_sensitivity, coupled=True)
MISALIGNMENT = Effect(
    "misalignment", "m", 6, (3, 3), BOTH, {"acc": "rad", "gyr": "rad"}, {"acc": 0.01, "gyr": 0.01},
    # includes the frame rotation between a mocap body and the sensor that a diag baseline leaves to it (10 deg)
    {"acc": 0.2, "gyr": 0.2}, "inputs on every axis", 3.0, _misalignment, _misalignment_inverse,
    to_flat=_misalignment_to_flat, from_flat=_misalignment_from_flat)
SCALE_NONLINEARITY = Effect(
    "scale_nonlinearity", "k2", 3, (3,), BOTH, {"acc": "1/g", "gyr": "1/(rad/s)"}, {"acc": 0.01, "gyr": 0.01},
    {"acc": 0.05, "gyr": 0.05}, "large inputs of both signs on every axis", 2.0, _scale_nonlinearity,
    lambda k2, x, ctx: invert_nonlinearity(x, k2))
TIME_OFFSET = Effect(
    "time_offset", "tau", 1, (), BOTH, {"acc": "s", "gyr": "s"}, {"acc": 0.01, "gyr": 0.01}, {"acc": 2.0, "gyr": 2.0},
    "changing inputs (angular acceleration); with none a time offset is unobservable", 1.0, _time_offset,
    lambda tau, x, ctx: unshift(x, ctx.t, float(tau), ctx.slices))
CLOCK_SKEW = Effect(
    "clock_skew", "s", 1, (), BOTH, {"acc": "ppm", "gyr": "ppm"}, {"acc": 100.0, "gyr": 100.0},
    # a crystal is within 100 ppm; an internal RC oscillator counted at its nominal rate within about 1 %
    {"acc": 1e4, "gyr": 1e4}, "changing inputs over a long recording (the offset it makes grows with time from the middle)",
    -1.0, retime=_clock_skew,
    not_carried="a rate between the IMU's clock and its reference's does not transfer to a recording without that reference")
TEMPERATURE_BIAS = Effect(
    "temperature_bias", "k", 3, (3,), BOTH, {"acc": "g/degC", "gyr": "(rad/s)/degC"}, {"acc": 1e-3, "gyr": 5e-4},
    {"acc": 0.01, "gyr": 0.01}, "a temperature change that is not monotonic in time (heat and cool)", 5.0, _temperature_bias,
    lambda k, x, ctx: x - np.asarray(k, np.float64) * ctx.dT, needs=("temp",))
TEMPERATURE_SCALE = Effect(
    "temperature_scale", "k", 3, (3,), BOTH, {"acc": "1/degC", "gyr": "1/degC"}, {"acc": 5e-4, "gyr": 5e-4},
    {"acc": 0.01, "gyr": 0.01}, "a temperature change while the inputs are large", 4.0, _temperature_scale,
    lambda k, x, ctx: x / (1.0 + np.asarray(k, np.float64) * ctx.dT), needs=("temp",))
BIAS_DRIFT = Effect(
    "bias_drift", "d", 3, (3,), BOTH, {"acc": "g/s", "gyr": "(rad/s)/s"}, {"acc": 1e-5, "gyr": 1e-5},
    {"acc": 1e-3, "gyr": 1e-3}, "a longer recording", 6.0, _bias_drift,
    not_carried="a drift over the diagnosed recording's own clock does not transfer to another recording")
SATURATION = Effect(
    "saturation", "limit", 1, (), BOTH, {"acc": "LSB", "gyr": "LSB"}, {}, {}, "inputs beyond the full-scale range", None,
    not_carried="clipped samples cannot be restored")

for _e in (LEVER_ARM, G_SENSITIVITY, MISALIGNMENT, SCALE_NONLINEARITY, TIME_OFFSET, CLOCK_SKEW, TEMPERATURE_BIAS, TEMPERATURE_SCALE,
           BIAS_DRIFT, SATURATION):
    register(_e)
