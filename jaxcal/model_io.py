"""Calibration model files and the method registry behind ``jaxcal calibrate`` / ``jaxcal apply``.

A *method* is a pair of functions registered under a name with :func:`register_method`:

* ``fit_fn(recording, options) -> Fitted``: estimate a calibration from a
  :class:`~jaxcal.recording.Recording`. ``Fitted.state`` is any pytree of arrays (dicts,
  NamedTuples such as :class:`~jaxcal.sensor.Affine`, flax params); ``Fitted.meta`` is a JSON-able
  dict (hyperparameters, units, fit statistics).
* ``apply_fn(state, meta, recording) -> {"acc_cal": (N, 3) g, "gyr_cal": (N, 3) rad/s}``:
  calibrate the sensors of a recording. ``state`` comes back as nested dicts of numpy arrays
  (the ``flax.serialization.to_state_dict`` form of the fitted pytree), so ``apply_fn`` rebuilds
  NamedTuples with e.g. ``Affine(**state["acc"])``. Only the sensors present are returned.

Built in: ``linear`` (thesis eq. 3.1-3.5, :func:`jaxcal.linear.fit_affine`, applied with
:func:`jaxcal.sensor.affine_inverse`) and ``nn`` (thesis section 3.3, :func:`jaxcal.nn.fit_nn`,
applied with :func:`jaxcal.nn.nn_calibrate`); both need reference labels (``acc_ref`` and/or
``gyr_ref``). ``online-thesis``, ``online`` and ``multipos`` are registered lazily from
:mod:`jaxcal.online_thesis`, :mod:`jaxcal.online` and :mod:`jaxcal.multipos`; if those modules
(or their entry points) are absent, :func:`get_method` raises
``ModelError("method 'online' is not available in this build")``.

Model file (``.npz``, ``allow_pickle=False``): ``jaxcal_model_format`` (int), ``method`` (str),
``sensors`` (str array), ``meta_json`` (JSON str), ``jaxcal_version`` (str), and the state
flattened with :func:`flax.traverse_util.flatten_dict` under keys ``state/<path>``.
"""

from __future__ import annotations

import importlib
import json
import math
import os
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization, traverse_util

from jaxcal import __version__
from jaxcal.normalise import Bounds, bounds_from_spec
from jaxcal.recording import Recording, sequence_slices
from jaxcal.sensor import Affine, Diag, affine_inverse, diag_inverse, spec_diag

__all__ = [
    "CalibrationModel",
    "FitOptions",
    "Fitted",
    "MethodSpec",
    "ModelError",
    "apply_model",
    "available_methods",
    "fit_model",
    "get_method",
    "load_model",
    "method_names",
    "recording_dt",
    "recording_spec",
    "register_method",
    "save_model",
]

MODEL_FORMAT = 1
SENSORS = ("acc", "gyr")
REF_KEY = {"acc": "acc_ref", "gyr": "gyr_ref"}
PHYS_UNIT = {"acc": "g", "gyr": "rad/s"}
# Full-scale ranges used for eq. 3.6 bounds when the recording gives datasheet values.
DEFAULT_ACC_RANGE_G = 2.0
DEFAULT_GYR_RANGE_RADS = 250.0 * math.pi / 180.0


class ModelError(ValueError):
    """Bad model file, unknown/unavailable method, or data unsuitable for a method (one line)."""


