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
(:mod:`jaxcal.readers`) return one, and this module is its one load / save path
(:func:`load_recording`, :func:`save_recording`); all functions take explicit paths. Any problem
with a file raises :class:`RecordingError` whose one-line message names the file, the key or
column, and the row. Besides shapes and types, validation refuses what the data contradict
(:func:`check_plausible`: a declared unit or datasheet scale off by a large factor; an ``fs`` the
spacing of ``t`` does not match). Files are written whole or not at all (:func:`atomic_output`).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import math
import os
import secrets
import zipfile
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.constants import PHYS_UNIT, SENSORS
from jaxcal.sequences import first_repeated_run, sequence_bounds  # sequence_bounds re-exported: sequence runs live in jaxcal.sequences

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
    "sequence_slices",
    "PER_SAMPLE_FIELDS",
    "take_rows",
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

ACC_UNITS = ("LSB", PHYS_UNIT["acc"])
GYR_UNITS = ("LSB", PHYS_UNIT["gyr"])

# Per-sample arrays: name -> trailing shape (() for (N,)) and CSV component suffixes.
_VECTOR_KEYS: dict[str, tuple[str, ...]] = {
    "acc": ("x", "y", "z"),
    "gyr": ("x", "y", "z"),
    "acc_ref": ("x", "y", "z"),
    "gyr_ref": ("x", "y", "z"),
    "pos_ref": ("x", "y", "z"),
    "quat_ref": ("w", "x", "y", "z"),
    "mag": ("x", "y", "z"),
}
# Reference keys: a row of NaN marks a reference gap ("no reference here"); inf is never allowed.
REF_GAP_KEYS = ("acc_ref", "gyr_ref", "pos_ref", "quat_ref")
_SAMPLE_SCALAR_KEYS = ("temp", "seq", "static", "ref_valid", "section")
_FLAG_KEYS = ("static", "ref_valid")  # per-sample booleans (or 0/1)
_ID_KEYS = {"seq": "sequence id", "section": "section label"}  # per-sample integers
_META_SCALAR_KEYS = ("fs", "t0")
_META_SPEC_KEYS = ("acc_lsb_per_g", "acc_bias_lsb", "gyr_lsb_per_rads", "gyr_bias_lsb")
_UNIT_KEYS = ("acc_unit", "gyr_unit")
_NAME_KEYS = ("section_names",)
# The original reference pose track (its own length M): name -> trailing shape.
_TRACK_KEYS: dict[str, tuple[int, ...]] = {"gt_t": (), "gt_pos": (3,), "gt_quat": (4,)}
# Column order of a written CSV; the sidecar holds the rest.
_CSV_ORDER = ("t", "acc", "gyr", "temp", "seq", "static", "acc_ref", "gyr_ref", "pos_ref", "quat_ref",
              "mag", "ref_valid", "section")
_SIDECAR_KEYS = _META_SCALAR_KEYS + _META_SPEC_KEYS + _NAME_KEYS + tuple(_TRACK_KEYS)

KNOWN_KEYS = (
    ("t",) + tuple(_VECTOR_KEYS) + _SAMPLE_SCALAR_KEYS + _META_SCALAR_KEYS + _META_SPEC_KEYS + _UNIT_KEYS
    + _NAME_KEYS + tuple(_TRACK_KEYS)
)
"""Every key with a :class:`Recording` field (all others go to :attr:`Recording.extra`)."""


class RecordingError(ValueError):
    """A recording file or object is invalid; the message is one line saying what and where."""


