"""What the model exports and imports share: the applied form ``x = A @ (y - b)`` of a linear model.

Export side: which models are linear (:func:`linear_methods`), their ``LinearCal`` per sensor
(:func:`linear_cals`, computed as ``jaxcal apply`` computes it), the gyro g-sensitivity ``G``
(:func:`g_sensitivity`), the physical-unit form Kalibr and OpenVINS use (:func:`physical_cals`) and
the triangular x rotation split both need (:func:`lower_times_rotation`). Import side: checked
matrices and rotations read from a parsed document (:func:`matrix`, :func:`rotation`, :func:`inv`,
one-line :class:`~jaxcal.methods.ModelError` otherwise), the parsers of JSON text
(:func:`parse_json`), and the ``linear`` model an import builds (:func:`imported_model`).

Gyro g-sensitivity: a linear model's gyroscope may hold ``G`` (3x3, (rad/s)/g, ``state/gyr/G``),
applied as ``w = A_g (y_g - b_g) - G f`` with ``f = A_a (y_a - b_a)`` the calibrated accelerometer
(g) of the same sample; its forward model is ``y_g = S_g (w + G f) + b_g``. Every export writes it in
the format's own term and each import reads it back.

Pure functions, no I/O.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np
from jaxtyping import Float

from jaxcal import methods
from jaxcal.arrays import Array
from jaxcal.constants import G0, PHYS_UNIT
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.methods.base import GSENS_KEY, MAX_CONDITION, apply_linear_state, check_linear_state, gsens_of, linear_cal_of_state
from jaxcal.sensor import LinearCal

__all__ = [
    "EQUATION",
    "EQUATION_GSENS",
    "IMU_SENSORS",
    "ROTATION_TOL",
    "g_sensitivity",
    "gsens_forward",
    "imported_model",
    "inv",
    "is_linear",
    "keep_gsens",
    "linear_cals",
    "linear_methods",
    "lower_times_rotation",
    "matrix",
    "model_units",
    "parse_json",
    "physical_cals",
    "rotation",
    "rows",
]

EQUATION = "x = A @ (y - b)"
"""The applied form both exports write out (``A`` multiplies the column vector ``y - b``)."""

EQUATION_GSENS = "x_gyr = A_gyr @ (y_gyr - b_gyr) - G @ x_acc"
"""The gyroscope's applied form when the model has a g-sensitivity ``G`` ((rad/s)/g; ``x_acc`` in g)."""


def linear_methods() -> tuple[str, ...]:
    """The registered methods whose models are linear (their ``apply`` is ``apply_linear_state``)."""
    return tuple(n for n, m in methods.REGISTRY.items() if m.apply is apply_linear_state)


def is_linear(model: CalibrationModel) -> bool:
    """Whether ``model``'s method stores a linear (affine) calibration per sensor."""
    return model.method in linear_methods()


def linear_cals(model: CalibrationModel) -> dict[str, LinearCal]:
    """``sensor -> LinearCal`` (numpy float64 ``A``, ``b``) of a linear model, in ``model.sensors`` order.

    ``A = S^{-1}`` is computed exactly as ``jaxcal apply`` computes it
    (:func:`~jaxcal.methods.base.linear_cal_of_state`, float64).

    Args:
        model: a fitted or loaded :class:`~jaxcal.methods.CalibrationModel`.

    Raises:
        ModelError: the model is not linear (one line naming the methods that are).
    """
    if not is_linear(model):
        raise ModelError(
            f"model of method '{model.method}' is not linear: jaxcal's exports hold one affine "
            f"calibration {EQUATION} per sensor, which only the methods {', '.join(linear_methods())} fit"
        )
    return {s: linear_cal_of_state(model.state[s]) for s in model.sensors}


def g_sensitivity(model: CalibrationModel) -> np.ndarray | None:
    """The gyroscope g-sensitivity ``G`` (3, 3), (rad/s)/g, of a linear model, or ``None`` when it has none.

    Args:
        model: a fitted or loaded :class:`~jaxcal.methods.CalibrationModel`.
    """
    return gsens_of(model.state) if is_linear(model) else None