@dataclass(frozen=True)
class FitOptions:
    """Options of a fit; methods read the ones they use and ignore the rest.

    Attributes:
        seed: PRNG seed (NN initial weights and any other randomness).
        sensors: sensors to calibrate (subset of ``("acc", "gyr")``); ``None``: all the method can.
        widths: NN hidden widths (thesis offline network: one layer of 7500).
        slope: leaky-ReLU slope (thesis: 0.1).
        learning_rate: Adam step size for the NN. The defaults (1e-2, patience 1000, at most 10000
            full-batch epochs) were picked on the Dataset 1 surrogate, where 1e-3 with patience 200
            stopped long before the network beat the linear model.
        patience: early-stopping patience (epochs without validation improvement).
        max_epochs: cap on NN full-batch epochs.
        val_fraction: share of labelled samples held out (deterministically) for early stopping.
        acc_range, gyr_range: full-scale range (g, rad/s) for the eq. 3.6 normalisation bounds.
        log: progress sink (e.g. a function printing to stderr); ``None`` for silence.
        extra: method-specific options (``name -> value``).
    """

    seed: int = 0
    sensors: tuple[str, ...] | None = None
    widths: tuple[int, ...] = (7500,)
    slope: float = 0.1
    learning_rate: float = 1e-2
    patience: int = 1000
    max_epochs: int = 10000
    val_fraction: float = 0.15
    acc_range: float = DEFAULT_ACC_RANGE_G
    gyr_range: float = DEFAULT_GYR_RANGE_RADS
    log: Callable[[str], None] | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def say(self, msg: str) -> None:
        """Send one progress line to :attr:`log` (if set)."""
        if self.log is not None:
            self.log(msg)


class Fitted(NamedTuple):
    """What a method's ``fit_fn`` returns: calibrated sensors, parameter pytree, JSON metadata."""

    sensors: tuple[str, ...]
    state: Any
    meta: dict[str, Any]


FitFn = Callable[[Recording, FitOptions], Fitted]
ApplyFn = Callable[[Mapping[str, Any], Mapping[str, Any], Recording], dict[str, np.ndarray]]


class MethodSpec(NamedTuple):
    """A registered calibration method."""

    name: str
    fit: FitFn
    apply: ApplyFn
    needs_labels: bool
    description: str


_REGISTRY: dict[str, MethodSpec] = {}
# Lazily imported methods: name -> loader returning a MethodSpec, or None if unavailable.
_LAZY: dict[str, Callable[[], MethodSpec | None]] = {}


def register_method(
    name: str, fit_fn: FitFn, apply_fn: ApplyFn, *, needs_labels: bool = False, description: str = ""
) -> None:
    """Register (or replace) a calibration method under ``name`` (see the module docstring)."""
    _REGISTRY[name] = MethodSpec(name, fit_fn, apply_fn, needs_labels, description)


def method_names() -> tuple[str, ...]:
    """All method names the CLI knows, available in this build or not."""
    return tuple(dict.fromkeys(list(_REGISTRY) + list(_LAZY)))


def get_method(name: str) -> MethodSpec:
    """The method registered as ``name``, importing lazily registered ones on first use.

    Raises:
        ModelError: unknown name, or a lazily registered method whose module is missing.
    """
    if name in _REGISTRY:
        return _REGISTRY[name]
    if name in _LAZY:
        spec = _LAZY[name]()
        if spec is None:
            raise ModelError(f"method '{name}' is not available in this build")
        _REGISTRY[name] = spec
        return spec
    raise ModelError(f"unknown method '{name}' (known: {', '.join(method_names())})")


def available_methods() -> dict[str, bool]:
    """``name -> whether it can be used in this build``."""
    out = {}
    for n in method_names():
        try:
            get_method(n)
            out[n] = True
        except ModelError:
            out[n] = False
    return out


# ----------------------------------------------------------------------------- recording helpers


def recording_spec(rec: Recording, sensor: str) -> Diag | None:
    """Datasheet model of ``sensor`` from the recording metadata (eq. 4.8), or ``None``.

    A sensor already in physical units (``acc_unit == "g"`` / ``gyr_unit == "rad/s"``) has the
    identity spec (scale 1, bias 0). Otherwise the scale key (``acc_lsb_per_g`` /
    ``gyr_lsb_per_rads``) is needed; the bias key defaults to 0.
    """
    if getattr(rec, f"{sensor}_unit") == PHYS_UNIT[sensor]:
        return spec_diag(1.0, 0.0)
    scale = rec.acc_lsb_per_g if sensor == "acc" else rec.gyr_lsb_per_rads
    bias = rec.acc_bias_lsb if sensor == "acc" else rec.gyr_bias_lsb
    if scale is None:
        return None
    return spec_diag(np.asarray(scale, np.float32), np.asarray(0.0 if bias is None else bias, np.float32))


