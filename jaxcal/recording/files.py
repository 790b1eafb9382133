"""Recording files: :func:`load_recording` / :func:`save_recording` (``.npz``, or ``.csv`` with a
``<stem>.json`` sidecar; layout in the package docstring) and the file helpers that other writers
share: :func:`atomic_output` (a file written whole or not at all) and :func:`read_npz_arrays`."""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import secrets
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.recording.types import (
    _CSV_ORDER,
    _FLAG_KEYS,
    _ID_KEYS,
    _SIDECAR_KEYS,
    _UNIT_KEYS,
    _VECTOR_KEYS,
    Recording,
    _fail,
)
from jaxcal.recording.validate import recording_from_dict, validate_recording

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
