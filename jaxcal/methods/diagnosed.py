"""Method ``diagnosed``: the baseline linear calibration plus the effects ``jaxcal diagnose`` named,
inverted on new data.

``diagnose`` (:mod:`jaxcal.diagnose`) fits, per sensor, the extended forward model of
:mod:`jaxcal.diagnose.effects` (``dT = T - T0``)::

    x_in  = f + (dw/dt x r + w x (w x r)) / g0            (acc: lever_arm r, m)
    x_in  = w + G f                                        (gyr: g_sensitivity G, (rad/s)/g)
    x1(t) = x_in(t - tau)                                  (time_offset tau, s)
    x2    = x1 + k2 * x1**2                                (scale_nonlinearity k2, per axis)
    x3    = (I + m) x2                                     (misalignment m, zero diagonal, rad)
    u     = (1 + kts dT) * x3 + ktb dT                     (temperature_scale kts, temperature_bias ktb)
    raw   = S u + b                                        (baseline, LSB or physical units)

with ``S, b`` the baseline (``diag`` or ``affine``) composed with the datasheet conversion, so
``raw`` is the recording's own output. The state stores, per sensor, the forward ``S`` (3, 3) and
``b`` (3,) (as the linear methods do: applied as ``x = A (y - b)``, ``A = S^{-1}``) and one array per
carried effect in the units ``diagnose`` reports (``lever_arm`` (3,) m, ``g_sensitivity`` (3, 3),
``misalignment`` (3, 3), ``scale_nonlinearity`` (3,), ``time_offset`` () s,
``temperature_bias`` / ``temperature_scale`` (3,), with ``T0`` () degC, the diagnosed recording's
mean temperature).

:func:`apply` inverts the chain step by step, exactly where the step is invertible:

* baseline: ``u = S^{-1} (raw - b)``;
* temperature: ``x3 = (u - ktb dT) / (1 + kts dT)`` with ``T`` the recording's ``temp`` (refused
  without one);
* misalignment: ``x2 = (I + m)^{-1} x3``;
* scale nonlinearity: the root through the origin, ``x1 = 2 x2 / (1 + sqrt(1 + 4 k2 x2))``
  (closed form, float64 round-off; beyond the fold ``x2 < -1/(4 k2)`` the output is the fold
  ``-1/(2 k2)``, e.g. 10 g or 10 rad/s at the plausible limit ``|k2| = 0.05``);
* time offset: ``x_in(t) = x1(t + tau)`` by a cubic spline through the samples of each ``seq``
  sequence (not-a-knot); where ``t + tau`` leaves the sequence, the edge sample is held (the first
  or last ``ceil(|tau| / dt)`` samples);
* g-sensitivity and lever arm, coupled: ``w = x_in_gyr - G f`` with ``f`` the calibrated
  accelerometer, and ``f = x_in_acc - (dw/dt x r + w x (w x r)) / g0`` with ``w`` the calibrated
  gyroscope and ``dw/dt`` its five-point derivative (second-order one-sided at the two end samples); solved by four fixed-point passes (each pass
  shrinks the error by about ``|G| |r| w^2 / g0``, < 1e-4 for plausible sizes).

Not carried: ``bias_drift`` (a drift over the diagnosed recording's own clock does not transfer to
another recording) and ``saturation`` (clipped samples cannot be restored); both are listed in
``meta["not_carried"]``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from jaxcal import flags
from jaxcal.constants import SENSORS
from jaxcal.diagnose import effects as E
from jaxcal.diagnose import vocabulary as V
from jaxcal.diagnose.kinematics import lever_force
from jaxcal.diagnose.vocabulary import InverseContext, invert_nonlinearity, unshift
from jaxcal.flags import Flag
from jaxcal.methods.base import (
    Fitted,
    Log,
    Method,
    ModelError,
    check_linear_state,
    recording_dt,
    recording_spec,
    units,
)
from jaxcal.recording import Recording, sequence_slices

__all__ = [
    "CARRIED",  # noqa: F822 - derived on access (__getattr__)
    "NOT_CARRIED",  # noqa: F822 - derived on access (__getattr__)
    "PARAM_SHAPES",  # noqa: F822 - derived on access (__getattr__)
    "COUPLING_PASSES",
    "DiagnosedOptions",
    "fit",
    "apply",
    "check",
    "diagnosed_model_state",
    "invert_nonlinearity",
    "unshift",
    "without_effect",
    "METHOD",
]

def __getattr__(name: str):
    """The tables of this method, derived from the vocabulary's records
    (:mod:`jaxcal.diagnose.vocabulary`) whenever they are read:

    * ``CARRIED``: the effects a ``diagnosed`` model carries and :func:`apply` inverts;
    * ``NOT_CARRIED``: ``{effect: why it is not carried}``;
    * ``PARAM_SHAPES``: shape of each effect's array in ``state/<sensor>/<effect>`` (``T0``: the
      reference temperature of effects that need ``temp``).
    """
    if name == "CARRIED":
        return _carried()
    if name == "NOT_CARRIED":
        return {e.name: e.not_carried for e in V.REGISTRY.values() if e.not_carried}
    if name == "PARAM_SHAPES":
        return _param_shapes()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _carried() -> tuple[str, ...]:
    return tuple(e.name for e in V.REGISTRY.values() if e.carried)


def _param_shapes() -> dict[str, tuple[int, ...]]:
    return {**{e.name: e.shape for e in V.REGISTRY.values() if e.carried}, "T0": ()}


def _sensor_effects(sensor: str) -> set[str]:
    return {sl.name for sl in E.LAYOUT[sensor]}


COUPLING_PASSES = 4  # fixed-point passes of the g-sensitivity <-> lever-arm coupling


class DiagnosedOptions(NamedTuple):
    """Options of ``diagnosed`` (static: plain Python values).

    Args:
        baseline: the baseline sensor model diagnosed against, ``"diag"`` (thesis eq. 4.6) or
            ``"affine"`` (eq. 2.3), as ``jaxcal diagnose --baseline``.
    """

    baseline: str = "diag"

    FLAGS = {"baseline": Flag("--baseline", flags.choice("diag", "affine"), None, "baseline sensor model diagnosed "
                              "against: diag (thesis eq. 4.6) or affine (eq. 2.3), as `jaxcal diagnose --baseline`",
                              "diag|affine")}


# ----------------------------------------------------------------------------- diagnosis -> state


def diagnosed_model_state(preps: Mapping[str, Any], results: Mapping[str, Any], kind: str,
                          rec: Recording | None = None, baseline_only: bool = False) -> Fitted:
    """The ``diagnosed`` model of a diagnosis (pure): per sensor the final refit's baseline composed
    with the datasheet conversion, and the named effects that :data:`CARRIED` lists at their refit
    values (``SensorResult.final_all``, the values ``report.json`` prints).

    Args:
        preps: ``{sensor: Prepared}`` from :func:`jaxcal.diagnose.diagnose_banded`.
        results: ``{sensor: SensorResult}`` from the same call.
        kind: the baseline diagnosed against, ``"diag"`` or ``"affine"``.
        rec: the diagnosed recording; when given, a gyroscope with g-sensitivity but an accelerometer
            that was not diagnosed (no ``acc_ref``) gets that accelerometer's datasheet conversion,
            so the model can still use it (``meta["notes"]`` says so).
        baseline_only: the baseline fitted without any effect (``SensorResult.base_all``) and no
            effects: the "before" of a comparison.

    Returns:
        :class:`~jaxcal.methods.base.Fitted` with ``state = {sensor: {"S", "b", effects...}}`` (numpy
        float64) and ``meta`` (baseline, effects per sensor, not carried, notes).
    """
    state: dict[str, dict[str, np.ndarray]] = {}
    meta: dict[str, Any] = {"baseline": kind, "effects": {}, "not_carried": [], "notes": [],
                            "inverse": "baseline, temperature, misalignment, scale nonlinearity (closed form), "
                                       "time offset (cubic spline, edges held), g-sensitivity / lever arm (coupled)"}
    for s, r in results.items():
        sd = preps[s].sensors[s]
        fit = r.base_all if baseline_only else r.final_all
        beta = np.asarray(fit.beta, np.float64)
        theta = np.asarray(fit.theta, np.float64)
        sc, bi = np.asarray(sd.spec_scale, np.float64), np.asarray(sd.spec_bias, np.float64)
        s_phys = np.diag(beta[:3]) if kind == "diag" else beta[:9].reshape(3, 3)
        b_phys = beta[3:6] if kind == "diag" else beta[9:12]
        p: dict[str, np.ndarray] = {"S": sc[:, None] * s_phys, "b": sc * b_phys + bi}
        named = [] if baseline_only else list(r.selected)
        if not baseline_only and r.saturation is not None and r.saturation.get("selected"):
            named.append("saturation")
        for n in named:
            e = V.REGISTRY.get(n)
            if e is None or not e.carried:
                meta["not_carried"].append({"sensor": s, "name": n, "why": (e.not_carried if e else "") or "not modelled by apply"})
                continue
            v = E.params_from_theta(s, n, theta)[E.slot(s, n).param]
            p[n] = np.asarray(v, np.float64).reshape(e.shape)
        if any("temp" in V.REGISTRY[n].needs for n in p if n in V.REGISTRY):
            # T0 of the diagnosis: the mean temperature over its valid rows (dT = temp - T0)
            prep = preps[s]
            p["T0"] = np.asarray(float(np.mean(np.asarray(prep.temp, np.float64) - np.asarray(sd.inp.dT, np.float64))))
            T = np.asarray(prep.temp, np.float64)[np.asarray(sd.valid, bool)]
            if T.size:  # `jaxcal apply` refuses a recording far outside it (jaxcal.plausible)
                meta.setdefault("temperature_range_degC", {})[s] = [float(T.min()), float(T.max())]
        state[s] = p
        meta["effects"][s] = [n for n in _carried() if n in p]
    if "gyr" in state and "g_sensitivity" in state["gyr"] and "acc" not in state and rec is not None and rec.acc is not None:
        spec = recording_spec(rec, "acc")
        if spec is not None:
            sc = np.broadcast_to(np.asarray(spec.s, np.float64), (3,))
            state["acc"] = {"S": np.diag(sc), "b": np.broadcast_to(np.asarray(spec.b, np.float64), (3,)).copy()}
            meta["effects"]["acc"] = []
            meta["notes"].append("acc was not diagnosed (no acc_ref); its datasheet conversion calibrates it for the gyro's g-sensitivity")
    sensors = tuple(s for s in SENSORS if s in state)
    if rec is not None:
        meta["units"] = units(rec, sensors)
    return Fitted(sensors, {s: state[s] for s in sensors}, meta)


def fit(rec: Recording, options: DiagnosedOptions, log: Log) -> Fitted:
    """Diagnose ``rec`` (:func:`jaxcal.diagnose.diagnose_banded`) and keep its baseline and named effects.

    Args:
        rec: a recording with reference motion (``acc_ref``/``gyr_ref`` or ``pos_ref`` + ``quat_ref``).
        options: :class:`DiagnosedOptions`.
        log: progress sink.
    """
    from jaxcal.diagnose import diagnose_banded  # imported on use: it adds about a second to every command

    if options.baseline not in ("diag", "affine"):
        raise ModelError(f"method 'diagnosed': unknown baseline {options.baseline!r} (expected diag or affine)")
    log(f"diagnosing {rec.n} samples against the {options.baseline} baseline ...")
    try:
        preps, results = diagnose_banded(rec, options.baseline)
    except (ValueError, TypeError) as e:
        raise ModelError(f"method 'diagnosed': {e}") from None
    fitted = diagnosed_model_state(preps, results, options.baseline, rec)
    log("named and carried: " + "; ".join(f"{s}: {', '.join(v) or 'none'}" for s, v in fitted.meta["effects"].items()))
    return fitted


# ----------------------------------------------------------------------------- inverse


def _derivative(w: np.ndarray, dt: float, slices: list[slice]) -> np.ndarray:
    """Per sequence: the five-point central difference inside (as ``diagnose`` differentiates its
    reference rate), second-order one-sided differences at the two samples at each end."""
    d = np.zeros_like(w)
    for sl in slices:
        x = w[sl]
        n = len(x)
        if n < 2:
            continue
        d[sl] = np.gradient(x, dt, axis=0, edge_order=2 if n >= 3 else 1)
        if n >= 5:
            d[sl][2:-2] = (x[:-4] - 8 * x[1:-3] + 8 * x[3:-1] - x[4:]) / (12 * dt)
    return d


def _need(rec: Recording, field: str, why: str, plural: bool = False) -> np.ndarray:
    v = getattr(rec, field)
    if v is None:
        raise ModelError(f"{why} need{'' if plural else 's'} the recording's '{field}' channel, which this recording lacks")
    return np.asarray(v, np.float64)


def _sensor_xin(s: str, p: Mapping[str, Any], rec: Recording, t: np.ndarray, slices: list[slice]) -> np.ndarray:
    """``x_in`` of one sensor: every step of the inverse but the coupled (cross-sensor) ones, each
    carried effect's ``inverse`` in the reverse order of the forward chain."""
    y = np.asarray(getattr(rec, s), np.float64)
    S, b = np.asarray(p["S"], np.float64), np.asarray(p["b"], np.float64)
    x = np.linalg.solve(S, (y - b).T).T
    steps = [e for e in reversed(V.smooth(s)) if e.inverse is not None and e.name in p]
    dT = None
    temp = [e.name for e in steps if "temp" in e.needs]
    if temp:
        names = " and ".join(temp)
        dT = (_need(rec, "temp", f"the model's {s} {names}", len(temp) > 1) - float(p["T0"]))[:, None]
    ctx = InverseContext(t, slices, dT)
    for e in steps:
        x = e.inverse(p[e.name], x, ctx)
    return x