def recording_dt(rec: Recording) -> float:
    """Sample period (s): ``1 / fs`` if given, else the median spacing of ``t`` within sequences."""
    if rec.fs is not None:
        return 1.0 / rec.fs
    diffs = [np.diff(np.asarray(rec.t, np.float64)[s]) for s in sequence_slices(rec)]
    diffs = [d for d in diffs if d.size]
    if not diffs:
        raise ModelError("cannot tell the sample period: one sample per sequence and no 'fs'")
    return float(np.median(np.concatenate(diffs)))


def _labelled_sensors(rec: Recording, options: FitOptions, method: str) -> tuple[str, ...]:
    wanted = options.sensors or SENSORS
    have = tuple(s for s in wanted if getattr(rec, s) is not None and getattr(rec, REF_KEY[s]) is not None)
    if not have:
        need = " or ".join(f"'{s}' with '{REF_KEY[s]}'" for s in wanted)
        raise ModelError(f"method '{method}' needs reference labels: recording has no {need}")
    return have


def _units(rec: Recording, sensors: tuple[str, ...]) -> dict[str, str]:
    return {s: getattr(rec, f"{s}_unit") for s in sensors}


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(np.asarray(e, np.float64) ** 2, axis=-1))))


def holdout_mask(rec: Recording, fraction: float) -> np.ndarray:
    """Deterministic validation mask holding out about ``fraction`` of the samples.

    With several sequences (``seq``), whole sequences are held out (every k-th, evenly spread),
    so correlated neighbours do not leak between the two sets; otherwise every k-th sample.
    Always keeps at least one training and one validation sample (for ``N >= 2``).
    """
    n = rec.n
    mask = np.zeros(n, dtype=bool)
    if fraction <= 0 or n < 2:
        return mask
    slices = sequence_slices(rec)
    if len(slices) >= 4:
        k = len(slices)
        pick = np.unique(np.floor(np.arange(max(1, round(fraction * k))) / fraction).astype(int))
        for j in pick[pick < k]:
            mask[slices[j]] = True
    else:
        pick = np.unique(np.floor(np.arange(max(1, round(fraction * n))) / fraction).astype(int))
        mask[pick[pick < n]] = True
    if mask.all():
        mask[-1] = False
    return mask


# ----------------------------------------------------------------------------- linear


def _fit_linear(rec: Recording, options: FitOptions) -> Fitted:
    from jaxcal.linear import fit_affine

    sensors = _labelled_sensors(rec, options, "linear")
    state: dict[str, Affine] = {}
    meta: dict[str, Any] = {"units": _units(rec, sensors), "n_samples": rec.n, "train_rms": {}}
    for s in sensors:
        y = np.asarray(getattr(rec, s), np.float64)
        x = np.asarray(getattr(rec, REF_KEY[s]), np.float64)
        options.say(f"fitting linear ({s}) on {rec.n} samples ...")
        t0 = time.perf_counter()
        with jax.enable_x64(True):  # LSB ~ 1e4 with 1e-5 relative floors: fit in float64
            model = fit_affine(jnp.asarray(x), jnp.asarray(y))
            model = Affine(np.asarray(model.S), np.asarray(model.b))
            x_hat = np.asarray(affine_inverse(Affine(jnp.asarray(model.S), jnp.asarray(model.b)), jnp.asarray(y)))
        if not (np.all(np.isfinite(model.S)) and np.all(np.isfinite(model.b))):
            raise ModelError(f"linear fit of '{s}' failed (singular: labels must span 3 directions)")
        state[s] = model
        meta["train_rms"][s] = _rms(x_hat - x)
        options.say(f"fitting linear ({s}) ... done in {time.perf_counter() - t0:.1f} s, "
                    f"train rms {meta['train_rms'][s]:.3g} {PHYS_UNIT[s]}")
    return Fitted(sensors, state, meta)


def _apply_linear(state: Mapping[str, Any], meta: Mapping[str, Any], rec: Recording) -> dict[str, np.ndarray]:
    out = {}
    with jax.enable_x64(True):
        for s, p in state.items():
            y = getattr(rec, s)
            if y is not None:
                model = Affine(jnp.asarray(p["S"], jnp.float64), jnp.asarray(p["b"], jnp.float64))
                out[f"{s}_cal"] = np.asarray(affine_inverse(model, jnp.asarray(y, jnp.float64)))
    return out


