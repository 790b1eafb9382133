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
* optional ``check(state, meta, sensors)``: raise :class:`ModelError` when a loaded state cannot be
  this method's (wrong shapes, a singular matrix); :func:`load_model` runs it after checking the
  file's own fields, so a corrupt model is refused on loading, not half-way through ``apply``.

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization, traverse_util
from flax.errors import FlaxError

from jaxcal import __version__
from jaxcal.normalise import Bounds, bounds_from_spec
from jaxcal.recording import (
    NPZ_READ_ERRORS,
    Recording,
    atomic_output,
    read_npz_arrays,
    sequence_bounds,
    sequence_slices,
)
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


CheckFn = Callable[[Mapping[str, Any], Mapping[str, Any], tuple[str, ...]], None]


class MethodSpec(NamedTuple):
    """A registered calibration method. ``check(state, meta, sensors)``, optional, raises
    :class:`ModelError` when a loaded model's state cannot be this method's (wrong shapes, a
    singular matrix); :func:`load_model` runs it."""

    name: str
    fit: FitFn
    apply: ApplyFn
    needs_labels: bool
    description: str
    check: CheckFn | None = None


_REGISTRY: dict[str, MethodSpec] = {}
# Lazily imported methods: name -> loader returning a MethodSpec, or None if unavailable.
_LAZY: dict[str, Callable[[], MethodSpec | None]] = {}


def register_method(
    name: str, fit_fn: FitFn, apply_fn: ApplyFn, *, needs_labels: bool = False, description: str = "",
    check: CheckFn | None = None,
) -> None:
    """Register (or replace) a calibration method under ``name`` (see the module docstring)."""
    _REGISTRY[name] = MethodSpec(name, fit_fn, apply_fn, needs_labels, description, check)


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
    for s in have:
        _require_label_span(rec, s, method)
    return have


LABEL_SPAN_MIN = 0.01  # least label spread along any direction, relative to the labels' RMS size
_EXCITE = {"acc": "static orientations: at least 4, better 6 or more, facing different ways",
           "gyr": "rotations about all three axes"}


def _require_label_span(rec: Recording, sensor: str, method: str) -> None:
    """Refuse labels that cannot determine a 3-axis calibration: fewer than 4 samples, or labels
    that vary along fewer than 3 directions (e.g. every sample in one pose). An affine model has
    12 unknowns per sensor; labels in one pose, on a line or in a plane leave some of them free,
    and a fit would return an arbitrary (yet finite) model."""
    x = np.asarray(getattr(rec, REF_KEY[sensor]), np.float64)
    key = REF_KEY[sensor]
    gaps = ~np.isfinite(x).all(axis=1)
    if gaps.any():
        raise ModelError(f"method '{method}': '{key}' has {int(gaps.sum())} gap rows (NaN), the first at row "
                         f"{int(np.flatnonzero(gaps)[0])}; a labelled fit needs a label on every sample, so drop those rows first")
    if x.shape[0] < 4:
        n = x.shape[0]
        raise ModelError(f"method '{method}': '{key}' has {n} labelled sample{'' if n == 1 else 's'}; a 3-axis "
                         f"calibration needs at least 4; record {_EXCITE[sensor]}")
    size = float(np.sqrt(np.mean(np.sum(x**2, axis=1))))
    sv = np.linalg.svd((x - x.mean(0)) / np.sqrt(x.shape[0]), compute_uv=False)
    spanned = int(np.sum(sv > LABEL_SPAN_MIN * size)) if size > 0 else 0
    if spanned < 3:
        raise ModelError(f"method '{method}': '{key}' varies along {spanned} of 3 directions (all {x.shape[0]} "
                         f"labels {'in one pose' if spanned == 0 else 'on a line' if spanned == 1 else 'in a plane'}), "
                         f"so the 12 parameters of '{sensor}' are undetermined; record {_EXCITE[sensor]}")


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


# ----------------------------------------------------------------------------- state checks

MAX_CONDITION = 1e10  # a calibration matrix worse conditioned than this is singular for our purposes