@dataclass(frozen=True, eq=False)
class Recording:
    """One IMU recording, the only in-memory recording of jaxcal (numpy arrays; absent optional
    fields are ``None``). Shapes and units as in the module docstring (CONVENTIONS.md).

    Construct directly (then call :func:`validate_recording`), with :func:`recording_from_dict`,
    :func:`load_recording` or a reader (:func:`jaxcal.readers.read`).

    Args:
        t: (N,) sample times (s), strictly increasing; required.
        acc: (N, 3) accelerometer output, in ``acc_unit``.
        gyr: (N, 3) gyroscope output, in ``gyr_unit``.
        temp: (N,) sensor temperature (degC).
        seq: (N,) integer sequence id; the samples of one id are contiguous.
        static: (N,) bool, sample known to be stationary.
        acc_ref: (N, 3) reference specific force (g), body frame; a NaN row is a reference gap.
        gyr_ref: (N, 3) reference body rate (rad/s); a NaN row is a reference gap.
        pos_ref: (N, 3) reference position (m); a NaN row is a reference gap.
        quat_ref: (N, 4) reference attitude, Hamilton [w, x, y, z], body to world; NaN row = gap.
        fs: nominal sample rate (Hz).
        acc_lsb_per_g: () or (3,) datasheet accelerometer scale (LSB/g).
        acc_bias_lsb: () or (3,) datasheet accelerometer bias (LSB).
        gyr_lsb_per_rads: () or (3,) datasheet gyroscope scale (LSB/(rad/s)).
        gyr_bias_lsb: () or (3,) datasheet gyroscope bias (LSB).
        acc_unit: ``"LSB"`` (raw counts, default) or ``"g"``.
        gyr_unit: ``"LSB"`` (raw counts, default) or ``"rad/s"``.
        mag: (N, 3) magnetometer output (uT).
        ref_valid: (N,) bool, where the reference pose may be used (a reader's mark of track gaps).
        section: (N,) integer pose label, index into ``section_names`` (-1: no label).
        section_names: (K,) str, the name of each ``section`` label.
        gt_t: (M,) times (s, clock of ``t``) of the original reference pose track, increasing.
        gt_pos: (M, 3) positions (m) of that track.
        gt_quat: (M, 4) attitudes of that track, Hamilton [w, x, y, z], body to world.
        t0: absolute time (s, e.g. Unix time) of ``t = 0``.
        extra: any other named arrays (format-specific, e.g. ``meta_*``); kept and written back.
    """

    t: np.ndarray
    acc: np.ndarray | None = None
    gyr: np.ndarray | None = None
    temp: np.ndarray | None = None
    seq: np.ndarray | None = None
    static: np.ndarray | None = None
    acc_ref: np.ndarray | None = None
    gyr_ref: np.ndarray | None = None
    pos_ref: np.ndarray | None = None
    quat_ref: np.ndarray | None = None
    fs: float | None = None
    acc_lsb_per_g: np.ndarray | None = None
    acc_bias_lsb: np.ndarray | None = None
    gyr_lsb_per_rads: np.ndarray | None = None
    gyr_bias_lsb: np.ndarray | None = None
    acc_unit: str = "LSB"
    gyr_unit: str = "LSB"
    mag: np.ndarray | None = None
    ref_valid: np.ndarray | None = None
    section: np.ndarray | None = None
    section_names: np.ndarray | None = None
    gt_t: np.ndarray | None = None
    gt_pos: np.ndarray | None = None
    gt_quat: np.ndarray | None = None
    t0: float | None = None
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)

    @property
    def n(self) -> int:
        """Number of samples ``N``."""
        return int(np.shape(self.t)[0])

    def sensors(self) -> tuple[str, ...]:
        """The sensors present, in the order ``("acc", "gyr")``."""
        return tuple(s for s in SENSORS if getattr(self, s) is not None)

    def replace(self, **changes: Any) -> "Recording":
        """A copy with some fields replaced (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """All present fields (and extras) as a flat ``name -> value`` dict."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            if f.name == "extra":
                continue
            v = getattr(self, f.name)
            if v is not None:
                out[f.name] = v
        out.update(self.extra)
        return out


# ----------------------------------------------------------------------------- construction


def _fail(source: str, msg: str) -> RecordingError:
    text = f"{source}: {msg}" if source else msg
    return RecordingError(" ".join(text.split("\n")))


def _as_str(v: Any) -> str:
    a = np.asarray(v)
    if a.shape != ():
        raise TypeError("not a scalar string")
    return str(a.item())


def recording_from_dict(d: Mapping[str, Any], source: str = "", *, csv_rows: bool = False) -> Recording:
    """Build and validate a :class:`Recording` from a ``name -> array`` mapping.

    Known names (:data:`KNOWN_KEYS`) go to their fields; unknown ones to ``extra``. Unsigned-integer
    arrays of known keys become ``int64`` (so no later subtraction wraps around).

    Args:
        d: ``name -> array`` (or scalar / unit string) with CONVENTIONS.md names.
        source: file name (or other label) put in front of an error message.
        csv_rows: give CSV line numbers in error messages (see :func:`validate_recording`).

    Raises:
        RecordingError: the mapping is not a valid recording (one line: what and where).
    """
    kw: dict[str, Any] = {}
    extra: dict[str, np.ndarray] = {}
    for k, v in d.items():
        if k in _UNIT_KEYS:
            try:
                kw[k] = _as_str(v)
            except TypeError:
                raise _fail(source, f"key '{k}': expected a unit string, got shape {np.shape(v)}") from None
        elif k in _META_SCALAR_KEYS:
            kw[k] = _meta_scalar(source, k, v)
        elif k in KNOWN_KEYS:
            kw[k] = _signed(source, k, np.asarray(v))
        else:
            extra[k] = np.asarray(v)
    if "t" not in kw:
        raise _fail(source, "missing required key 't' (sample times in s)")
    rec = Recording(**kw, extra=extra)
    validate_recording(rec, source, csv_rows=csv_rows)
    return rec


_META_SCALAR_WHAT = {"fs": "a scalar sample rate in Hz", "t0": "a scalar time in s"}


def _meta_scalar(source: str, name: str, v: Any) -> float:
    """``fs`` or ``t0`` as a float; a real number is required (no string, bool or complex)."""
    a = np.asarray(v)
    if a.shape != () or not _is_real(a.dtype):
        raise _fail(source, f"key '{name}': expected {_META_SCALAR_WHAT[name]}, got {a.dtype} of shape {a.shape}")
    return float(a)


def _signed(source: str, name: str, a: np.ndarray) -> np.ndarray:
    """Unsigned integers as ``int64`` (values kept); ``uint64`` beyond ``int64`` is refused."""
    if a.dtype.kind != "u":
        return a
    if a.size and a.max() > np.iinfo(np.int64).max:
        raise _fail(source, f"key '{name}': unsigned value {a.max()} does not fit a signed 64-bit integer")
    return a.astype(np.int64)


# ----------------------------------------------------------------------------- validation