register_method(
    "linear",
    _fit_linear,
    _apply_linear,
    needs_labels=True,
    description="12-parameter affine model per sensor (thesis eq. 3.1-3.5); needs acc_ref/gyr_ref",
)


# ----------------------------------------------------------------------------- nn


def _nn_bounds(rec: Recording, sensor: str, y: np.ndarray, options: FitOptions) -> tuple[Bounds, str]:
    spec = recording_spec(rec, sensor)
    if spec is not None:
        rng = options.acc_range if sensor == "acc" else options.gyr_range
        return bounds_from_spec(spec, rng), f"spec, range {rng:g} {PHYS_UNIT[sensor]}"
    lo, hi = y.min(axis=0), y.max(axis=0)
    pad = 0.1 * np.maximum(hi - lo, 1.0)
    return Bounds(jnp.asarray(lo - pad, jnp.float32), jnp.asarray(hi + pad, jnp.float32)), "data range +- 10 %"


def _fit_nn(rec: Recording, options: FitOptions) -> Fitted:
    from jaxcal.nn import MLP, fit_nn
    from jaxcal.train import TrainConfig

    sensors = _labelled_sensors(rec, options, "nn")
    val = holdout_mask(rec, options.val_fraction)
    if not val.any():
        raise ModelError("method 'nn' needs at least 2 labelled samples (training + validation)")
    widths = tuple(int(w) for w in options.widths)
    mlp = MLP(widths=widths, out_dim=3, slope=float(options.slope))
    config = TrainConfig(learning_rate=options.learning_rate, patience=options.patience, min_delta=0.0)
    max_epochs = int(options.max_epochs)

    @jax.jit
    def fit(key, bounds, y_tr, x_tr, y_va, x_va):
        w_tr = jnp.ones(y_tr.shape[0], jnp.float32)
        return fit_nn(key, mlp, bounds, (y_tr, x_tr, w_tr), (y_va, x_va), config, max_epochs)

    state: dict[str, Any] = {}
    meta: dict[str, Any] = {
        "units": _units(rec, sensors),
        "widths": list(widths),
        "slope": float(options.slope),
        "learning_rate": float(options.learning_rate),
        "patience": int(options.patience),
        "max_epochs": max_epochs,
        "val_fraction": float(options.val_fraction),
        "seed": int(options.seed),
        "n_train": int((~val).sum()),
        "n_val": int(val.sum()),
        "bounds_from": {},
        "epochs": {},
        "best_epoch": {},
        "val_rms": {},
        "fit_seconds": {},
    }
    keys = jax.random.split(jax.random.PRNGKey(options.seed), len(SENSORS))
    for s in sensors:
        y = np.asarray(getattr(rec, s), np.float64)
        x = np.asarray(getattr(rec, REF_KEY[s]), np.float64)
        bounds, how = _nn_bounds(rec, s, y, options)
        options.say(
            f"fitting nn ({s}) on {int((~val).sum())} samples ({int(val.sum())} held out for early stopping), "
            f"widths {widths}, up to {max_epochs} epochs ..."
        )
        t0 = time.perf_counter()
        cal, res = fit(
            keys[SENSORS.index(s)],
            bounds,
            jnp.asarray(y[~val], jnp.float32),
            jnp.asarray(x[~val], jnp.float32),
            jnp.asarray(y[val], jnp.float32),
            jnp.asarray(x[val], jnp.float32),
        )
        jax.block_until_ready(cal)
        dt = time.perf_counter() - t0
        best_val = float(res.best_val)
        if not math.isfinite(best_val):
            raise ModelError(f"nn fit of '{s}' diverged (non-finite validation loss); try a smaller --lr")
        state[s] = cal
        meta["bounds_from"][s] = how
        meta["epochs"][s] = int(res.epochs)
        meta["best_epoch"][s] = int(res.best_epoch)
        meta["val_rms"][s] = math.sqrt(3.0 * best_val)  # weighted_mse averages over the 3 axes
        meta["fit_seconds"][s] = dt
        options.say(
            f"fitting nn ({s}) ... done in {dt:.1f} s: {int(res.epochs)} epochs, best at {int(res.best_epoch)}, "
            f"validation rms {meta['val_rms'][s]:.3g} {PHYS_UNIT[s]}"
        )
    return Fitted(sensors, state, meta)


