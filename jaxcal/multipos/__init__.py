"""Multi-position self-calibration (Tedaldi, Pretto, Menegatti, ICRA 2014; the imu_tk method).

No labels and no datasheet values are needed: the user holds the IMU still in many orientations
and turns it by hand in between.

* **Accelerometer** (from the static poses): ``f = A (y - b)`` with ``|f| = 1 g`` in every pose.
  ``model="9"`` is imu_tk's 9 parameters, ``A = T diag(k)`` with ``T`` unit lower-triangular
  (3 non-orthogonality terms), 3 scales, 3 biases. ``model="12"`` frees all of ``A`` (12
  parameters); the ``|f|`` residual is blind to a rotation ``A -> Q A`` (3 gauge directions), so
  the antisymmetric part of ``A`` is pinned by a residual ``A - A^T``, which costs nothing at the
  optimum. The two therefore reach the same ``|f|`` fit: they differ in the frame they report.
* **Gyroscope** (from the motions between poses): ``w = G (y_g - b_g) [- G_s f]`` with a full
  ``G`` (9 parameters: scales and misalignment w.r.t. the accelerometer frame), the bias ``b_g``
  from the static intervals, and optionally the g-sensitivity ``G_s`` (9 more). The rates are
  integrated between consecutive static poses, ``R = prod_n Exp(w_n dt_n)`` (midpoint rate,
  uneven ``dt`` kept; samples are grouped in blocks whose rotation vector is the second-order
  Magnus sum, precomputed once from the raw data, see :class:`MultiposData`; blocks of 8 barely change
  the Xsens angles against the per-sample product, ``block=1``), and under the physical convention (``CONVENTIONS.md``) the gravity
  direction measured in pose ``j`` must be carried onto pose ``j + 1``: ``R^T u_j = u_{j+1}``.

Optional extra gyro rows: sections of known rotation (:class:`KnownRotations`, e.g. a closed
turn, ``R_known = I``) and whole turns about the vertical (:class:`VerticalTurns`, e.g. the IMU
turned flat on a table, as in Ferraris' protocol, but unlabelled: the turning axis is the gravity
direction the calibrated accelerometer measures at the rests next to the turn).

Everything is initialised from the data: the accelerometer from an axis-aligned ellipsoid fit of
the pose means (fallback: per-axis min/max), the gyro scale from a grid search over
``G = s I`` (both signs, 1e-7 .. 10 unit/LSB) of the same residual. Both fits are
``optimistix.LevenbergMarquardt`` least squares on pure residual functions, run in float64 and
vmappable over per-pose / per-transition weights (used for leave-poses-out folds).

Modules, in the order data flows through them (the user path is re-exported here; internals such
as the residual functions and their argument types stay in their modules):

* ``data``: :func:`prepare` (numpy: a recording plus static intervals to padded block sums),
  :func:`prepare_known`, :func:`prepare_turns`; :func:`~jaxcal.multipos.data.calibrated_acc_sums`
  and :data:`OBSERVABLE_TOL`, shared by the later stages;
* ``acc``: :func:`fit_acc`, :func:`fit_acc_determined`, :class:`DatasheetPrior`
  (:class:`~jaxcal.multipos.acc.AccArgs`, :func:`~jaxcal.multipos.acc.acc_residuals`);
* ``gyro``: the gyro residuals and scores (:class:`~jaxcal.multipos.gyro.GyroArgs`,
  :func:`~jaxcal.multipos.gyro.gyr_residuals`, :func:`gyro_angle_errors`; :func:`rest_gsens`: bias and
  g-sensitivity jointly from the rests);
* ``fit``: :func:`fit_prepared` (pure JAX, vmappable over weights; :data:`fit_prepared_jit`),
  :func:`fit_multipos`;
* ``observe``: :func:`observability`, :func:`check_observable`;
* ``detect``: :func:`fit_multipos_recording` (interval detection with imu_tk's threshold scan,
  :class:`DetectOptions`, then the fit and its checks, observability and :func:`check_turns` for
  given turns; applied :class:`~jaxcal.sensor.LinearCal` pairs for
  ``jaxcal calibrate --method multipos``);
* ``heldout``: :func:`leave_poses_out`, :func:`jackknife_sd` (the biases' standard errors from its folds);
* ``timesplit``: a held-out time split of a continuous Ferraris session (:func:`time_split`), fair
  to a labelled tool such as imucal and to multipos.

Calibrations are :class:`~jaxcal.sensor.LinearCal` (applied direction ``x = A (y - b)``).
"""

from __future__ import annotations

from jaxcal.multipos.acc import MPU6050_PRIOR, DatasheetPrior, acc_norm_errors, fit_acc, fit_acc_determined
from jaxcal.multipos.data import (
    OBSERVABLE_TOL,
    KnownRotations,
    MultiposData,
    VerticalTurns,
    prepare,
    prepare_known,
    prepare_turns,
    turns_from_times,
)
from jaxcal.multipos.detect import (
    DetectOptions,
    check_turns,
    detect_and_fit,
    detect_rests,
    fit_multipos_recording,
    fit_multipos_recording_gsens,
    fit_summary,
    rest_design_sv,
)
from jaxcal.multipos.fit import MultiposConfig, MultiposFit, fit_multipos, fit_prepared, fit_prepared_jit, fit_prepared_numpy
from jaxcal.multipos.gyro import (
    block_rotvecs,
    carry_rotation,
    gyro_angle_errors,
    gyro_angle_errors_jit,
    known_rotation_errors,
    rest_gsens,
    vertical_turn_errors,
)
from jaxcal.multipos.heldout import HeldOut, fold_batch, fold_ids, jackknife_sd, leave_poses_out
from jaxcal.multipos.observe import Observability, check_observable, observability
from jaxcal.multipos.timesplit import (
    FERRARIS_FACES,
    FERRARIS_TURNS,
    TimeSplit,
    gyro_folds,
    peer_sections,
    split_samples,
    time_split,
    whole_sections,
)

__all__ = [
    # data
    "MultiposData", "KnownRotations", "VerticalTurns", "prepare", "prepare_known", "prepare_turns",
    "turns_from_times", "OBSERVABLE_TOL",
    # fits and configuration
    "MultiposConfig", "MultiposFit", "DatasheetPrior", "MPU6050_PRIOR", "fit_prepared", "fit_prepared_jit", "fit_prepared_numpy",
    "fit_multipos", "fit_acc", "fit_acc_determined", "rest_gsens",
    # recordings
    "DetectOptions", "detect_and_fit", "detect_rests", "fit_multipos_recording", "fit_multipos_recording_gsens", "fit_summary",
    "check_turns", "rest_design_sv",
    # what the poses determine
    "Observability", "observability", "check_observable",
    # scores
    "acc_norm_errors", "gyro_angle_errors", "gyro_angle_errors_jit", "known_rotation_errors", "vertical_turn_errors",
    "block_rotvecs", "carry_rotation",
    # held-out
    "HeldOut", "fold_batch", "fold_ids", "jackknife_sd", "leave_poses_out",
    "FERRARIS_FACES", "FERRARIS_TURNS", "TimeSplit", "time_split", "whole_sections", "peer_sections",
    "gyro_folds", "split_samples",
]