# What a recording may hold (CONVENTIONS.md, "What is refused").
MAX_COUNT = 2.0**32  # raw counts (LSB) beyond 32 bits are no ADC's output
MAX_VALUE = 1e9  # any other per-sample value (g, rad/s, m, degC, ...)
MAX_TIME = 1e12  # s (Unix seconds are 1.7e9)
ABS_ZERO_C = -273.15
ACC_NORM_G = (0.25, 4.0)  # median |f| of a resting or hand-held accelerometer, g
GYR_MEDIAN_MAX = 20.0  # rad/s (1150 deg/s): a median rate above this is a unit error
GYR_Q99_MAX = 35.0  # rad/s (2000 deg/s, the largest common full scale)
FS_TOLERANCE = 0.25  # relative mismatch allowed between fs and the spacing of t (jittered clocks)
QUAT_NORM_TOL = 0.01


def _row_text(i: int, csv_rows: bool) -> str:
    return f"row {i} (line {i + 2})" if csv_rows else f"row {i}"


def _is_real(dtype: np.dtype) -> bool:
    """Real numbers: integers and floats (not bool, complex, strings, objects, datetimes)."""
    return dtype.kind in "iuf"


def _check_numeric(source: str, name: str, a: np.ndarray, *, allow_bool: bool = False) -> None:
    if _is_real(a.dtype) or (allow_bool and a.dtype == np.bool_):
        return
    kind = {"b": "booleans", "c": "complex numbers"}.get(a.dtype.kind, f"dtype {a.dtype}")
    raise _fail(source, f"key '{name}': expected real numbers, got {kind}")


def validate_recording(rec: Recording, source: str = "", *, csv_rows: bool = False) -> None:
    """Check a recording against CONVENTIONS.md; raise :class:`RecordingError` on the first problem.

    Checks: ``t`` present, 1-D, finite, strictly increasing; ``acc`` or ``gyr`` present; every
    per-sample key has ``N`` rows and the right trailing shape, real numbers (``static`` and
    ``ref_valid`` may be boolean), finite and of plausible size (raw counts within 32 bits), except
    that a whole row of NaN in a reference key (:data:`REF_GAP_KEYS`) marks a reference gap; units
    known; ``seq`` integer-valued with contiguous ids; ``section`` integer-valued, naming an entry of
    ``section_names`` (1-D strings) where both are given; ``static`` and ``ref_valid`` boolean;
    ``quat_ref`` of unit norm (gap rows skipped); the pose track ``gt_t`` 1-D, finite, strictly
    increasing, with ``gt_pos`` / ``gt_quat`` of matching length and finite; metadata scalar or
    (3,), finite, scales positive, ``fs`` positive and matching the spacing of ``t``, ``t0``
    finite; no extra named like a field; and the declared units plausible (:func:`check_plausible`).

    Args:
        rec: the recording.
        source: file name (or other label) put in front of the message.
        csv_rows: also give the CSV line number (header = line 1) next to each row index.
    """
    n = _validate_time(rec, source, csv_rows)
    if rec.acc is None and rec.gyr is None:
        raise _fail(source, "neither 'acc' nor 'gyr' present: a recording needs at least one sensor")
    _validate_units(rec, source)
    for name, comps in _VECTOR_KEYS.items():
        _validate_per_sample(rec, name, (len(comps),), n, source, csv_rows)
    for name in _SAMPLE_SCALAR_KEYS:
        _validate_per_sample(rec, name, (), n, source, csv_rows)
    _validate_seq_static(rec, source, csv_rows)
    _validate_quaternions(rec, source, csv_rows)
    _validate_names(rec, source, csv_rows)
    _validate_track(rec, source)
    _validate_meta(rec, source)
    _validate_extra(rec, source)
    _validate_fs(rec, source)
    check_plausible(rec, source)


def _validate_time(rec: Recording, source: str, csv_rows: bool) -> int:
    """``t``: 1-D real, non-empty, finite, within :data:`MAX_TIME`, strictly increasing; returns N."""
    if rec.t is None:
        raise _fail(source, "missing required key 't' (sample times in s)")
    t = np.asarray(rec.t)
    _check_numeric(source, "t", t)
    if t.ndim != 1:
        raise _fail(source, f"key 't': expected shape (N,), got {t.shape}")
    if t.shape[0] == 0:
        raise _fail(source, "key 't': recording has no samples")
    tf = t.astype(np.float64)  # differences of integer times must not wrap around
    bad = np.flatnonzero(~np.isfinite(tf))
    if bad.size:
        raise _fail(source, f"key 't' {_row_text(int(bad[0]), csv_rows)}: non-finite value {t[bad[0]]}")
    big = np.flatnonzero(np.abs(tf) > MAX_TIME)
    if big.size:
        i = int(big[0])
        raise _fail(source, f"key 't' {_row_text(i, csv_rows)}: time {tf[i]:.4g} s is implausibly large (t is in seconds)")
    dec = np.flatnonzero(np.diff(tf) <= 0)
    if dec.size:
        i = int(dec[0]) + 1
        raise _fail(
            source,
            f"key 't' {_row_text(i, csv_rows)}: times not strictly increasing "
            f"(t[{i - 1}] = {tf[i - 1]:.10g}, t[{i}] = {tf[i]:.10g})",
        )
    return int(t.shape[0])