def _apply_nn(state: Mapping[str, Any], meta: Mapping[str, Any], rec: Recording) -> dict[str, np.ndarray]:
    from jaxcal.nn import MLP, NNCalibration, nn_calibrate

    mlp = MLP(widths=tuple(int(w) for w in meta["widths"]), out_dim=3, slope=float(meta["slope"]))
    out = {}
    for s, p in state.items():
        y = getattr(rec, s)
        if y is None:
            continue
        params = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), dict(p["params"]))
        cal = NNCalibration(params, Bounds(jnp.asarray(p["bounds"]["lo"]), jnp.asarray(p["bounds"]["hi"])))
        out[f"{s}_cal"] = np.asarray(jax.jit(lambda c, v: nn_calibrate(mlp, c, v))(cal, jnp.asarray(y, jnp.float32)))
    return out


register_method(
    "nn",
    _fit_nn,
    _apply_nn,
    needs_labels=True,
    description="MLP sensor model per sensor (thesis section 3.3); needs acc_ref/gyr_ref",
)


# ----------------------------------------------------------------------------- lazily wired methods


def _apply_affine_state(state: Mapping[str, Any], meta: Mapping[str, Any], rec: Recording) -> dict[str, np.ndarray]:
    """Apply per-sensor ``Affine`` (``S``, ``b``) or ``Diag`` (``s``, ``b``) states."""
    out = {}
    with jax.enable_x64(True):
        for s, p in state.items():
            y = getattr(rec, s)
            if y is None:
                continue
            yj = jnp.asarray(y, jnp.float64)
            if "S" in p:
                x = affine_inverse(Affine(jnp.asarray(p["S"], jnp.float64), jnp.asarray(p["b"], jnp.float64)), yj)
            elif "s" in p:
                x = diag_inverse(Diag(jnp.asarray(p["s"], jnp.float64), jnp.asarray(p["b"], jnp.float64)), yj)
            else:
                raise ModelError(f"model state for '{s}' is neither affine (S, b) nor diagonal (s, b)")
            out[f"{s}_cal"] = np.asarray(x)
    return out


def _lazy(module: str, attr: str, build: Callable[[Any], MethodSpec]) -> Callable[[], MethodSpec | None]:
    def load() -> MethodSpec | None:
        try:
            mod = importlib.import_module(module)
        except ImportError:
            return None
        if not hasattr(mod, attr):
            return None
        return build(mod)

    return load


def _require_both(rec: Recording, method: str) -> None:
    missing = [s for s in SENSORS if getattr(rec, s) is None]
    if missing:
        raise ModelError(f"method '{method}' needs both 'acc' and 'gyr' (recording lacks '{missing[0]}')")


def _require_spec(rec: Recording, sensor: str, method: str) -> Diag:
    spec = recording_spec(rec, sensor)
    if spec is None:
        key = "acc_lsb_per_g" if sensor == "acc" else "gyr_lsb_per_rads"
        raise ModelError(f"method '{method}' needs the datasheet scale '{key}' in the recording metadata")
    return spec


def _sequences_of(rec: Recording, method: str) -> np.ndarray:
    if rec.seq is None:
        raise ModelError(f"method '{method}' needs 'seq' ids (the recording must be split into rotation sequences)")
    return np.asarray(rec.seq)


def _diag_state(d: Diag) -> dict[str, np.ndarray]:
    return {"s": np.asarray(d.s, np.float64), "b": np.asarray(d.b, np.float64)}