def _check_affine_state(state: Mapping[str, Any], sensors: tuple[str, ...]) -> None:
    """Each sensor's state is an affine ``S`` (3, 3) + ``b`` (3,) or a diagonal ``s`` (3,) + ``b``,
    finite, with an invertible, reasonably conditioned scale (the model is applied by inverting it)."""
    for s in sensors:
        p = state.get(s)
        if not isinstance(p, Mapping) or "b" not in p or ("S" not in p and "s" not in p):
            raise ModelError(f"state of '{s}' is neither affine (S, b) nor diagonal (s, b)")
        name, want = ("S", (3, 3)) if "S" in p else ("s", (3,))
        for key, shape in ((name, want), ("b", (3,))):
            if np.shape(p[key]) != shape:
                raise ModelError(f"state/{s}/{key} has shape {np.shape(p[key])}, expected {shape}")
        m = np.asarray(p[name], np.float64)
        cond = np.linalg.cond(m if name == "S" else np.diag(m))
        if not np.isfinite(cond) or cond > MAX_CONDITION:
            raise ModelError(f"state/{s}/{name} is singular (condition number {cond:.3g}); the model cannot be "
                             "inverted to calibrate")


def _affine_check(state: Mapping[str, Any], meta: Mapping[str, Any], sensors: tuple[str, ...]) -> None:
    """:data:`CheckFn` of the affine-state methods (``linear``, ``online``, ``multipos``)."""
    _check_affine_state(state, sensors)


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
    check=_affine_check,
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
    _check_nn_size(widths, rec.n)
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


NN_MEMORY_LIMIT = 16 * 2**30  # bytes: a full-batch fit that needs more is refused before it starts


def _check_nn_size(widths: tuple[int, ...], n: int) -> None:
    """Refuse network sizes whose full-batch fit could not fit in memory (float32 activations and
    their gradients for ``n`` samples, weights with Adam's two moments), before any allocation."""
    if not widths or min(widths) < 1:
        raise ModelError(f"method 'nn': hidden widths must be positive integers, got {list(widths)}")
    sizes = (3, *widths, 3)
    params = sum((a + 1) * b for a, b in zip(sizes[:-1], sizes[1:]))
    need = 4 * (3 * n * sum(widths) + 4 * params)
    if need > NN_MEMORY_LIMIT:
        raise ModelError(f"method 'nn': widths {list(widths)} on {n} samples need about {need / 2**30:.3g} GiB "
                         f"(limit {NN_MEMORY_LIMIT / 2**30:.0f} GiB); use smaller --widths (the thesis uses 7500)")


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


PAD_RATIO_MAX = 4.0  # padded (sequences x longest) size allowed, relative to the samples ...
PAD_FLOOR = 2_000_000  # ... above this many padded samples (small layouts always pass)


def _sequences_of(rec: Recording, method: str) -> np.ndarray:
    """The ``seq`` ids, after :func:`_check_sequences` and :func:`_check_rotation`."""
    if rec.seq is None:
        raise ModelError(f"method '{method}' needs 'seq' ids (the recording must be split into rotation sequences)")
    _check_sequences(rec, method)
    _check_rotation(rec, method)
    return np.asarray(rec.seq)


def _check_sequences(rec: Recording, method: str) -> None:
    """Some sequence must hold a rotation (two or more samples), and padding the sequences to one
    length (the filter's layout: number of sequences x longest) must stay within
    :data:`PAD_RATIO_MAX` times the samples (or :data:`PAD_FLOOR`), so memory is bounded by the
    recording's size."""
    starts, ends = sequence_bounds(rec.seq)
    lengths = ends - starts
    if lengths.max() < 2:
        raise ModelError(f"method '{method}': all {len(lengths)} sequences have one sample each; a sequence is a "
                         "rotation: contiguous samples sharing one 'seq' id")
    padded = len(lengths) * int(lengths.max())
    if padded > max(PAD_RATIO_MAX * rec.n, PAD_FLOOR):
        raise ModelError(
            f"method '{method}': {len(lengths)} sequences of very unequal length (longest {int(lengths.max())}, "
            f"median {int(np.median(lengths))} samples) pad to {padded} samples, {padded / rec.n:.0f}x the "
            f"recording's {rec.n}; split the long sequences or drop the short ones")


