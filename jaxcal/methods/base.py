"""What a calibration method is, and the checks its adapters share.

A method is a :class:`Method`: a name, a ``fit`` and an ``apply`` function, its typed options
(a ``NamedTuple`` whose defaults are the only copy of the method's defaults; the CLI reads its
flags' defaults from them), a one-line description, an optional ``check`` of a loaded state and
an optional ``quality`` (what ``jaxcal calibrate`` reports in-sample and held out).

* ``fit(rec, options, log) -> Fitted``: estimate a calibration from a
  :class:`~jaxcal.recording.Recording`; ``log`` is a progress sink (one line per call).
  ``Fitted.state`` is a pytree whose leaves are arrays, keyed per sensor (typed ``NamedTuple``
  states such as :class:`~jaxcal.sensor.Affine`, flax params); it is stored by field name
  (``state/acc/S``, ...). ``Fitted.meta`` is a JSON-able dict.
* ``apply(state, meta, rec) -> {"acc_cal": (N, 3) g, "gyr_cal": (N, 3) rad/s}``: ``state`` comes
  back from a model file as nested dicts of numpy arrays; the method rebuilds its typed state by
  field name (e.g. :func:`affine_state`). Only the sensors present are returned.
* ``check(state, meta, sensors)``, optional: raise :class:`ModelError` when a loaded state cannot
  be this method's (wrong shapes, a singular matrix).

Shared here: the recording checks that several methods make (labels that span three directions,
both sensors, ``seq`` ids that form rotations, datasheet values), the validation hold-out, and the
linear-state helpers (a forward :class:`~jaxcal.sensor.Affine` on file, applied as a
:class:`~jaxcal.sensor.LinearCal`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxcal import flags
from jaxcal.constants import PHYS_UNIT, SENSORS
from jaxcal.flags import Flag
from jaxcal.multipos import DatasheetPrior
from jaxcal.precision import float64
from jaxcal.recording import Recording, sequence_slices
from jaxcal.sensor import Affine, Diag, LinearCal, spec_diag
from jaxcal.sequences import sequence_bounds

__all__ = [
    "LABEL_SPAN_MIN",
    "MAX_CONDITION",
    "PAD_FLOOR",
    "PAD_RATIO_MAX",
    "REF_KEY",
    "SHARED_FLAGS",
    "ApplyFn",
    "CheckFn",
    "FitFn",
    "GSENS_KEY",
    "Fitted",
    "Log",
    "Method",
    "ModelError",
    "affine_state",
    "apply_linear_state",
    "check_linear_state",
    "datasheet_cals",
    "datasheet_prior",
    "fit_each_labelled",
    "gsens_of",
    "holdout_mask",
    "labelled_sensors",
    "linear_cal_of_state",
    "linear_state",
    "recording_dt",
    "recording_spec",
    "require_both",
    "require_label_span",
    "require_spec",
    "rms",
    "sequences_of",
    "units",
]

REF_KEY = {"acc": "acc_ref", "gyr": "gyr_ref"}

# The flags of option fields that several methods' options types share (each type declares them in
# its ``FLAGS`` from here, so a shared field has one flag; jaxcal.flags).
SHARED_FLAGS: dict[str, Flag] = {
    "seed": Flag("--seed", flags.seed, None, "PRNG seed in [0, 2**32 - 1]", "N"),
    "sensors": Flag("--sensors", flags.sensors, None, "calibrate only these: acc, gyr or acc,gyr", "S",
                    show_default="all labelled"),
    "g_sensitivity": Flag("--g-sensitivity", None, None, "also fit the gyroscope's g-sensitivity G ((rad/s)/g: "
                          "w = A_g (y_g - b_g) - G f, f the calibrated accelerometer) jointly with the gyro bias from "
                          "the rests (4+ poses spanning 3-D), stored as state/gyr/G and applied by `jaxcal apply` "
                          "(which then needs the recording's acc)", const=True,
                          show_default="off"),
    "datasheet_prior": Flag("--datasheet-prior", None, None, "MAP fit of the rests with the recording's datasheet "
                            "scales (acc_lsb_per_g, gyr_lsb_per_rads) as prior centre, tolerances --prior-scale and "
                            "--prior-cross (online: its initial calibration; never its starting point)", const=True,
                            show_default="off"),
    "prior_scale": Flag("--prior-scale", flags.real(0.0, 10.0), None,
                        "prior std of the relative scale around the datasheet value (sensitivity tolerance)", "S"),
    "prior_cross": Flag("--prior-cross", flags.real(0.0, 10.0), None, "prior std of the cross-axis terms", "S"),
    "init_duration": Flag("--init-duration", flags.real(0.0, 1e6), None, "seconds of initial rest that set the rest "
                          "detector's threshold", "SEC", show_default="10 %% of the recording, at most 30 s"),
    "min_rest": Flag("--min-rest", flags.real(0.0, 1e6), None, "shortest rest (pose) kept, in seconds", "SEC"),
    "rest_window": Flag("--rest-window", flags.real(0.0, 1e6), None,
                        "moving-variance window of the rest detector, seconds", "SEC"),
}


class ModelError(ValueError):
    """Bad model file, unknown method, or data unsuitable for a method (one line)."""


class Fitted(NamedTuple):
    """What a method's ``fit`` returns.

    Args:
        sensors: the sensors calibrated, a subset of ``("acc", "gyr")`` in that order.
        state: per-sensor parameter pytree (typed ``NamedTuple`` states, flax params); stored by name.
        meta: JSON-able metadata (units, hyperparameters, fit statistics).
    """

    sensors: tuple[str, ...]
    state: Any
    meta: dict[str, Any]


Log = Callable[[str], None]
FitFn = Callable[[Recording, Any, Log], Fitted]
ApplyFn = Callable[[Mapping[str, Any], Mapping[str, Any], Recording], dict[str, np.ndarray]]
CheckFn = Callable[[Mapping[str, Any], Mapping[str, Any], tuple[str, ...]], None]


class Method(NamedTuple):
    """A calibration method, as registered in :data:`jaxcal.methods.REGISTRY`.

    Args:
        name: the name used by ``jaxcal calibrate --method`` and stored in model files.
        fit: ``fit(rec, options, log) -> Fitted`` (see the module docstring).
        apply: ``apply(state, meta, rec) -> {"acc_cal": ..., "gyr_cal": ...}``.
        options: the method's options type (a ``NamedTuple`` with a default for every field; its
            class attribute ``FLAGS``, field -> :class:`~jaxcal.flags.Flag`, declares the
            ``calibrate`` flags of its fields, :data:`SHARED_FLAGS` for a field another type shares;
            optional ``EFFECTS``, ``(sensor, effect)`` -> a boolean field, the vocabulary effects a
            ``jaxcal diagnose`` report can switch on, :mod:`jaxcal.methods.from_report`).
        doc: one-line description (``jaxcal methods``).
        check: optional ``check(state, meta, sensors)`` run by ``load_model``; raises :class:`ModelError`.
        quality: optional ``quality(rec, options, model, *, held_out, log) -> (in_sample, held_out)``,
            the method's quality rows (:class:`~jaxcal.eval.scores.QualityRow`, ``None`` where not
            computed) that ``jaxcal calibrate`` reports (:func:`jaxcal.methods.summary.describe`);
            ``None``: no built-in held-out score.
    """

    name: str
    fit: FitFn
    apply: ApplyFn
    options: type
    doc: str
    check: CheckFn | None = None
    quality: Callable[..., tuple[Any, Any]] | None = None


# ----------------------------------------------------------------------------- recording helpers


def units(rec: Recording, sensors: tuple[str, ...]) -> dict[str, str]:
    """``sensor -> unit`` of the recording's sensors (stored in the model's metadata).

    Args:
        rec: the recording.
        sensors: the sensors to report, a subset of ``("acc", "gyr")``.
    """
    return {s: getattr(rec, f"{s}_unit") for s in sensors}


def rms(e: np.ndarray) -> float:
    """Root mean square of the row norms of ``e`` (float64)."""
    return float(np.sqrt(np.mean(np.sum(np.asarray(e, np.float64) ** 2, axis=-1))))


def recording_spec(rec: Recording, sensor: str) -> Diag | None:
    """Datasheet model of ``sensor`` from the recording metadata (eq. 4.8), or ``None``.

    A sensor already in physical units (``acc_unit == "g"`` / ``gyr_unit == "rad/s"``) has the
    identity spec (scale 1, bias 0). Otherwise the scale key (``acc_lsb_per_g`` /
    ``gyr_lsb_per_rads``) is needed; the bias key defaults to 0.

    Args:
        rec: the recording.
        sensor: ``"acc"`` or ``"gyr"``.
    """
    if getattr(rec, f"{sensor}_unit") == PHYS_UNIT[sensor]:
        return spec_diag(1.0, 0.0)
    scale = rec.acc_lsb_per_g if sensor == "acc" else rec.gyr_lsb_per_rads
    bias = rec.acc_bias_lsb if sensor == "acc" else rec.gyr_bias_lsb
    if scale is None:
        return None
    return spec_diag(np.asarray(scale, np.float32), np.asarray(0.0 if bias is None else bias, np.float32))


@float64
def datasheet_cals(rec: Recording) -> tuple[LinearCal, LinearCal] | None:
    """The datasheet conversion of both sensors (:func:`recording_spec`) as numpy float64
    :class:`~jaxcal.sensor.LinearCal` pair (the starting point of the ``seq`` methods), or ``None``
    when either has no datasheet values."""
    specs = [recording_spec(rec, s) for s in SENSORS]
    if any(sp is None for sp in specs):
        return None
    cals = tuple(LinearCal.from_diag(Diag(jnp.asarray(sp.s, jnp.float64), jnp.asarray(sp.b, jnp.float64)))
                 for sp in specs)
    return tuple(LinearCal(np.asarray(c.A), np.asarray(c.b)) for c in cals)


def datasheet_prior(rec: Recording, prior_scale: float, prior_cross: float, method: str) -> DatasheetPrior:
    """``--datasheet-prior``: the recording's datasheet scales (``acc_lsb_per_g``, ``gyr_lsb_per_rads``;
    1 for a sensor already in g or rad/s) as the initial fit's prior centre, with the tolerances
    ``prior_scale`` (relative) and ``prior_cross``; refused in one line without them.

    Args:
        rec: the recording.
        prior_scale, prior_cross: the prior's std (the datasheet's sensitivity and cross-axis tolerances).
        method: the method's name, for the message.
    """
    per = {}
    for s, key in (("acc", "acc_lsb_per_g"), ("gyr", "gyr_lsb_per_rads")):
        if getattr(rec, f"{s}_unit") in ("g", "rad/s"):
            per[s] = 1.0
            continue
        v = getattr(rec, key)
        if v is None:
            raise ModelError(f"{method} --datasheet-prior needs '{key}' in the recording metadata")
        per[s] = float(1.0 / np.mean(np.asarray(v, np.float64)))
    return DatasheetPrior(per["acc"], per["gyr"], float(prior_scale), float(prior_cross))


def recording_dt(rec: Recording) -> float:
    """Sample period (s): ``1 / fs`` if given, else the median spacing of ``t`` within sequences.

    Args:
        rec: the recording.
    """
    if rec.fs is not None:
        return 1.0 / rec.fs
    diffs = [np.diff(np.asarray(rec.t, np.float64)[s]) for s in sequence_slices(rec)]
    diffs = [d for d in diffs if d.size]
    if not diffs:
        raise ModelError("cannot tell the sample period: one sample per sequence and no 'fs'")
    return float(np.median(np.concatenate(diffs)))


def labelled_sensors(rec: Recording, wanted: tuple[str, ...] | None, method: str) -> tuple[str, ...]:
    """The sensors of ``wanted`` (``None``: both) that ``rec`` has with reference labels, each
    checked by :func:`require_label_span`.

    Args:
        rec: the recording.
        wanted: sensors asked for (the method's ``sensors`` option), ``None`` for all.
        method: method name for the messages.

    Raises:
        ModelError: a wanted sensor is absent, no wanted sensor is labelled, or labels that cannot
            determine a 3-axis calibration.
    """
    if wanted is not None:
        absent = [s for s in wanted if getattr(rec, s) is None]
        if absent:
            raise ModelError(f"recording has no '{absent[0]}' to calibrate")
    wanted = wanted or SENSORS
    have = tuple(s for s in wanted if getattr(rec, s) is not None and getattr(rec, REF_KEY[s]) is not None)
    if not have:
        need = " or ".join(f"'{s}' with '{REF_KEY[s]}'" for s in wanted)
        raise ModelError(f"method '{method}' needs reference labels: recording has no {need}")
    for s in have:
        require_label_span(rec, s, method)
    return have


def fit_each_labelled(rec: Recording, sensors: tuple[str, ...], method: str,
                      fit_one: Callable[[str, np.ndarray, np.ndarray], tuple[Any, np.ndarray]], log: Log,
                      detail: str = "") -> tuple[dict[str, Any], dict[str, float]]:
    """The per-sensor loop of the methods fitted to reference labels (``linear``, ``cubic``): each
    sensor's samples ``y`` and labels ``x`` in float64 to ``fit_one(sensor, y, x) -> (model, x_hat)``,
    timed and logged, and its training RMS (:func:`rms` of ``x_hat - x``).

    Args:
        rec: the recording.
        sensors: the labelled sensors to fit (:func:`labelled_sensors`), in order.
        method: method name for the log lines.
        fit_one: fits one sensor and returns its model and its calibrated training samples.
        log: progress sink.
        detail: what the start line adds after the sensor (e.g. ``", degree 3 (60 parameters),"``).

    Returns:
        ``sensor -> model`` and ``sensor -> train RMS``, in ``sensors`` order.
    """
    state: dict[str, Any] = {}
    train_rms: dict[str, float] = {}
    for s in sensors:
        y = np.asarray(getattr(rec, s), np.float64)
        x = np.asarray(getattr(rec, REF_KEY[s]), np.float64)
        log(f"fitting {method} ({s}){detail} on {rec.n} samples ...")
        t0 = time.perf_counter()
        state[s], x_hat = fit_one(s, y, x)
        train_rms[s] = rms(x_hat - x)
        log(f"fitting {method} ({s}) ... done in {time.perf_counter() - t0:.1f} s, "
            f"train rms {train_rms[s]:.3g} {PHYS_UNIT[s]}")
    return state, train_rms


LABEL_SPAN_MIN = 0.01  # least label spread along any direction, relative to the labels' RMS size
_EXCITE = {"acc": "static orientations: at least 4, better 6 or more, facing different ways",
           "gyr": "rotations about all three axes"}


def require_label_span(rec: Recording, sensor: str, method: str) -> None:
    """Refuse labels that cannot determine a 3-axis calibration: fewer than 4 samples, or labels
    that vary along fewer than 3 directions (e.g. every sample in one pose). An affine model has
    12 unknowns per sensor; labels in one pose, on a line or in a plane leave some of them free,
    and a fit would return an arbitrary (yet finite) model.

    Args:
        rec: the recording.
        sensor: ``"acc"`` or ``"gyr"`` (its labels ``acc_ref`` / ``gyr_ref`` are judged).
        method: the method's name, for the message.
    """
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


def holdout_mask(rec: Recording, fraction: float) -> np.ndarray:
    """Deterministic validation mask holding out about ``fraction`` of the samples.

    With several sequences (``seq``), whole sequences are held out (every k-th, evenly spread),
    so correlated neighbours do not leak between the two sets; otherwise every k-th sample.
    Always keeps at least one training and one validation sample (for ``N >= 2``).

    Args:
        rec: the recording.
        fraction: share of samples (or sequences) to hold out, in (0, 1).
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


def require_both(rec: Recording, method: str) -> None:
    """Refuse a recording that lacks the accelerometer or the gyroscope.

    Args:
        rec: the recording.
        method: the method's name, for the message.
    """
    missing = [s for s in SENSORS if getattr(rec, s) is None]
    if missing:
        raise ModelError(f"method '{method}' needs both 'acc' and 'gyr' (recording lacks '{missing[0]}')")


def require_spec(rec: Recording, sensor: str, method: str) -> Diag:
    """The datasheet model of ``sensor`` (:func:`recording_spec`); refuse a recording without one.

    Args:
        rec: the recording.
        sensor: ``"acc"`` or ``"gyr"``.
        method: the method's name, for the message.
    """
    spec = recording_spec(rec, sensor)
    if spec is None:
        key = "acc_lsb_per_g" if sensor == "acc" else "gyr_lsb_per_rads"
        raise ModelError(f"method '{method}' needs the datasheet scale '{key}' in the recording metadata")
    return spec


PAD_RATIO_MAX = 4.0  # padded (sequences x longest) size allowed, relative to the samples ...
PAD_FLOOR = 2_000_000  # ... above this many padded samples (small layouts always pass)


def sequences_of(rec: Recording, method: str) -> np.ndarray:
    """The ``seq`` ids of a recording of rotation sequences, after :func:`_check_sequences` and
    :func:`_check_rotation`.

    Args:
        rec: the recording (both sensors present).
        method: method name for the messages.
    """
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


# ----------------------------------------------------------------------------- linear states

GSENS_KEY = "G"
"""The optional key of a linear gyroscope state holding its g-sensitivity ``G`` (3, 3), (rad/s)/g."""

MAX_CONDITION = 1e10  # a calibration matrix worse conditioned than this is singular for our purposes


@float64
def linear_state(cal: LinearCal) -> Affine:
    """The state a linear calibration is stored as: its forward model ``y = S x + b`` (numpy
    float64, ``S = A^{-1}``), written as ``state/<sensor>/S`` and ``state/<sensor>/b``."""
    fwd = LinearCal(jnp.asarray(cal.A, jnp.float64), jnp.asarray(cal.b, jnp.float64)).to_forward()
    return Affine(np.asarray(fwd.S), np.asarray(fwd.b))


def affine_state(p: Mapping[str, Any]) -> Affine:
    """A stored linear state (``{"S": (3, 3), "b": (3,)}``) as a float64 :class:`~jaxcal.sensor.Affine`.
    Call inside a :func:`~jaxcal.precision.float64` entry point."""
    return Affine(*(jnp.asarray(p[k], jnp.float64) for k in Affine._fields))


@float64
def linear_cal_of_state(p: Mapping[str, Any]) -> LinearCal:
    """A stored linear state's applied calibration ``x = A (y - b)`` (numpy float64), ``A = S^{-1}``
    computed exactly as :func:`apply_linear_state` computes it
    (:meth:`~jaxcal.sensor.LinearCal.from_forward` of :func:`affine_state`).

    Args:
        p: ``{"S": (3, 3), "b": (3,)}``.
    """
    cal = LinearCal.from_forward(affine_state(p))
    return LinearCal(np.asarray(cal.A, np.float64), np.asarray(cal.b, np.float64))


def check_linear_state(state: Mapping[str, Any], meta: Mapping[str, Any], sensors: tuple[str, ...]) -> None:
    """:data:`CheckFn` of the linear methods: each sensor's state is an affine ``S`` (3, 3) and
    ``b`` (3,), finite, with an invertible, reasonably conditioned ``S`` (it is inverted to
    calibrate). The gyroscope may also hold its g-sensitivity ``G`` (3, 3), finite, in
    (rad/s)/g (:data:`GSENS_KEY`); it is applied with the calibrated accelerometer, so a model
    with ``G`` must also calibrate ``acc``.

    Args:
        state: the loaded state (nested dicts of numpy arrays).
        meta: the model's metadata (unused).
        sensors: the model's sensors.
    """
    for s in sensors:
        p = state.get(s)
        if not isinstance(p, Mapping) or any(k not in p for k in Affine._fields):
            raise ModelError(f"state of '{s}' is not affine (S, b)")
        for key, shape in (("S", (3, 3)), ("b", (3,))):
            if np.shape(p[key]) != shape:
                raise ModelError(f"state/{s}/{key} has shape {np.shape(p[key])}, expected {shape}")
        cond = np.linalg.cond(np.asarray(p["S"], np.float64))
        if not np.isfinite(cond) or cond > MAX_CONDITION:
            raise ModelError(f"state/{s}/S is singular (condition number {cond:.3g}); the model cannot be "
                             "inverted to calibrate")
        if GSENS_KEY in p:
            if s != "gyr":
                raise ModelError(f"state/{s}/{GSENS_KEY}: only the gyroscope has a g-sensitivity")
            if np.shape(p[GSENS_KEY]) != (3, 3):
                raise ModelError(f"state/gyr/{GSENS_KEY} has shape {np.shape(p[GSENS_KEY])}, expected (3, 3)")
            if not np.all(np.isfinite(np.asarray(p[GSENS_KEY], np.float64))):
                raise ModelError(f"state/gyr/{GSENS_KEY} has a non-finite value")
            if "acc" not in sensors:
                raise ModelError(f"state/gyr/{GSENS_KEY} (g-sensitivity) is applied with the calibrated accelerometer, "
                                 "but the model has no 'acc' calibration")


def gsens_of(state: Mapping[str, Any]) -> np.ndarray | None:
    """The gyroscope g-sensitivity ``G`` (3, 3) ((rad/s)/g, float64) of a linear state, or ``None``.

    Args:
        state: a linear state (``sensor -> {"S", "b"[, "G"]}``).
    """
    p = state.get("gyr")
    if isinstance(p, Mapping) and GSENS_KEY in p:
        return np.asarray(p[GSENS_KEY], np.float64)
    return None


@float64
def apply_linear_state(state: Mapping[str, Any], meta: Mapping[str, Any], rec: Recording) -> dict[str, np.ndarray]:
    """:data:`ApplyFn` of the linear methods: ``x = A (y - b)`` with
    ``A = S^{-1}`` (:meth:`~jaxcal.sensor.LinearCal.from_forward`, eq. 3.5), in float64. A gyroscope
    with a g-sensitivity ``G`` (``state/gyr/G``, (rad/s)/g) is calibrated as
    ``w = A_g (y_g - b_g) - G f`` with ``f = A_a (y_a - b_a)`` the calibrated accelerometer (g) of the
    same sample: the exact inverse of the forward model ``y_g = S_g (w + G f) + b_g`` that
    :mod:`jaxcal.multipos` fits (:func:`jaxcal.multipos.gyro.block_rotvecs`).

    Args:
        state: ``sensor -> {"S", "b"[, "G"]}`` (the forward model of each sensor).
        meta: the model's metadata (unused).
        rec: the recording to calibrate.

    Raises:
        ModelError: the model has ``G`` and the recording (or the model) has no accelerometer.
    """
    out = {}
    for s in SENSORS:
        p = state.get(s)
        y = getattr(rec, s)
        if p is None or y is None:
            continue
        cal = LinearCal.from_forward(affine_state(p))
        out[f"{s}_cal"] = np.asarray(cal.apply(jnp.asarray(y, jnp.float64)))
    G = gsens_of(state)
    if G is not None and "gyr_cal" in out:
        if rec.acc is None:
            raise ModelError("the gyroscope's g-sensitivity (state/gyr/G) needs the recording's 'acc' channel, "
                             "which this recording lacks")
        if "acc_cal" not in out:
            raise ModelError("the gyroscope's g-sensitivity (state/gyr/G) needs the model's 'acc' calibration, "
                             "which it lacks")
        out["gyr_cal"] = out["gyr_cal"] - out["acc_cal"] @ G.T
    return out
