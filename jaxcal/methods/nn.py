"""Method ``nn``: the thesis's MLP sensor model per sensor (section 3.3), fitted to reference
labels with :func:`jaxcal.nn.fit_nn` (Adam, early stopping on a held-out share) and applied with
:func:`jaxcal.nn.nn_calibrate` after the eq. 3.6-3.7 input normalisation."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal import flags
from jaxcal.constants import ACC_RANGE_G, GYR_RANGE_DEGS, GYR_RANGE_RADS, PHYS_UNIT, SENSORS
from jaxcal.flags import Flag
from jaxcal.methods.base import (
    REF_KEY,
    SHARED_FLAGS,
    Fitted,
    Log,
    Method,
    ModelError,
    holdout_mask,
    labelled_sensors,
    recording_spec,
    units,
)
from jaxcal.methods.quality import early_stopping_quality
from jaxcal.nn import MLP, NNCalibration, fit_nn, nn_calibrate_jit
from jaxcal.normalise import Bounds, bounds_from_spec
from jaxcal.recording import Recording
from jaxcal.train import TrainConfig

__all__ = ["METHOD", "NN_MEMORY_LIMIT", "NNOptions", "apply", "fit"]


class NNOptions(NamedTuple):
    """Options of ``nn`` (static: plain Python values). The defaults are the recipe of the chapter-3
    reproduction (:class:`jaxcal.offline.NNTrainSpec`, chosen in ``results/sweep_offline_nn/sweep.md``):
    output layer warm-started by ridge least squares on the random hidden features, then full-batch
    Adam at 3e-5 until the validation loss stops falling by 0.1 % within 200 epochs. On 1000
    labelled orientations of the Dataset 1 surrogate it reaches 0.45x the linear model's test
    error (1.03 vs 2.27 mg) in about 30 s on 2 CPU cores (``tests/test_methods_nn.py``).

    Args:
        seed: PRNG seed of the initial weights.
        sensors: sensors to calibrate (subset of ``("acc", "gyr")``); ``None``: every labelled one.
        widths: hidden layer widths (thesis offline network: one layer of 7500).
        slope: leaky-ReLU slope (thesis: 0.1).
        learning_rate: Adam step size.
        patience: early-stopping patience (epochs without validation improvement).
        max_epochs: cap on full-batch epochs.
        min_rel_delta: relative fall of the validation loss that counts as an improvement.
        warm_start: start Adam from the ridge least-squares output layer
            (:func:`jaxcal.nn.ridge_output_layer`); ``False``: from the random initialisation.
        row_chunk: rows per gradient block (cache-sized; ``None``: all rows at once).
        val_fraction: share of labelled samples held out (deterministically) for early stopping.
        acc_range: accelerometer full scale (g) for the eq. 3.6 bounds from the datasheet values.
        gyr_range: gyroscope full scale (rad/s) for the eq. 3.6 bounds.
    """

    seed: int = 0
    sensors: tuple[str, ...] | None = None
    widths: tuple[int, ...] = (7500,)
    slope: float = 0.1
    learning_rate: float = 3e-5
    patience: int = 200
    max_epochs: int = 5000
    val_fraction: float = 0.15
    acc_range: float = ACC_RANGE_G
    gyr_range: float = GYR_RANGE_RADS
    min_rel_delta: float = 1e-3
    warm_start: bool = True
    row_chunk: int | None = 200

    # row_chunk has no flag: a memory layout knob, not a calibration choice
    FLAGS = {
        "seed": SHARED_FLAGS["seed"],
        "sensors": SHARED_FLAGS["sensors"],
        "widths": Flag("--widths", flags.int_tuple, None, "hidden widths, e.g. 7500 or 5,10,5", "W[,W...]"),
        "slope": Flag("--slope", flags.real(0.0, 1.0, open_low=False), None, "leaky-ReLU slope in [0, 1]", "A"),
        "learning_rate": Flag("--lr", flags.real(0.0, 10.0), None, "Adam learning rate", "LR"),
        "patience": Flag("--patience", flags.count(1, 10**9), None, "early-stopping patience in epochs", "N"),
        "max_epochs": Flag("--max-epochs", flags.count(1, 10**9), None, "maximum full-batch epochs", "N"),
        "val_fraction": Flag("--val-fraction", flags.real(0.0, 0.99), None, "share of labelled samples held out for "
                             "early stopping, whole sequences if `seq` is given", "F"),
        "acc_range": Flag("--acc-range", flags.real(0.0, 1e6), None, "accelerometer full scale in g for eq. 3.6 bounds",
                          "G"),
        "gyr_range": Flag("--gyr-range", flags.real(0.0, 1e6), flags.degs_to_rads,
                          "gyroscope full scale in deg/s for eq. 3.6 bounds", "DEG_S", show_default=GYR_RANGE_DEGS),
        "min_rel_delta": Flag("--min-rel-delta", flags.real(0.0, 1.0, open_low=False), None,
                              "relative fall of the validation loss that counts as an improvement", "R"),
        "warm_start": Flag("--no-warm-start", None, None, "start Adam from the random initialisation, not from the "
                           "ridge least-squares output layer", const=False, show_default="warm start"),
    }


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


def _nn_bounds(rec: Recording, sensor: str, y: np.ndarray, options: NNOptions) -> tuple[Bounds, str]:
    """Eq. 3.6 input bounds: from the datasheet values and the full scale, else the data range +- 10 %."""
    spec = recording_spec(rec, sensor)
    if spec is not None:
        rng = options.acc_range if sensor == "acc" else options.gyr_range
        return bounds_from_spec(spec, rng), f"spec, range {rng:g} {PHYS_UNIT[sensor]}"
    lo, hi = y.min(axis=0), y.max(axis=0)
    pad = 0.1 * np.maximum(hi - lo, 1.0)
    return Bounds(jnp.asarray(lo - pad, jnp.float32), jnp.asarray(hi + pad, jnp.float32)), "data range +- 10 %"


def fit(rec: Recording, options: NNOptions, log: Log) -> Fitted:
    """Train one MLP per labelled sensor (full batch, early stopping on the :func:`holdout_mask` share).

    Args:
        rec: a recording with ``acc``/``acc_ref`` and/or ``gyr``/``gyr_ref``.
        options: :class:`NNOptions`.
        log: progress sink.
    """
    sensors = labelled_sensors(rec, options.sensors, "nn")
    val = holdout_mask(rec, options.val_fraction)
    if not val.any():
        raise ModelError("method 'nn' needs at least 2 labelled samples (training + validation)")
    widths = tuple(int(w) for w in options.widths)
    _check_nn_size(widths, rec.n)
    mlp = MLP(widths=widths, out_dim=3, slope=float(options.slope))
    config = TrainConfig(learning_rate=options.learning_rate, patience=options.patience, min_delta=0.0,
                         min_rel_delta=options.min_rel_delta)
    max_epochs = int(options.max_epochs)

    clock = {"t0": time.perf_counter(), "sensor": ""}

    def progress(epoch, loss, val, best):
        """Host side of the training loop's progress callback: epoch, losses as RMS, and an ETA to
        the epoch cap (early stopping usually ends sooner)."""
        e = int(epoch)
        spent = time.perf_counter() - clock["t0"]
        eta = spent / e * (max_epochs - e)
        log(f"nn ({clock['sensor']}): epoch {e}/{max_epochs}, train rms {math.sqrt(3.0 * float(loss)):.3g}, "
            f"validation rms {math.sqrt(3.0 * float(val)):.3g} (best {math.sqrt(3.0 * float(best)):.3g}), "
            f"{spent:.0f} s, at most {eta:.0f} s left")

    @jax.jit
    def train(key, bounds, y_tr, x_tr, y_va, x_va):
        w_tr = jnp.ones(y_tr.shape[0], jnp.float32)
        return fit_nn(key, mlp, bounds, (y_tr, x_tr, w_tr), (y_va, x_va), config, max_epochs,
                      bool(options.warm_start), options.row_chunk, progress=progress)

    state: dict[str, Any] = {}
    meta: dict[str, Any] = {
        "units": units(rec, sensors),
        "widths": list(widths),
        "slope": float(options.slope),
        "learning_rate": float(options.learning_rate),
        "patience": int(options.patience),
        "max_epochs": max_epochs,
        "min_rel_delta": float(options.min_rel_delta),
        "warm_start": bool(options.warm_start),
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
        log(f"fitting nn ({s}) on {int((~val).sum())} samples ({int(val.sum())} held out for early stopping), "
            f"widths {widths}, up to {max_epochs} epochs ...")
        t0 = time.perf_counter()
        clock.update(t0=t0, sensor=s)
        cal, res = train(
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
        log(f"fitting nn ({s}) ... done in {dt:.1f} s: {int(res.epochs)} epochs, best at {int(res.best_epoch)}, "
            f"validation rms {meta['val_rms'][s]:.3g} {PHYS_UNIT[s]}")
    return Fitted(sensors, state, meta)


def _nn_state(p: Mapping[str, Any]) -> NNCalibration:
    """A stored ``{"params": ..., "bounds": {"lo", "hi"}}`` as an :class:`~jaxcal.nn.NNCalibration`."""
    params = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), dict(p["params"]))
    return NNCalibration(params, Bounds(*(jnp.asarray(p["bounds"][k]) for k in Bounds._fields)))


def apply(state: Mapping[str, Any], meta: Mapping[str, Any], rec: Recording) -> dict[str, np.ndarray]:
    """Calibrate with the stored networks (eq. 3.7 normalisation, then the MLP; float32).

    Args:
        state: ``sensor -> {"params", "bounds"}``.
        meta: the fit's metadata (``widths``, ``slope`` rebuild the network).
        rec: the recording to calibrate.
    """
    mlp = MLP(widths=tuple(int(w) for w in meta["widths"]), out_dim=3, slope=float(meta["slope"]))
    out = {}
    for s, p in state.items():
        y = getattr(rec, s)
        if y is None:
            continue
        cal = _nn_state(p)
        out[f"{s}_cal"] = np.asarray(nn_calibrate_jit(mlp, cal, jnp.asarray(y, jnp.float32)))
    return out


METHOD = Method("nn", fit, apply, NNOptions, "MLP sensor model per sensor (thesis section 3.3); needs acc_ref/gyr_ref",
                quality=early_stopping_quality)