def _validate_units(rec: Recording, source: str) -> None:
    if rec.acc_unit not in ACC_UNITS:
        raise _fail(source, f"key 'acc_unit': unknown unit {rec.acc_unit!r} (expected one of {', '.join(ACC_UNITS)})")
    if rec.gyr_unit not in GYR_UNITS:
        raise _fail(source, f"key 'gyr_unit': unknown unit {rec.gyr_unit!r} (expected one of {', '.join(GYR_UNITS)})")


def _cell_label(name: str, comp: int | np.integer | None, csv_rows: bool) -> str:
    if comp is not None and csv_rows:
        return f"column '{name}_{_VECTOR_KEYS[name][comp]}'"
    if comp is not None:
        return f"key '{name}' column {comp}"
    return f"{'column' if csv_rows else 'key'} '{name}'"


def _value_limits(rec: Recording, name: str) -> tuple[float, float, str]:
    """``(low, high, what)``: the range a per-sample key's values must lie in, and why."""
    if name in ("acc", "gyr") and getattr(rec, f"{name}_unit") == "LSB":
        return -MAX_COUNT, MAX_COUNT, "raw counts beyond 32 bits"
    if name == "temp":
        return ABS_ZERO_C, MAX_VALUE, "a temperature below absolute zero or implausibly large"
    if name in _ID_KEYS:
        return -(2.0**53), 2.0**53, f"a {_ID_KEYS[name]} beyond 2**53"
    return -MAX_VALUE, MAX_VALUE, f"implausibly large (beyond {MAX_VALUE:.0e})"


def _validate_per_sample(rec: Recording, name: str, trailing: tuple[int, ...], n: int, source: str,
                         csv_rows: bool) -> None:
    """One per-sample key: real numbers, shape ``(N,) + trailing``, finite, within :func:`_value_limits`."""
    v = getattr(rec, name)
    if v is None:
        return
    a = np.asarray(v)
    _check_numeric(source, name, a, allow_bool=name in _FLAG_KEYS)
    want = "(N,)" if not trailing else f"(N, {trailing[0]})"
    if a.ndim != 1 + len(trailing) or a.shape[1:] != trailing:
        raise _fail(source, f"key '{name}': expected shape {want}, got {a.shape}")
    if a.shape[0] != n:
        raise _fail(source, f"key '{name}': length {a.shape[0]} does not match len(t) = {n}")
    af = a.astype(np.float64)
    fin = np.isfinite(af)
    if name in REF_GAP_KEYS:  # a whole row of NaN is a reference gap
        fin |= np.isnan(af).all(axis=1, keepdims=True)
    if not fin.all():
        i, *rest = np.argwhere(~fin)[0]
        why = "non-finite value"
        if name in REF_GAP_KEYS and np.isnan(af[(i, *rest)]):
            why += " (NaN in part of the row; a reference gap is a whole row of NaN)"
        raise _fail(source, f"{_cell_label(name, rest[0] if rest else None, csv_rows)} {_row_text(int(i), csv_rows)}: "
                            f"{why}")
    lo, hi, what = _value_limits(rec, name)
    out = (af < lo) | (af > hi)
    if out.any():
        i, *rest = np.argwhere(out)[0]
        raise _fail(source, f"{_cell_label(name, rest[0] if rest else None, csv_rows)} {_row_text(int(i), csv_rows)}: "
                            f"value {af[tuple([i, *rest])]:.4g} is {what}")


def _validate_seq_static(rec: Recording, source: str, csv_rows: bool) -> None:
    """``seq`` / ``section``: integer ids, each sequence contiguous; ``static`` / ``ref_valid``:
    booleans (or 0/1)."""
    for name, what in _ID_KEYS.items():
        v = getattr(rec, name)
        if v is None:
            continue
        s = np.asarray(v)
        if not np.all(s == np.round(s)):
            i = int(np.flatnonzero(s != np.round(s))[0])
            raise _fail(source, f"key '{name}' {_row_text(i, csv_rows)}: {what} {s[i]} is not an integer")
    if rec.seq is not None:
        i = first_repeated_run(rec.seq)
        if i is not None:
            raise _fail(
                source,
                f"key 'seq' {_row_text(i, csv_rows)}: sequence id {int(np.asarray(rec.seq)[i])} appears again after "
                "other ids (samples of one sequence must be contiguous)",
            )
    for name in _FLAG_KEYS:
        v = getattr(rec, name)
        if v is None:
            continue
        a = np.asarray(v)
        if a.dtype != np.bool_ and not np.all((a == 0) | (a == 1)):
            i = int(np.flatnonzero((a != 0) & (a != 1))[0])
            raise _fail(source, f"key '{name}' {_row_text(i, csv_rows)}: expected a boolean (0/1), got {a[i]}")


def _validate_quaternions(rec: Recording, source: str, csv_rows: bool) -> None:
    """``quat_ref`` rows must be unit quaternions (within :data:`QUAT_NORM_TOL`); NaN gap rows are skipped."""
    if rec.quat_ref is None:
        return
    norm = np.linalg.norm(np.asarray(rec.quat_ref, np.float64), axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > QUAT_NORM_TOL)
    if bad.size:
        i = int(bad[0])
        raise _fail(source, f"key 'quat_ref' {_row_text(i, csv_rows)}: quaternion norm {norm[i]:.4g}, "
                            "not a unit quaternion (Hamilton [w, x, y, z])")