def _build_online_thesis(mod: Any) -> MethodSpec:
    def fit(rec: Recording, options: FitOptions) -> Fitted:
        _require_both(rec, "online-thesis")
        seq = _sequences_of(rec, "online-thesis")
        acc_spec = _require_spec(rec, "acc", "online-thesis")
        gyr_spec = _require_spec(rec, "gyr", "online-thesis")
        dt = recording_dt(rec)
        n_seq = len(sequence_slices(rec))
        options.say(f"fitting online-thesis on {n_seq} sequences ({rec.n} samples, dt {dt:g} s) ...")
        t0 = time.perf_counter()
        try:
            res = mod.fit_online_thesis_recording(
                np.asarray(rec.acc, np.float32), np.asarray(rec.gyr, np.float32), seq, dt,
                acc_spec, gyr_spec, jax.random.PRNGKey(options.seed), None,
            )
            jax.block_until_ready(res.acc_params)
        except ValueError as e:  # e.g. sequences of unequal length
            raise ModelError(f"online-thesis: {e}") from None
        elapsed = time.perf_counter() - t0
        options.say(f"fitting online-thesis ... done in {elapsed:.1f} s")
        state = {
            "acc": {"params": res.acc_params, "spec": _diag_state(acc_spec)},
            "gyr": {"params": res.gyr_params, "spec": _diag_state(gyr_spec)},
        }
        meta = {
            "units": _units(rec, SENSORS),
            "seed": int(options.seed),
            "n_sequences": n_seq,
            "dt": dt,
            "fit_seconds": elapsed,
            "acc_range": float(getattr(mod, "ACC_RANGE_G", DEFAULT_ACC_RANGE_G)),
            "gyr_range": float(getattr(mod, "GYR_RANGE_RADS", DEFAULT_GYR_RANGE_RADS)),
        }
        return Fitted(SENSORS, state, meta)

    def apply(state: Mapping[str, Any], meta: Mapping[str, Any], rec: Recording) -> dict[str, np.ndarray]:
        out = {}
        for s, fn, rng in (("acc", mod.calibrate_acc, meta["acc_range"]), ("gyr", mod.calibrate_gyr, meta["gyr_range"])):
            y = getattr(rec, s)
            if y is None or s not in state:
                continue
            params = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), dict(state[s]["params"]))
            spec = Diag(jnp.asarray(state[s]["spec"]["s"], jnp.float32), jnp.asarray(state[s]["spec"]["b"], jnp.float32))
            out[f"{s}_cal"] = np.asarray(fn(params, jnp.asarray(y, jnp.float32), spec, rng))
        return out

    return MethodSpec(
        "online-thesis", fit, apply, False,
        "thesis chapter 4 as published: two 3-5-10-5-3 NNs self-calibrated on rotation sequences; "
        "needs seq ids and datasheet values",
    )


def _build_online(mod: Any) -> MethodSpec:
    def fit(rec: Recording, options: FitOptions) -> Fitted:
        _require_both(rec, "online")
        seq = _sequences_of(rec, "online")
        n_seq = len(sequence_slices(rec))
        dt = recording_dt(rec)
        acc_spec, gyr_spec = recording_spec(rec, "acc"), recording_spec(rec, "gyr")
        options.say(f"fitting online on {n_seq} sequences ({rec.n} samples, dt {dt:g} s) ...")
        t0 = time.perf_counter()
        try:
            acc_model, gyr_model = mod.fit_online_recording(
                np.asarray(rec.acc, np.float64), np.asarray(rec.gyr, np.float64), seq, dt, acc_spec, gyr_spec
            )
        except ValueError as e:
            raise ModelError(f"online: {e}") from None
        elapsed = time.perf_counter() - t0
        for name, m in (("acc", acc_model), ("gyr", gyr_model)):
            if not (np.all(np.isfinite(np.asarray(m.S))) and np.all(np.isfinite(np.asarray(m.b)))):
                raise ModelError(f"online: the {name} estimate is not finite (does the recording hold rotation sequences?)")
        options.say(f"fitting online ... done in {elapsed:.1f} s")
        meta = {
            "units": _units(rec, SENSORS),
            "n_sequences": n_seq,
            "dt": dt,
            "fit_seconds": elapsed,
            "spec_from": {s: ("metadata" if sp is not None else "data") for s, sp in (("acc", acc_spec), ("gyr", gyr_spec))},
        }
        return Fitted(SENSORS, {"acc": acc_model, "gyr": gyr_model}, meta)

    return MethodSpec(
        "online", fit, _apply_affine_state, False,
        "jaxcal's streaming self-calibration (affine per sensor, information filter on rotation "
        "sequences); needs seq ids, no labels",
    )