def model_units(model: CalibrationModel, sensor: str) -> tuple[str | None, str]:
    """(input unit at fit time or ``None`` if the model does not say, output unit)."""
    units = model.meta.get("units", {})
    unit = units.get(sensor) if isinstance(units, Mapping) else None
    return (unit if isinstance(unit, str) else None), PHYS_UNIT[sensor]


IMU_SENSORS = ("acc", "gyr")


def lower_times_rotation(X: Float[Array, "3 3"]) -> tuple[np.ndarray, np.ndarray]:
    """``X = T @ C`` with ``T`` lower triangular and ``C`` a rotation (orthonormal, det +1).

    From the QR decomposition of ``X.T = Q R``: ``X = R.T @ Q.T``, ``T = R.T``, ``C = Q.T``. Signs are
    chosen so that ``T``'s diagonal is positive; when ``det X < 0`` a rotation cannot absorb the
    reflection and ``T[2, 2]`` is negative instead.

    Args:
        X: an invertible 3x3 matrix.

    Raises:
        ModelError: ``X`` is singular or not finite.
    """
    X = np.asarray(X, np.float64)
    if X.shape != (3, 3) or not np.all(np.isfinite(X)) or abs(np.linalg.det(X)) < 1e-300:
        raise ModelError("a singular or non-finite calibration matrix cannot be written as triangular x rotation")
    Q, R = np.linalg.qr(X.T)
    d = np.where(np.diag(R) < 0, -1.0, 1.0)
    Q, R = Q * d, d[:, None] * R  # Q D, D R: same product, R's diagonal positive
    if np.linalg.det(Q) < 0:
        Q[:, 2], R[2, :] = -Q[:, 2], -R[2, :]
    T, C = np.tril(R.T), Q.T  # R is upper triangular; tril drops QR's exact zeros only
    return T, C


def physical_cals(model: CalibrationModel) -> dict[str, LinearCal]:
    """``acc``, ``gyr`` -> ``LinearCal`` with ``x = A (y - b)`` in m/s^2 and rad/s (Kalibr's, OpenVINS's units).

    ``y`` and ``b`` stay in the model's input unit; the accelerometer's ``A`` is jaxcal's times
    :data:`~jaxcal.constants.G0` (g -> m/s^2).

    Args:
        model: a linear model with both sensors.

    Raises:
        ModelError: the model is not linear or lacks ``acc`` or ``gyr``.
    """
    cals = linear_cals(model)
    missing = [s for s in IMU_SENSORS if s not in cals]
    if missing:
        raise ModelError(f"the kalibr and openvins exports describe a 6-axis IMU, but the model has no "
                         f"{' or '.join(missing)} calibration (sensors: {', '.join(model.sensors)})")
    scale = {"acc": G0, "gyr": 1.0}
    return {s: LinearCal(cals[s].A * scale[s], cals[s].b) for s in IMU_SENSORS}


def rows(M: np.ndarray) -> list[list[float]]:
    """A matrix as a list of rows of Python floats (how every file writes one)."""
    return [[float(v) for v in row] for row in np.asarray(M, np.float64)]



def gsens_forward(model: CalibrationModel, S_g: np.ndarray) -> np.ndarray:
    """OpenVINS's ``Tg`` / imucal's ``K_ga``: ``S_g G / G0`` (input unit per m/s^2; zero without ``G``)."""
    G = g_sensitivity(model)
    return np.zeros((3, 3)) if G is None else S_g @ G / G0