def _check_rotation(rec: Recording, method: str) -> None:
    """Refuse a recording whose accelerometer or gyroscope output never changes: it holds no
    rotation, and a self-calibration would only return its prior."""
    for s in SENSORS:
        y = np.asarray(getattr(rec, s), np.float64)
        if np.ptp(y, axis=0).max() == 0:
            raise ModelError(f"method '{method}': '{s}' never changes (all {rec.n} samples identical); "
                             "the recording holds no rotation to calibrate from")


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
        _affine_check,
    )


def _build_multipos(mod: Any) -> MethodSpec:
    def fit(rec: Recording, options: FitOptions) -> Fitted:
        # No progress line before the fit: its refusals (poses that determine too little, turns the
        # data contradict) come from the fit itself and must stay the only line on stderr.
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
        options.say(f"fitted multipos on {rec.n} samples in {elapsed:.1f} s")
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
        _affine_check,
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
    except (KeyError, TypeError, IndexError, ValueError, AttributeError, FlaxError) as e:
        # a state/meta entry missing or of the wrong kind or shape
        msg = " ".join(str(e).split())[:200]
        raise ModelError(f"'{model.method}' model is malformed ({type(e).__name__}: {msg})") from None
    out = {k: np.asarray(v, np.float64) for k, v in out.items() if k in ("acc_cal", "gyr_cal")}
    _check_output(model.method, out, rec.n)
    return out


def _check_output(method: str, out: Mapping[str, np.ndarray], n: int) -> None:
    """Calibrated arrays must be (N, 3) and finite: a model that yields NaN or inf is refused
    rather than written."""
    if not out:
        raise ModelError(f"the '{method}' model calibrated none of the recording's sensors")
    for k, v in out.items():
        if v.shape != (n, 3):
            raise ModelError(f"'{method}' model gives {k} of shape {v.shape}, expected ({n}, 3): the model is malformed")
        bad = np.argwhere(~np.isfinite(v))
        if bad.size:
            raise ModelError(f"'{method}' model gives a non-finite {k} at row {int(bad[0][0])} (a singular or "
                             "corrupt model, or input far outside its range)")


def save_model(model: CalibrationModel, path: str | os.PathLike) -> None:
    """Write ``model`` as a ``.npz`` model file (see the module docstring).

    The file is written beside ``path`` and renamed over it only when complete
    (:func:`jaxcal.recording.atomic_output`): an interruption leaves an earlier model intact.
    """
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
        with atomic_output(p) as tmp, open(tmp, "wb") as fh:  # whole or not at all: never a truncated model
            np.savez_compressed(fh, **arrays)
    except OSError as e:
        raise ModelError(f"{p}: cannot write ({e.strerror or e})") from None


def load_model(path: str | os.PathLike) -> CalibrationModel:
    """Read a model file written by :func:`save_model`, checking every field before use.

    Raises:
        ModelError: missing/unreadable file, not a jaxcal model, a header field of the wrong
            kind (format not an integer, metadata not a JSON object, ...), state arrays that are
            not finite real numbers, a state the method cannot use (its ``check``: e.g. a 2x2 or
            singular matrix), or a method unknown or not available in this build.
    """
    p = Path(path)
    if not p.is_file():
        raise ModelError(f"{p}: no such model file")
    try:
        d = read_npz_arrays(p)
    except NPZ_READ_ERRORS as e:
        raise ModelError(f"{p}: cannot read as a .npz model file ({type(e).__name__})") from None
    try:
        method = _model_method(d)
        meta = _model_meta(d)
        sensors = _model_sensors(d)
        state = _model_state(d, sensors)
        spec = get_method(method)
    except ModelError as e:
        raise ModelError(f"{p}: {e}") from None
    if spec.check is not None:
        try:
            spec.check(state, meta, sensors)
        except ModelError as e:
            raise ModelError(f"{p}: malformed '{method}' model: {e}") from None
    return CalibrationModel(method, sensors, state, meta)