def _build_multipos(mod: Any) -> MethodSpec:
    def fit(rec: Recording, options: FitOptions) -> Fitted:
        options.say(f"fitting multipos on {rec.n} samples ...")
        t0 = time.perf_counter()
        try:
            acc_model, gyr_model, q = mod.fit_multipos_recording(
                rec, turn_times=options.extra.get("turns"), partial=options.extra.get("partial", False), summary=True)
        except ValueError as e:
            raise ModelError(f"multipos: {e}") from None
        elapsed = time.perf_counter() - t0
        state = {s: m for s, m in (("acc", acc_model), ("gyr", gyr_model)) if m is not None}
        if not state:
            raise ModelError("multipos: no sensor could be calibrated")
        options.say(f"fitting multipos ... done in {elapsed:.1f} s")
        gm = "-" if q["gyr_median_deg"] is None else f"{q['gyr_median_deg']:.3f} deg"
        turns = f", worst turn {q['turn_max_deg']:.3f} deg" if "turn_max_deg" in q else ""
        options.say(f"multipos: {q['n_poses']} poses, {q['n_transitions']} usable transitions; in-sample |f| - 1 g RMS "
                    f"{q['acc_rms_mg']:.3f} mg, carried-gravity median {gm}{turns}; least determined combination "
                    f"(relative singular value): acc {q['acc_sv_min']:.2f}, gyro {q['gyr_sv_min']:.2f}")
        for s, what in q.get("partial", {}).items():
            options.say(f"multipos --partial: {s}: {what}")
        sensors = tuple(s for s in SENSORS if s in state)
        return Fitted(sensors, state, {"units": _units(rec, sensors), "fit_seconds": elapsed, "fit_quality": q})

    return MethodSpec(
        "multipos", fit, _apply_affine_state, False,
        "static poses joined by rotations (Tedaldi et al. 2014); no labels, no datasheet values",
    )


_LAZY["online-thesis"] = _lazy("jaxcal.online_thesis", "fit_online_thesis_recording", _build_online_thesis)
_LAZY["online"] = _lazy("jaxcal.online", "fit_online_recording", _build_online)
_LAZY["multipos"] = _lazy("jaxcal.multipos", "fit_multipos_recording", _build_multipos)


# ----------------------------------------------------------------------------- model object and files


@dataclass(frozen=True, eq=False)
class CalibrationModel:
    """A fitted calibration: method name, calibrated sensors, state (nested dicts of numpy
    arrays) and JSON metadata. :meth:`apply` maps a recording to calibrated physical units."""

    method: str
    sensors: tuple[str, ...]
    state: Mapping[str, Any]
    meta: Mapping[str, Any]

    def apply(self, rec: Recording) -> dict[str, np.ndarray]:
        """Calibrate ``rec``: ``{"acc_cal": (N, 3) g, "gyr_cal": (N, 3) rad/s}`` for the sensors
        that both the model and the recording have.

        Raises:
            ModelError: the recording has none of the model's sensors, a sensor's unit differs
                from the one the model was fitted on, or the method is unavailable.
        """
        return apply_model(self, rec)


def _to_state(state: Any) -> dict[str, Any]:
    sd = serialization.to_state_dict(state)
    return jax.tree.map(lambda a: np.asarray(a), sd)


def fit_model(method: str, rec: Recording, options: FitOptions = FitOptions()) -> CalibrationModel:
    """Fit ``method`` on ``rec`` and return a :class:`CalibrationModel` (state as numpy dicts)."""
    spec = get_method(method)
    if options.sensors is not None:
        absent = [s for s in options.sensors if getattr(rec, s) is None]
        if absent:
            raise ModelError(f"recording has no '{absent[0]}' to calibrate")
    fitted = spec.fit(rec, options)
    meta = dict(fitted.meta)
    meta.setdefault("units", _units(rec, tuple(fitted.sensors)))
    return CalibrationModel(method, tuple(fitted.sensors), _to_state(fitted.state), meta)