def apply(state: Mapping[str, Any], meta: Mapping[str, Any], rec: Recording) -> dict[str, np.ndarray]:
    """:data:`~jaxcal.methods.base.ApplyFn` of ``diagnosed``: invert baseline and carried effects
    (module docstring), in float64.

    Args:
        state: ``sensor -> {"S", "b", effects...}`` (only the sensors the recording has).
        meta: the model's metadata (unused).
        rec: the recording to calibrate; ``temp`` is needed for temperature terms, ``acc`` for the
            gyroscope's g-sensitivity and ``gyr`` for the accelerometer's lever arm.

    Raises:
        ModelError: the recording lacks a channel the model needs (one line naming it).
    """
    t = np.asarray(rec.t, np.float64)
    slices = sequence_slices(rec)
    sens = [s for s in SENSORS if s in state and getattr(rec, s) is not None]
    G = state["gyr"].get("g_sensitivity") if "gyr" in sens else None
    r = state["acc"].get("lever_arm") if "acc" in sens else None
    if G is not None and "acc" not in sens:
        _need(rec, "acc", "the model's gyr g_sensitivity")
        raise ModelError("the model's gyr g_sensitivity needs a calibrated 'acc', which this model does not carry")
    if r is not None and "gyr" not in sens:
        _need(rec, "gyr", "the model's acc lever_arm")
        raise ModelError("the model's acc lever_arm needs a calibrated 'gyr', which this model does not carry")
    xin = {s: _sensor_xin(s, state[s], rec, t, slices) for s in sens}
    out = {f"{s}_cal": xin[s] for s in sens}
    if G is None and r is None:
        return out
    G = None if G is None else np.asarray(G, np.float64).reshape(3, 3)
    r = None if r is None else np.asarray(r, np.float64).reshape(3)
    dt = recording_dt(rec)
    acc, gyr = xin.get("acc"), xin.get("gyr")
    for _ in range(COUPLING_PASSES if (G is not None and r is not None) else 1):
        if G is not None:
            gyr = xin["gyr"] - acc @ G.T
        if r is not None:
            acc = xin["acc"] - lever_force(gyr, _derivative(gyr, dt, slices), r)
    if acc is not None:
        out["acc_cal"] = acc
    if gyr is not None:
        out["gyr_cal"] = gyr
    return out


