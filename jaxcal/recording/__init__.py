"""IMU recordings: the one in-memory type (:class:`Recording`) and its ``.npz`` / ``.csv`` (+ ``.json``
sidecar) format of CONVENTIONS.md.

A recording is a set of named arrays sharing one sample axis of length ``N``:

=====================  =========  =======================================================
key                    shape      meaning (units)
=====================  =========  =======================================================
``t``                  (N,)       sample times (s), strictly increasing; required
``acc``                (N, 3)     accelerometer output (LSB, or g if ``acc_unit == "g"``)
``gyr``                (N, 3)     gyroscope output (LSB, or rad/s if ``gyr_unit == "rad/s"``)
``temp``               (N,)       temperature (degC)
``seq``                (N,)       integer sequence id; the samples of one id are contiguous
``static``             (N,)       bool, sample known to be stationary
``acc_ref``            (N, 3)     reference specific force (g), body frame
``gyr_ref``            (N, 3)     reference body rate (rad/s)
``pos_ref``            (N, 3)     reference position (m)
``quat_ref``           (N, 4)     reference attitude, Hamilton [w, x, y, z], body to world
``fs``                 scalar     nominal sample rate (Hz)
``acc_lsb_per_g``      () or (3,) datasheet accelerometer scale (LSB/g)
``acc_bias_lsb``       () or (3,) datasheet accelerometer bias (LSB)
``gyr_lsb_per_rads``   () or (3,) datasheet gyroscope scale (LSB/(rad/s))
``gyr_bias_lsb``       () or (3,) datasheet gyroscope bias (LSB)
``acc_unit``           str        ``"LSB"`` (default) or ``"g"``
``gyr_unit``           str        ``"LSB"`` (default) or ``"rad/s"``
``mag``                (N, 3)     magnetometer output (uT)
``ref_valid``          (N,)       bool, the reference pose may be used at this sample (a reader's mark)
``section``            (N,)       integer pose label, index into ``section_names`` (-1: none)
``section_names``      (K,)       str, the names of the labels of ``section``
``gt_t``               (M,)       times (s, on the clock of ``t``) of the original reference pose track
``gt_pos``             (M, 3)     that track's positions (m)
``gt_quat``            (M, 4)     that track's attitudes, Hamilton [w, x, y, z], body to world
``t0``                 scalar     the absolute time of ``t = 0`` (s, e.g. Unix time)
=====================  =========  =======================================================

At least one of ``acc`` and ``gyr`` must be present. A row of NaN in ``acc_ref``, ``gyr_ref``,
``pos_ref`` or ``quat_ref`` marks a reference gap (no reference at that sample); every other
value must be finite. Keys not in this table (format-specific ones such as a reader's ``meta_*``)
are kept in :attr:`Recording.extra` and written back out (never silently dropped).

CSV layout: a header row, then one row per sample, columns ``t, acc_x, acc_y, acc_z, gyr_x,
gyr_y, gyr_z`` then any of ``temp, seq, static, acc_ref_x..z, gyr_ref_x..z, pos_ref_x..z,
quat_ref_w, quat_ref_x, quat_ref_y, quat_ref_z, mag_x..z, ref_valid, section``. Scalar metadata
(``fs``, ``t0``, spec values, units, scalar extras), ``section_names`` and the pose track
``gt_*`` live in a sidecar ``<stem>.json`` next to the ``.csv``. Unknown per-sample columns are
kept as extra arrays (``foo_x, foo_y, foo_z`` as one ``(N, 3)`` array ``foo``).

:class:`Recording` is the only in-memory recording: the readers of foreign formats
(:mod:`jaxcal.readers`) return one, and this package is its one load / save path
(:func:`load_recording`, :func:`save_recording`); all functions take explicit paths. Any problem
with a file raises :class:`RecordingError` whose one-line message names the file, the key or
column, and the row. Besides shapes and types, validation refuses what the data contradict
(:func:`check_plausible`: a declared unit or datasheet scale off by a large factor; an ``fs`` the
spacing of ``t`` does not match). Files are written whole or not at all (:func:`atomic_output`).

One module per reason to change, all re-exported here (``from jaxcal.recording import X``):
:mod:`~jaxcal.recording.types` (:class:`Recording`, the key tables, :class:`RecordingError`),
:mod:`~jaxcal.recording.validate` (:func:`recording_from_dict`, :func:`validate_recording`),
:mod:`~jaxcal.recording.plausibility` (:func:`implausible`, :func:`check_plausible`),
:mod:`~jaxcal.recording.rows` (:func:`take_rows`, :func:`crop`, :func:`sequence_slices`),
:mod:`~jaxcal.recording.calibrated` (:func:`with_calibrated`: the sensors replaced by calibrated output) and
:mod:`~jaxcal.recording.files` (:func:`load_recording`, :func:`save_recording`, :func:`atomic_output`,
:func:`read_npz_arrays`).
"""

from __future__ import annotations

from jaxcal.recording.calibrated import with_calibrated
from jaxcal.recording.files import NPZ_READ_ERRORS, atomic_output, load_recording, read_npz_arrays, save_recording
from jaxcal.recording.plausibility import ACC_NORM_G, GYR_MEDIAN_MAX, GYR_Q99_MAX, check_plausible, implausible
from jaxcal.recording.rows import PER_SAMPLE_FIELDS, crop, sequence_slices, take_rows
from jaxcal.recording.types import ACC_UNITS, GYR_UNITS, KNOWN_KEYS, REF_GAP_KEYS, Recording, RecordingError
from jaxcal.recording.validate import (
    ABS_ZERO_C,
    FS_TOLERANCE,
    MAX_COUNT,
    MAX_TIME,
    MAX_VALUE,
    QUAT_NORM_TOL,
    recording_from_dict,
    validate_recording,
)
from jaxcal.sequences import sequence_bounds as sequence_bounds  # kept importable from here; sequence runs live in jaxcal.sequences

__all__ = [
    "ACC_UNITS",
    "GYR_UNITS",
    "KNOWN_KEYS",
    "REF_GAP_KEYS",
    "NPZ_READ_ERRORS",
    "Recording",
    "RecordingError",
    "load_recording",
    "save_recording",
    "recording_from_dict",
    "validate_recording",
    "crop",
    "sequence_slices",
    "PER_SAMPLE_FIELDS",
    "take_rows",
    "with_calibrated",
    "check_plausible",
    "implausible",
    "atomic_output",
    "read_npz_arrays",
    "MAX_COUNT",
    "MAX_VALUE",
    "MAX_TIME",
    "ABS_ZERO_C",
    "ACC_NORM_G",
    "GYR_MEDIAN_MAX",
    "GYR_Q99_MAX",
    "FS_TOLERANCE",
    "QUAT_NORM_TOL",
]