def apply_model(model: CalibrationModel, rec: Recording) -> dict[str, np.ndarray]:
    """Function form of :meth:`CalibrationModel.apply`."""
    present = [s for s in model.sensors if getattr(rec, s) is not None]
    if not present:
        raise ModelError(
            f"recording has no {' or '.join(repr(s) for s in model.sensors)}, "
            f"which the '{model.method}' model calibrates"
        )
    units = model.meta.get("units", {})
    for s in present:
        want, got = units.get(s), getattr(rec, f"{s}_unit")
        if want is not None and want != got:
            raise ModelError(f"recording's '{s}' is in {got}, the model was fitted on {want}")
    spec = get_method(model.method)
    state = {s: model.state[s] for s in present if s in model.state}
    other = {k: v for k, v in model.state.items() if k not in SENSORS}
    try:
        out = spec.apply({**other, **state}, model.meta, rec)
    except (KeyError, TypeError, IndexError) as e:  # a state/meta entry missing or of the wrong kind
        raise ModelError(f"'{model.method}' model is malformed ({type(e).__name__}: {e})") from None
    return {k: np.asarray(v, np.float64) for k, v in out.items() if k in ("acc_cal", "gyr_cal")}


def save_model(model: CalibrationModel, path: str | os.PathLike) -> None:
    """Write ``model`` as a ``.npz`` model file (see the module docstring)."""
    p = Path(path)
    flat = traverse_util.flatten_dict(dict(model.state), sep="/")
    arrays = {f"state/{k}": np.asarray(v) for k, v in flat.items()}
    arrays.update(
        jaxcal_model_format=np.asarray(MODEL_FORMAT),
        method=np.asarray(model.method),
        sensors=np.asarray(list(model.sensors), dtype=str),
        meta_json=np.asarray(json.dumps(model.meta, sort_keys=True)),
        jaxcal_version=np.asarray(__version__),
    )
    if p.suffix.lower() != ".npz":
        raise ModelError(f"{p}: model files are .npz (got extension {p.suffix!r})")
    try:
        with open(p, "wb") as fh:
            np.savez_compressed(fh, **arrays)
    except OSError as e:
        raise ModelError(f"{p}: cannot write ({e.strerror or e})") from None


def load_model(path: str | os.PathLike) -> CalibrationModel:
    """Read a model file written by :func:`save_model`.

    Raises:
        ModelError: missing/unreadable file, not a jaxcal model, or a method unknown or not
            available in this build.
    """
    p = Path(path)
    if not p.is_file():
        raise ModelError(f"{p}: no such model file")
    try:
        with np.load(p, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError) as e:
        raise ModelError(f"{p}: cannot read as a .npz model file ({type(e).__name__})") from None
    if "jaxcal_model_format" not in d or "method" not in d:
        raise ModelError(f"{p}: not a jaxcal model file (no 'jaxcal_model_format'/'method' keys)")
    if int(d["jaxcal_model_format"]) > MODEL_FORMAT:
        raise ModelError(f"{p}: model format {int(d['jaxcal_model_format'])} is newer than this jaxcal reads")
    method = str(d["method"])
    if method not in method_names():
        raise ModelError(f"{p}: model of unknown method '{method}' (known: {', '.join(method_names())})")
    try:
        get_method(method)
    except ModelError as e:
        raise ModelError(f"{p}: {e}") from None
    try:
        meta = json.loads(str(d.get("meta_json", "{}")))
    except ValueError:
        raise ModelError(f"{p}: 'meta_json' is not valid JSON") from None
    flat = {k[len("state/"):]: v for k, v in d.items() if k.startswith("state/")}
    state = traverse_util.unflatten_dict(flat, sep="/") if flat else {}
    sensors = tuple(str(s) for s in np.atleast_1d(d.get("sensors", np.asarray([], dtype=str))))
    bad = [s for s in sensors if s not in SENSORS]
    if bad or not sensors:
        raise ModelError(f"{p}: bad 'sensors' entry {list(sensors)} (expected a subset of acc, gyr)")
    return CalibrationModel(method, sensors, state, meta)


def method_help() -> str:
    """One line per method: name, availability, description (for ``--help``)."""
    lines = []
    for n, ok in available_methods().items():
        spec = _REGISTRY.get(n)
        desc = spec.description if spec is not None else ""
        lines.append(f"{n}: {desc}" if ok else f"{n}: (not available in this build)")
    return "; ".join(lines)

