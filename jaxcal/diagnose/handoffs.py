"""The typed hand-offs between the stages of one sensor's pass, and the answers a pass returns.

:mod:`jaxcal.diagnose.stages` runs the stages (``linearise`` -> :class:`Linearised`,
``select_effects`` -> :class:`Selection`, ``detectability`` -> :class:`Detectability`,
``name_effects`` -> :class:`Named`) and re-exports these records; ``sensor_pass`` answers
:class:`Relinearise`, :class:`Retrim`, :class:`Unskew` or :class:`DropOffset`, and
``diagnose_sensor`` returns a :class:`SensorResult` per sensor.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxcal.diagnose.refit import RefitResult
from jaxcal.diagnose.select import Decision, System
from jaxcal.diagnose.whiten import ARModel

__all__ = [
    "SensorResult",
    "Linearised",
    "Selection",
    "Detectability",
    "Named",
    "Relinearise",
    "Retrim",
    "Unskew",
    "DropOffset",
]


class SensorResult(NamedTuple):
    """Everything the report needs about one sensor."""

    sensor: str
    selected: list[str]
    decisions: dict
    mds: dict
    warnings: list[str]
    base_all: RefitResult  # baseline fitted on all fit rows
    final_all: RefitResult  # baseline + named effects, joint nonlinear refit on all fit rows
    fit_rows: np.ndarray
    heldout_path: list[float]  # held-out RMS, noise-model (GLS) fits, as effects are added
    heldout_path_ols: list[float]  # the same with least-squares fits on the physical residual
    saturation: dict | None
    tau_lin: float
    ar_orders: list[int]
    ar_sigma: list[float]
    ar_theta: list[float]
    frame_fit: RefitResult | None = None  # the refit whose covariance gives the affine frame split
    bands: dict | None = None  # {effect: band check} of the effects whose intervals were pooled over bands


class Linearised(NamedTuple):
    """Stage 2: the rows fitted (edges trimmed by the offset), the effect parameters and the
    baseline fitted at the linearisation point, and the regressors ``x`` (N, 3, B+Q) of the
    residual ``z`` (N, 3)."""

    fit_rows: np.ndarray
    theta_lin: np.ndarray
    beta: np.ndarray
    x: np.ndarray
    z: np.ndarray


class Selection(NamedTuple):
    """Stage 3: the noise model per axis, the whitened system, the forward selection (names,
    decisions, coefficients ``th`` of columns ``cols``, the full linear step ``full`` and its
    residual), the rows fitted (clipped samples removed) and the saturation test."""

    ars: list[ARModel]
    system: System
    selected: list[str]
    decisions: dict
    th: np.ndarray
    cols: list[int]
    full: np.ndarray
    resid: np.ndarray
    fit_rows: np.ndarray
    saturation: dict | None


class Detectability(NamedTuple):
    """Stage 4: minimum detectable sizes per candidate, their warnings, and the decisions with
    confounding noted."""

    mds: dict
    warnings: list[str]
    decisions: dict


class Named(NamedTuple):
    """Stage 5: the named effects in order, the final decisions and warnings, the baseline and the
    joint refit with standard errors, and the held-out rms paths (GLS and OLS fits)."""

    order: list[str]
    decisions: dict
    warnings: list[str]
    base_all: RefitResult
    final_all: RefitResult
    path: list[float]
    path_ols: list[float]
    bands: dict | None = None


class Relinearise(NamedTuple):
    """A pass's answer: a time offset ``tau`` was named far from the linearisation point; run
    again linearised there (``decision``: its decision)."""

    tau: float
    decision: Decision


class Retrim(NamedTuple):
    """A pass's answer: a clock skew was named whose stretch moves the recording's ends by
    ``shift`` (s) on the reference's clock, a sample or more. Run again linearised at the named skew
    ``skew`` (ppm; ``decision``: its decision): a skew that large leaves a second-order remainder at
    0 (0.04 g rms at 500 ppm over 20 min) that other effects would otherwise absorb (a spurious
    accelerometer ``scale_nonlinearity``) and that inflates the standard errors (15x at 500 ppm
    over 5 min, 1.9 samples). Where the shift passes the rows trimmed for the time offset, those
    rows saw reference times the reference does not hold (the stretch reflects there: errors of up
    to 0.13 g and 0.8 rad/s in the last 8 rows at 500 ppm over 20 min); the run leaves them out."""

    shift: float
    skew: float = 0.0
    decision: Decision | None = None


class Unskew(NamedTuple):
    """A pass's answer: the clock skew at which it was linearised did not keep the promise (or was
    not named); run again linearised at 0, its end rows still trimmed, and let that pass decide."""


class DropOffset(NamedTuple):
    """A pass's answer: the time offset did not lower the held-out rms; run again without it and
    report ``decision`` and ``warning``."""

    decision: Decision
    warning: str