def _validate_names(rec: Recording, source: str, csv_rows: bool) -> None:
    """``section_names``: 1-D strings; every ``section`` label is -1 or names one of them."""
    if rec.section_names is None:
        return
    names = np.asarray(rec.section_names)
    if names.ndim != 1 or names.dtype.kind not in "US":
        raise _fail(source, f"key 'section_names': expected a list of strings (K,), got {names.dtype} of shape {names.shape}")
    if rec.section is None:
        return
    sec = np.asarray(rec.section)
    bad = np.flatnonzero((sec < -1) | (sec >= names.shape[0]))
    if bad.size:
        i = int(bad[0])
        raise _fail(source, f"key 'section' {_row_text(i, csv_rows)}: label {sec[i]} names none of the "
                            f"{names.shape[0]} 'section_names' (-1 marks no section)")


def _validate_track(rec: Recording, source: str) -> None:
    """The pose track: ``gt_t`` 1-D, finite, strictly increasing; ``gt_pos`` (M, 3) and ``gt_quat``
    (M, 4) real, finite, with M = len(gt_t) where ``gt_t`` is given."""
    m = None
    for name, trailing in _TRACK_KEYS.items():
        v = getattr(rec, name)
        if v is None:
            continue
        a = np.asarray(v)
        _check_numeric(source, name, a)
        want = ("(M,)" if not trailing else f"(M, {trailing[0]})") + ("" if m is None else f" with M = len(gt_t) = {m}")
        if a.ndim != 1 + len(trailing) or a.shape[1:] != trailing or (m is not None and a.shape[0] != m):
            raise _fail(source, f"key '{name}': expected shape {want}, got {a.shape}")
        af = a.astype(np.float64)
        if not np.all(np.isfinite(af)):
            raise _fail(source, f"key '{name}' row {int(np.argwhere(~np.isfinite(af))[0][0])}: non-finite value")
        if name == "gt_t":
            m = a.shape[0]
            dec = np.flatnonzero(np.diff(af) <= 0)
            if dec.size:
                raise _fail(source, f"key 'gt_t' row {int(dec[0]) + 1}: times not strictly increasing")


def _validate_meta(rec: Recording, source: str) -> None:
    """``fs`` positive and finite; ``t0`` finite; datasheet values real, scalar or (3,), finite, scales positive."""
    if rec.fs is not None and not (math.isfinite(rec.fs) and rec.fs > 0):
        raise _fail(source, f"key 'fs': sample rate must be positive and finite, got {rec.fs}")
    if rec.t0 is not None and not math.isfinite(rec.t0):
        raise _fail(source, f"key 't0': must be finite, got {rec.t0}")
    for name in _META_SPEC_KEYS:
        v = getattr(rec, name)
        if v is None:
            continue
        a = np.asarray(v)
        _check_numeric(source, name, a)
        if a.shape not in ((), (3,)):
            raise _fail(source, f"key '{name}': expected a scalar or shape (3,), got {a.shape}")
        af = a.astype(np.float64)
        if not np.all(np.isfinite(af)) or np.any(np.abs(af) > MAX_VALUE):
            raise _fail(source, f"key '{name}': non-finite or implausibly large value {af.tolist()}")
        if name.endswith(("per_g", "per_rads")) and np.any(af <= 0):
            raise _fail(source, f"key '{name}': datasheet scale must be positive, got {af.tolist()} "
                                "(an inverted axis is part of the calibration, not of the datasheet)")


def _validate_fs(rec: Recording, source: str) -> None:
    """``fs`` must match the spacing of ``t`` within sequences: refused when neither the median
    step (robust to gaps) nor the mean step (robust to jitter) is within :data:`FS_TOLERANCE` of
    ``1 / fs`` (e.g. ``fs`` = 1000 Hz beside a ``t`` that steps at 100 Hz)."""
    if rec.fs is None:
        return
    t = np.asarray(rec.t, np.float64)
    steps = np.concatenate([np.diff(t[s]) for s in sequence_slices(rec)])
    if steps.size == 0:
        return
    ratios = [rec.fs * float(np.median(steps)), rec.fs * float(np.mean(steps))]
    if all(abs(np.log(r)) > np.log1p(FS_TOLERANCE) for r in ratios):
        rate = 1.0 / float(np.median(steps))
        raise _fail(source, f"key 'fs': {rec.fs:.6g} Hz, but 't' steps at {rate:.6g} Hz (median spacing "
                            f"{1.0 / rate:.6g} s); fix 'fs' or leave it out")


def _validate_extra(rec: Recording, source: str) -> None:
    """No extra may carry a field's name (it would shadow the field in :meth:`Recording.to_dict`)."""
    clash = [k for k in rec.extra if k in KNOWN_KEYS]
    if clash:
        raise _fail(source, f"key '{clash[0]}' is a field of Recording; pass it as {clash[0]}=..., not in extra")


# ----------------------------------------------------------------------------- plausibility