def check(state: Mapping[str, Any], meta: Mapping[str, Any], sensors: tuple[str, ...]) -> None:
    """:data:`~jaxcal.methods.base.CheckFn`: an invertible affine ``S, b`` per sensor and effect
    arrays of the right shapes (``T0`` with temperature terms).

    Args:
        state: the loaded state.
        meta: the model's metadata (unused).
        sensors: the model's sensors.
    """
    check_linear_state(state, meta, sensors)
    shapes = _param_shapes()
    for s in sensors:
        p = state[s]
        for k, v in p.items():
            if k in ("S", "b"):
                continue
            if k not in shapes or (k != "T0" and k not in _sensor_effects(s)):
                raise ModelError(f"state/{s}/{k}: not an effect a 'diagnosed' model of '{s}' carries "
                                 f"(known: {', '.join(n for n in _carried() if n in _sensor_effects(s))})")
            if np.shape(v) != shapes[k]:
                raise ModelError(f"state/{s}/{k} has shape {np.shape(v)}, expected {shapes[k]}")
        if any("temp" in V.REGISTRY[k].needs for k in p if k in V.REGISTRY) and "T0" not in p:
            raise ModelError(f"state/{s}: temperature terms without their reference temperature T0")


def without_effect(model: Any, sensor: str, name: str) -> Any:
    """A ``diagnosed`` model with one carried effect dropped (baseline and the other effects at their
    joint refit values, not refitted; ``T0`` dropped with the last temperature term).

    Args:
        model: the diagnosed :class:`~jaxcal.methods.CalibrationModel`.
        sensor: the effect's sensor.
        name: the effect.
    """
    st = {s: dict(p) for s, p in model.state.items()}
    st[sensor].pop(name)
    if "T0" in st[sensor] and not any(k.startswith("temperature") for k in st[sensor]):
        st[sensor].pop("T0")
    return type(model)("diagnosed", model.sensors, st, model.meta)


METHOD = Method(
    "diagnosed", fit, apply, DiagnosedOptions,
    "baseline + the effects `jaxcal diagnose` names (time offset, g-sensitivity, temperature, ...); needs reference motion",
    check,
)