def _scalar_field(d: Mapping[str, np.ndarray], key: str, kinds: str, what: str) -> Any:
    """A 0-d entry of the model file whose dtype kind is in ``kinds``, as a Python scalar."""
    a = d[key]
    if a.shape != () or a.dtype.kind not in kinds:
        raise ModelError(f"'{key}' must be {what}, got {a.dtype} of shape {a.shape}")
    return a.item()


def _model_method(d: Mapping[str, np.ndarray]) -> str:
    """Format (an integer this jaxcal reads) and method name (a known string)."""
    if "jaxcal_model_format" not in d or "method" not in d:
        raise ModelError("not a jaxcal model file (no 'jaxcal_model_format'/'method' keys)")
    fmt = _scalar_field(d, "jaxcal_model_format", "iu", "an integer")
    if not 1 <= fmt <= MODEL_FORMAT:
        raise ModelError(f"model format {fmt} is not one this jaxcal reads (1..{MODEL_FORMAT})")
    method = str(_scalar_field(d, "method", "U", "a string"))
    if method not in method_names():
        raise ModelError(f"model of unknown method '{method}' (known: {', '.join(method_names())})")
    return method


def _model_meta(d: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """``meta_json``: a JSON object (``{}`` if absent); its ``units``, if any, an object too."""
    text = _scalar_field(d, "meta_json", "U", "a JSON string") if "meta_json" in d else "{}"
    try:
        meta = json.loads(text)
    except ValueError:
        raise ModelError("'meta_json' is not valid JSON") from None
    if not isinstance(meta, dict):
        raise ModelError(f"'meta_json' must hold a JSON object, got {type(meta).__name__}")
    if not isinstance(meta.get("units", {}), dict):
        raise ModelError(f"'meta_json' field 'units' must be an object, got {type(meta['units']).__name__}")
    return meta


def _model_sensors(d: Mapping[str, np.ndarray]) -> tuple[str, ...]:
    """``sensors``: a non-empty set of strings from ``acc``, ``gyr``."""
    a = d.get("sensors", np.asarray([], dtype=str))
    if a.dtype.kind != "U" or a.ndim > 1:
        raise ModelError(f"'sensors' must be a list of strings, got {a.dtype} of shape {a.shape}")
    sensors = tuple(str(s) for s in np.atleast_1d(a))
    if not sensors or any(s not in SENSORS for s in sensors) or len(set(sensors)) != len(sensors):
        raise ModelError(f"bad 'sensors' entry {list(sensors)} (expected a subset of acc, gyr)")
    return sensors


def _model_state(d: Mapping[str, np.ndarray], sensors: tuple[str, ...]) -> dict[str, Any]:
    """The ``state/...`` arrays, unflattened: finite real numbers, an entry for every sensor."""
    flat = {k[len("state/"):]: v for k, v in d.items() if k.startswith("state/")}
    for k, v in flat.items():
        if v.dtype.kind not in "iuf":
            raise ModelError(f"state/{k}: expected real numbers, got {v.dtype}")
        if not np.all(np.isfinite(v)):
            raise ModelError(f"state/{k}: non-finite value")
    try:
        state = traverse_util.unflatten_dict(flat, sep="/") if flat else {}
    except (ValueError, TypeError, KeyError) as e:
        raise ModelError(f"state keys do not form a tree ({type(e).__name__}: {e})") from None
    missing = [s for s in sensors if not isinstance(state.get(s), dict)]
    if missing:
        raise ModelError(f"no state for '{missing[0]}', which 'sensors' lists")
    return state


def method_help() -> str:
    """One line per method: name, availability, description (for ``--help``)."""
    lines = []
    for n, ok in available_methods().items():
        spec = _REGISTRY.get(n)
        desc = spec.description if spec is not None else ""
        lines.append(f"{n}: {desc}" if ok else f"{n}: (not available in this build)")
    return "; ".join(lines)