def implausible(sensor: str, x: np.ndarray, how: str) -> str | None:
    """What contradicts values ``x`` (N, 3) being in g (``acc``) or rad/s (``gyr``), or ``None``.

    The median ``|f|`` of a resting or hand-held accelerometer lies in :data:`ACC_NORM_G` (near 1 g);
    outside, the unit is off by a large factor (m/s^2 declared as g reads ~9.8). A median rate
    above :data:`GYR_MEDIAN_MAX` or a 99th percentile above :data:`GYR_Q99_MAX` (2000 deg/s) means
    deg/s declared as rad/s. ``how`` says where the values came from (e.g. "after unit conversion").

    Args:
        sensor: ``"acc"`` or ``"gyr"``.
        x: (N, 3) values, declared in g (``acc``) or rad/s (``gyr``).
        how: where the values came from, for the message.
    """
    with np.errstate(over="ignore", invalid="ignore"):  # huge values are refused elsewhere, with their row
        norm = np.linalg.norm(np.asarray(x, np.float64), axis=-1).ravel()
    norm = norm[np.isfinite(norm)]  # non-finite values are refused elsewhere, with their row
    if norm.size == 0:
        return None
    med = float(np.median(norm))
    if sensor == "acc":
        if ACC_NORM_G[0] <= med <= ACC_NORM_G[1]:
            return None
        hint = " (looks like m/s^2)" if 5.0 < med < 15.0 else ""
        return f"median |acc| is {med:.3g} g {how}, not near 1 g{hint}"
    q99 = float(np.quantile(norm, 0.99))
    if med > GYR_MEDIAN_MAX:
        return f"median |gyr| is {med:.3g} rad/s {how}, faster than any hand or rig turns (deg/s declared as rad/s?)"
    if q99 > GYR_Q99_MAX:
        return f"99th percentile of |gyr| is {q99:.3g} rad/s {how}, beyond 2000 deg/s (deg/s declared as rad/s?)"
    return None


_SCALE_KEY = {"acc": ("acc_lsb_per_g", "acc_bias_lsb"), "gyr": ("gyr_lsb_per_rads", "gyr_bias_lsb")}
_SENSOR_WORD = {"acc": "accelerometer", "gyr": "gyroscope"}


def _physical_values(rec: Recording, s: str) -> tuple[np.ndarray, str, str] | None:
    """Sensor ``s`` in g / rad/s with how it got there and what to blame, or ``None`` (raw counts
    without a datasheet scale cannot be judged)."""
    y = np.asarray(getattr(rec, s), np.float64)
    if getattr(rec, f"{s}_unit") == PHYS_UNIT[s]:
        return y, f"with {s}_unit = {PHYS_UNIT[s]!r}", f"the declared {_SENSOR_WORD[s]} unit is wrong"
    scale_key, bias_key = _SCALE_KEY[s]
    scale, bias = getattr(rec, scale_key), getattr(rec, bias_key)
    if scale is None:
        return None
    x = (y - np.asarray(0.0 if bias is None else bias, np.float64)) / np.asarray(scale, np.float64)
    return x, f"after the datasheet scale '{scale_key}'", f"the datasheet scale '{scale_key}' or the unit is wrong"


def check_plausible(rec: Recording, source: str = "") -> None:
    """Refuse declared units or datasheet scales that the data contradict (:func:`implausible`).

    Judges ``acc``/``gyr`` declared in g / rad/s, raw counts converted with the datasheet scale
    where the recording gives one, and the labels ``acc_ref`` (g) and ``gyr_ref`` (rad/s).
    Raises :class:`RecordingError` naming the key.

    Args:
        rec: the recording.
        source: prefix of the error message (e.g. the file); empty: none.
    """
    for s in SENSORS:
        got = None if getattr(rec, s) is None else _physical_values(rec, s)
        why = None if got is None else implausible(s, got[0], got[1])
        if why:
            raise _fail(source, f"key '{s}': {why}; {got[2]}")
    for s, key in (("acc", "acc_ref"), ("gyr", "gyr_ref")):
        x = getattr(rec, key)
        why = None if x is None else implausible(s, x, "in the labels")
        if why:
            raise _fail(source, f"key '{key}': {why}; labels must be in {PHYS_UNIT[s]}")


PER_SAMPLE_FIELDS = ("t", "acc", "gyr", "temp", "seq", "static", "acc_ref", "gyr_ref", "pos_ref", "quat_ref", "mag",
                     "ref_valid", "section")
"""The fields with one row per sample (``t``'s length), which :func:`take_rows` cuts."""


def take_rows(rec: Recording, mask: np.ndarray) -> Recording:
    """The recording restricted to the rows where ``mask`` is true (per-sample fields only; extras
    and reference tracks dropped).

    Args:
        rec: the recording.
        mask: (N,) bool.
    """
    changes = {f: np.asarray(getattr(rec, f))[mask] for f in PER_SAMPLE_FIELDS if getattr(rec, f) is not None}
    return rec.replace(**changes, extra={}, gt_t=None, gt_pos=None, gt_quat=None)


def sequence_slices(rec: Recording) -> list[slice]:
    """Sample ranges of the contiguous sequences (one slice over everything if ``seq`` is absent)."""
    if rec.seq is None:
        return [slice(0, rec.n)]
    return [slice(int(a), int(b)) for a, b in zip(*sequence_bounds(rec.seq))]


