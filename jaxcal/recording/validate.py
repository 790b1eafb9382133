"""Building and validating a :class:`~jaxcal.recording.Recording`: :func:`recording_from_dict`
(a ``name -> array`` mapping to a validated recording) and :func:`validate_recording` (every check
of CONVENTIONS.md on shapes, types, finiteness, sizes, ids, quaternions, the pose track and the
metadata, then :func:`~jaxcal.recording.plausibility.check_plausible`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from jaxcal.recording.plausibility import check_plausible
from jaxcal.recording.rows import sequence_slices
from jaxcal.recording.types import (
    _FLAG_KEYS,
    _ID_KEYS,
    _META_SCALAR_KEYS,
    _META_SPEC_KEYS,
    _SAMPLE_SCALAR_KEYS,
    _TRACK_KEYS,
    _UNIT_KEYS,
    _VECTOR_KEYS,
    ACC_UNITS,
    GYR_UNITS,
    KNOWN_KEYS,
    REF_GAP_KEYS,
    Recording,
    _fail,
)
from jaxcal.sequences import first_repeated_run


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