def matrix(d: Any, key: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """``d[key]`` as a finite float64 array of ``shape`` (one-line :class:`ModelError` otherwise)."""
    if not isinstance(d, Mapping) or key not in d or d[key] is None:
        raise ModelError(f"{where}: no {key}")
    v = d[key]
    if isinstance(v, (list, tuple)) and not _list_shape(v, shape):  # before any allocation
        got = _outer_shape(v)
        if got != shape:
            raise ModelError(f"{where}: {key} has shape {got}, expected {shape}")
        raise ModelError(f"{where}: {key} is not a {'x'.join(map(str, shape))} array of numbers (ragged rows)")
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise ModelError(f"{where}: {key} is not a {'x'.join(map(str, shape))} array of numbers") from None
    if a.shape != shape:
        raise ModelError(f"{where}: {key} has shape {a.shape}, expected {shape}")
    if not np.all(np.isfinite(a)):
        raise ModelError(f"{where}: {key} has a non-finite value")
    return a


ROTATION_TOL = 1e-6  # |R R^T - I| and |det R - 1| of a matrix a format defines as a rotation


def rotation(R: np.ndarray, key: str, where: str) -> np.ndarray:
    """``R`` if it is a rotation (orthonormal, determinant +1, within :data:`ROTATION_TOL`); a one-line
    :class:`ModelError` otherwise (a scaled one would change the sensor's scale, a reflection would
    make a left-handed frame)."""
    err = float(np.max(np.abs(R @ R.T - np.eye(3))))
    det = float(np.linalg.det(R))
    if err > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
        what = ("a reflection (determinant -1: a left-handed frame)" if det < 0 else
                f"not orthonormal (|R R^T - I| = {err:.3g}, determinant {det:.6g})")
        raise ModelError(f"{where}: {key} must be a rotation, but it is {what}")
    return R


def _list_shape(v: Any, shape: tuple[int, ...]) -> bool:
    """Whether nested lists ``v`` have exactly ``shape`` (checked before any array is built)."""
    if not shape:
        return not isinstance(v, (list, tuple, Mapping))
    return isinstance(v, (list, tuple)) and len(v) == shape[0] and all(_list_shape(x, shape[1:]) for x in v)


def _outer_shape(v: Any) -> tuple[int, ...]:
    """The shape of nested lists read along their first elements (no array built)."""
    out = []
    while isinstance(v, (list, tuple)):
        out.append(len(v))
        v = v[0] if v else None
    return tuple(out)


def inv(M: np.ndarray, what: str, where: str) -> np.ndarray:
    """``M^{-1}``, or a one-line :class:`ModelError` when ``M`` is singular."""
    cond = np.linalg.cond(M)
    if not np.isfinite(cond) or cond > MAX_CONDITION:
        raise ModelError(f"{where}: {what} is singular (condition number {cond:.3g})")
    return np.linalg.inv(M)


def keep_gsens(M: np.ndarray, name: str, where: str, drop: bool, notes: list[str]) -> bool:
    """Whether to import a gyro g-sensitivity matrix ``M``: ``False`` when it is zero, or non-zero and
    dropped (``drop``, with a note)."""
    if not np.any(M):
        return False
    if drop:
        notes.append(f"dropped the gyroscope g-sensitivity {name} (max |{name}| = {float(np.max(np.abs(M))):.3g})")
        return False
    return True


def imported_model(fwd: Mapping[str, tuple[np.ndarray, np.ndarray]], units: Mapping[str, str],
                  source: Mapping[str, Any], G: np.ndarray | None = None) -> CalibrationModel:
    """A ``linear`` model from forward ``(S, b)`` per sensor (jaxcal units) and an optional gyro
    g-sensitivity ``G`` ((rad/s)/g), checked as ``load_model`` would."""
    state = {s: {"S": np.asarray(S, np.float64), "b": np.asarray(b, np.float64)} for s, (S, b) in fwd.items()}
    if G is not None:
        state["gyr"][GSENS_KEY] = np.asarray(G, np.float64)
    meta = {"units": dict(units), "imported_from": dict(source)}
    check_linear_state(state, meta, tuple(state))
    return CalibrationModel("linear", tuple(state), state, meta)


def parse_json(text: str) -> Any:
    """The parsed JSON of an import file's text.

    Raises:
        ModelError: text that does not parse (one line).
    """
    try:
        return json.loads(text)
    except ValueError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ModelError(f"not valid JSON ({first})") from None