# ----------------------------------------------------------------------------- writing


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix) to write; on success it replaces ``path``.

    Any failure, Ctrl-C included, removes the temporary file and leaves ``path`` as it was: an
    earlier file there is never truncated or destroyed, and nothing is left behind. The writer
    creates the temporary file itself (so it gets the usual permissions).
    """
    p = Path(path)
    tmp = p.with_name(f".{p.name}.{secrets.token_hex(4)}.partial{p.suffix}")
    try:
        yield tmp
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


# ----------------------------------------------------------------------------- npz


NPZ_READ_ERRORS = (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError, zlib.error, MemoryError)


def read_npz_arrays(path: Path) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file (no pickles); the file is closed even when it is not one.

    Raises one of :data:`NPZ_READ_ERRORS` (a single ``.npy`` array is a ``ValueError``).
    """
    with open(path, "rb") as fh:
        z = np.load(fh, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise ValueError("a single .npy array, not an .npz archive of named arrays")
        with z:
            return {k: z[k] for k in z.files}


def _load_npz(path: Path) -> dict[str, Any]:
    try:
        return read_npz_arrays(path)
    except NPZ_READ_ERRORS as e:
        raise _fail(str(path), f"cannot read as .npz ({type(e).__name__}: {' '.join(str(e).split())[:120]})") from None


def _save_npz(rec: Recording, path: Path) -> None:
    arrays: dict[str, np.ndarray] = {}
    for k, v in rec.to_dict().items():
        arrays[k] = np.asarray(v)
    with open(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)


# ----------------------------------------------------------------------------- csv


def _sidecar(path: Path) -> Path:
    return path.with_suffix(".json")


def _json_value(v: Any) -> Any:
    a = np.asarray(v)
    if a.dtype.kind in "US":
        return a.tolist()
    if a.dtype == np.bool_:
        return a.tolist()
    return a.astype(np.float64).tolist() if a.dtype.kind == "f" else a.tolist()


def _format_cell(x: Any) -> str:
    if isinstance(x, (bool, np.bool_)):
        return "1" if x else "0"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    return repr(float(x))


def _save_csv(rec: Recording, path: Path, sidecar: Path) -> None:
    n = rec.n
    header: list[str] = []
    columns: list[np.ndarray] = []
    meta: dict[str, Any] = {}
    for name in _CSV_ORDER:
        v = getattr(rec, name)
        if v is None:
            continue
        a = np.asarray(v)
        if name in _VECTOR_KEYS:
            for j, c in enumerate(_VECTOR_KEYS[name]):
                header.append(f"{name}_{c}")
                columns.append(a[:, j])
        else:
            header.append(name)
            columns.append(a)
    for name in _SIDECAR_KEYS:
        v = getattr(rec, name)
        if v is not None:
            meta[name] = _json_value(v)
    for name in _UNIT_KEYS:
        meta[name] = getattr(rec, name)
    for k, v in rec.extra.items():
        a = np.asarray(v)
        if a.ndim == 1 and a.shape[0] == n and a.dtype.kind in "biuf":
            header.append(k)
            columns.append(a)
        elif a.ndim == 2 and a.shape == (n, 3) and a.dtype.kind in "biuf":
            for j, c in enumerate("xyz"):
                header.append(f"{k}_{c}")
                columns.append(a[:, j])
        else:
            meta[k] = _json_value(a)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for i in range(n):
            w.writerow([_format_cell(c[i]) for c in columns])
    with open(sidecar, "w") as fh:
        json.dump(meta, fh, indent=1, sort_keys=True)


def _parse_cell(cell: str, src: str, col: str, i: int) -> float:
    s = cell.strip()
    low = s.lower()
    if low in ("true", "false"):
        return 1.0 if low == "true" else 0.0
    try:
        return float(s) if s else math.nan
    except ValueError:
        raise _fail(src, f"column '{col}' row {i} (line {i + 2}): cannot parse {cell!r} as a number") from None


def _load_csv(path: Path) -> dict[str, Any]:
    src = str(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise _fail(src, f"cannot read as .csv ({type(e).__name__}: {e})") from None
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise _fail(src, "empty file (expected a header row)")
    header = [h.strip() for h in rows[0]]
    if "" in header:
        raise _fail(src, f"column {header.index('') + 1} of the header has no name")
    if len(set(header)) != len(header):
        dup = next(h for h in header if header.count(h) > 1)
        raise _fail(src, f"column '{dup}' appears twice in the header")
    body = rows[1:]
    for i, r in enumerate(body):
        if len(r) != len(header):
            raise _fail(src, f"row {i} (line {i + 2}): {len(r)} cells, header has {len(header)} columns")
    try:  # fast path: numpy parses plain numbers
        data = np.array(body, dtype=np.float64).reshape(len(body), len(header))
    except ValueError:  # slow path: true/false, empty cells, and a precise error otherwise
        data = np.empty((len(body), len(header)), dtype=np.float64)
        for i, r in enumerate(body):
            for j, c in enumerate(r):
                data[i, j] = _parse_cell(c, src, header[j], i)
    col = {h: data[:, j] for j, h in enumerate(header)}
    out: dict[str, Any] = {}
    used: set[str] = set()
    for name, comps in _VECTOR_KEYS.items():
        names = [f"{name}_{c}" for c in comps]
        have = [c for c in names if c in col]
        if not have:
            continue
        missing = [c for c in names if c not in col]
        if missing:
            raise _fail(src, f"column '{missing[0]}' missing (have {', '.join(have)})")
        out[name] = np.stack([col[c] for c in names], axis=1)
        used.update(names)
    for name in ("t", "temp"):
        if name in col:
            out[name] = col[name]
            used.add(name)
    for name, what in _ID_KEYS.items():
        if name not in col:
            continue
        s = col[name]
        bad = np.flatnonzero(~np.isfinite(s) | (s != np.round(s)))
        if bad.size:
            i = int(bad[0])
            raise _fail(src, f"column '{name}' row {i} (line {i + 2}): {what} {s[i]} is not an integer")
        out[name] = s.astype(np.int64)
        used.add(name)
    for name in _FLAG_KEYS:
        if name not in col:
            continue
        s = col[name]
        bad = np.flatnonzero((s != 0) & (s != 1))
        if bad.size:
            i = int(bad[0])
            raise _fail(src, f"column '{name}' row {i} (line {i + 2}): expected 0/1 or true/false, got {s[i]}")
        out[name] = s.astype(bool)
        used.add(name)
    rest = [h for h in header if h not in used]
    # Unknown columns: group foo_x/foo_y/foo_z triples into (N, 3) extras.
    for h in list(rest):
        if h.endswith("_x"):
            stem = h[:-2]
            trip = [f"{stem}_{c}" for c in "xyz"]
            if all(c in rest for c in trip):
                out[stem] = np.stack([col[c] for c in trip], axis=1)
                for c in trip:
                    rest.remove(c)
    for h in rest:
        out[h] = col[h]
    side = _sidecar(path)
    if side.exists():
        try:
            with open(side, encoding="utf-8") as fh:
                meta = json.load(fh)
        except (OSError, ValueError) as e:
            raise _fail(str(side), f"cannot read JSON sidecar ({type(e).__name__}: {e})") from None
        if not isinstance(meta, dict):
            raise _fail(str(side), "JSON sidecar must hold an object of scalar metadata")
        for k, v in meta.items():
            if k in out:
                raise _fail(str(side), f"key '{k}' given both as a CSV column and in the sidecar")
            if k in _UNIT_KEYS:
                if not isinstance(v, str):
                    raise _fail(str(side), f"key '{k}': expected a unit string, got {v!r}")
                out[k] = v
            else:
                out[k] = _sidecar_value(side, k, v)
    return out


def _sidecar_value(side: Path, k: str, v: Any) -> np.ndarray:
    """A sidecar entry as an array: a number, a string, or a (nested) list of numbers."""
    try:
        a = np.asarray(v)
    except ValueError:
        a = np.asarray(None)
    if a.dtype.kind not in "biufU":
        raise _fail(str(side), f"key '{k}': expected a number, a string or a list of numbers, got {type(v).__name__}")
    return a


# ----------------------------------------------------------------------------- public API


def load_recording(path: str | os.PathLike) -> Recording:
    """Read and validate a recording (``.npz``, or ``.csv`` with optional ``.json`` sidecar).

    The one way a recording file comes into memory (foreign formats: :func:`jaxcal.readers.read`).
    Keys of :data:`KNOWN_KEYS` become fields, any other array goes to ``Recording.extra``.

    Args:
        path: the ``.npz`` or ``.csv`` file (the format follows the extension).

    Returns:
        The validated :class:`Recording` (arrays as stored: float32 stays float32, counts stay
        integers; unsigned integers become ``int64``).

    Raises:
        RecordingError: missing/unreadable file, unknown extension, or any check of
            :func:`validate_recording` failing; the message names the file, key/column and row.
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in (".npz", ".csv"):
        raise _fail(str(p), f"unknown recording extension {p.suffix!r} (expected .npz or .csv)")
    if not p.is_file():
        raise _fail(str(p), "no such file")
    if ext == ".npz":
        return recording_from_dict(_load_npz(p), str(p))
    d = _load_csv(p)
    if "t" not in d:
        raise _fail(str(p), "missing required column 't' (sample times in s)")
    return recording_from_dict(d, str(p), csv_rows=True)


def save_recording(rec: Recording, path: str | os.PathLike) -> None:
    """Validate ``rec`` and write it as ``.npz`` or ``.csv`` (+ ``<stem>.json`` sidecar).

    The one way a recording goes to a file. Arrays are written with their own dtypes (``.npz``,
    ``savez_compressed``; no down-casting here). Files are written whole or not at all
    (:func:`atomic_output`).

    Args:
        rec: the recording (validated first).
        path: the ``.npz`` or ``.csv`` file to write (the format follows the extension).

    Raises:
        RecordingError: ``rec`` is invalid, the extension is unknown, or the file cannot be
            written; one line naming the file.
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in (".npz", ".csv"):
        raise _fail(str(p), f"unknown recording extension {p.suffix!r} (expected .npz or .csv)")
    validate_recording(rec, str(p))
    try:
        if ext == ".npz":
            with atomic_output(p) as tmp:
                _save_npz(rec, tmp)
        else:
            with atomic_output(p) as tmp, atomic_output(_sidecar(p)) as tmp_side:
                _save_csv(rec, tmp, tmp_side)
    except OSError as e:
        raise _fail(str(p), f"cannot write ({e.strerror or e})") from None
