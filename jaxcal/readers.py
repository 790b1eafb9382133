"""Readers: public IMU recording formats -> the conventions' recording (``CONVENTIONS.md``).

Every reader returns a plain ``dict`` of numpy arrays keyed by the conventions' names:

* ``t`` (N,) float64, seconds, increasing. Uneven sampling is kept as recorded.
* ``acc`` (N, 3) and ``gyr`` (N, 3): raw integer counts (``acc_unit`` / ``gyr_unit`` = ``"LSB"``)
  or physical values converted explicitly to **g** and **rad/s** (``"g"`` / ``"rad/s"``).
* optional ``fs`` (Hz), ``acc_lsb_per_g``, ``gyr_lsb_per_rads`` (datasheet values where the format
  documents them), ``pos_ref`` (m) / ``quat_ref`` (Hamilton, **scalar first**, body to world),
  ``seq``, ``static``, and format-specific extras (``mag`` in uT, ``section`` ids with
  ``section_names``, ``meta_*`` header values).

:func:`read_dict` dispatches on a format name; :func:`read` does the same and returns a validated
:class:`jaxcal.recording.Recording` (``jaxcal import FORMAT FILES...``). The per-format functions
are public too. Units are never guessed silently: a unit is taken from the caller or from
the header (``Name (unit)`` / ``Name [unit]``), and an unknown, conflicting or implausible unit
raises :class:`ReaderError` naming the file, the column and the reason.

Readers do file input by design (this module is the I/O boundary); they hold no state.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

G0 = 9.80665  # standard gravity, m/s^2 (conventions: the g unit)

# Factors to the conventions' units. ``None`` marks raw counts (kept as integers).
_ACC_UNITS: dict[str, float | None] = {
    "g": 1.0, "g0": 1.0, "mg": 1e-3, "m/s^2": 1.0 / G0, "m/s2": 1.0 / G0, "ms^-2": 1.0 / G0,
    "m s^-2": 1.0 / G0, "m/s/s": 1.0 / G0, "lsb": None, "counts": None, "a.u.": None, "raw": None,
}
_GYR_UNITS: dict[str, float | None] = {
    "rad/s": 1.0, "rad s^-1": 1.0, "rad/sec": 1.0, "mrad/s": 1e-3, "deg/s": math.pi / 180.0,
    "dps": math.pi / 180.0, "degree/s": math.pi / 180.0, "°/s": math.pi / 180.0,
    "lsb": None, "counts": None, "a.u.": None, "raw": None,
}
_TIME_UNITS: dict[str, float] = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}
_MAG_UNITS: dict[str, float] = {"ut": 1.0, "µt": 1.0, "gauss": 100.0, "mgauss": 0.1, "nt": 1e-3}

_QUANTITY_UNITS = {"acc": _ACC_UNITS, "gyr": _GYR_UNITS, "t": _TIME_UNITS, "mag": _MAG_UNITS}
_CANONICAL = {"acc": "g", "gyr": "rad/s", "t": "s", "mag": "uT"}

FORMATS = ("imu_tk", "imucal", "euroc", "tumvi", "mpu6050", "fusion", "csv")


class ReaderError(ValueError):
    """Bad input: the message names the file, the column (where there is one) and the reason."""


# --------------------------------------------------------------------------------------- helpers

def _norm_unit(u: str) -> str:
    return u.strip().lower().replace(" ", "").replace("²", "^2").replace("sec", "s") if u else u


def unit_factor(quantity: str, unit: str, *, where: str) -> float | None:
    """Factor from ``unit`` to the conventions' unit of ``quantity`` (``None``: raw counts).

    Args:
        quantity: ``"acc"``, ``"gyr"``, ``"t"`` or ``"mag"``.
        unit: e.g. ``"m/s^2"``, ``"deg/s"``, ``"ns"``, ``"LSB"``.
        where: ``file: column`` text used in the error message.

    Raises:
        ReaderError: unknown unit for that quantity.
    """
    table = _QUANTITY_UNITS[quantity]
    key = _norm_unit(unit)
    lookup = {_norm_unit(k): v for k, v in table.items()}
    if key not in lookup:
        raise ReaderError(
            f"{where}: unknown {quantity} unit {unit!r}; expected one of {sorted(table)}"
        )
    return lookup[key]


_UNIT_IN_NAME = re.compile(r"[\(\[]\s*([^\)\]]*?)\s*[\)\]]\s*$")


def unit_from_header(name: str) -> str | None:
    """The unit written in a column header as ``Name (unit)`` or ``Name [unit]``, else ``None``."""
    m = _UNIT_IN_NAME.search(name)
    if not m or not m.group(1):
        return None
    return m.group(1)


def _read_table(path: Path, skip: int = 0) -> tuple[list[str], list[list[str]]]:
    text = path.read_text()
    lines = text.splitlines()[skip:]
    rows = list(csv.reader(io.StringIO("\n".join(lines))))
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        raise ReaderError(f"{path}: no header line")
    header = [h.strip().lstrip("#").strip() for h in rows[0]]
    return header, rows[1:]


def _column(path: Path, header: list[str], rows: list[list[str]], name: str) -> np.ndarray:
    if name not in header:
        raise ReaderError(f"{path}: column {name!r} not found; header has {header}")
    j = header.index(name)
    try:
        return np.array([float(r[j]) for r in rows], dtype=np.float64)
    except (ValueError, IndexError) as e:
        raise ReaderError(f"{path}: column {name!r}: non-numeric or missing value ({e})") from None


def _as_counts(x: np.ndarray, where: str) -> np.ndarray:
    """Raw counts as int32; they must be integer-valued."""
    if not np.all(np.isfinite(x)) or np.any(np.abs(x - np.round(x)) > 1e-6):
        raise ReaderError(f"{where}: unit says raw counts (LSB) but the values are not integers")
    return np.round(x).astype(np.int32)


def _check_time(t: np.ndarray, where: str) -> np.ndarray:
    if t.ndim != 1 or t.size < 2:
        raise ReaderError(f"{where}: need at least two samples")
    if not np.all(np.isfinite(t)):
        raise ReaderError(f"{where}: non-finite time stamps")
    if np.any(np.diff(t) <= 0):
        i = int(np.argmax(np.diff(t) <= 0))
        raise ReaderError(f"{where}: time is not strictly increasing at row {i + 1}")
    return t


def check_plausible(rec: Mapping[str, Any], where: str = "recording") -> None:
    """Reject physical units that cannot be right (a wrong unit, e.g. m/s^2 declared as g).

    The median accelerometer norm of a hand-held or resting IMU lies near 1 g; a value outside
    [0.25, 4] g means the declared unit is off by a large factor. A median gyro rate above
    20 rad/s (1150 deg/s) likewise means deg/s were declared as rad/s.
    """
    if rec.get("acc_unit") == "g" and "acc" in rec:
        med = float(np.median(np.linalg.norm(rec["acc"], axis=-1)))
        if not 0.25 <= med <= 4.0:
            col = rec.get("_acc_columns", "acc")
            hint = " (looks like m/s^2)" if 5.0 < med < 15.0 else ""
            raise ReaderError(
                f"{where}: column {col}: median |acc| is {med:.3g} g after unit conversion, "
                f"not near 1 g{hint}; the declared accelerometer unit is wrong"
            )
    if rec.get("gyr_unit") == "rad/s" and "gyr" in rec:
        med = float(np.median(np.linalg.norm(rec["gyr"], axis=-1)))
        if med > 20.0:
            col = rec.get("_gyr_columns", "gyr")
            raise ReaderError(
                f"{where}: column {col}: median |gyr| is {med:.3g} rad/s after unit conversion; "
                "the declared gyroscope unit is wrong (deg/s declared as rad/s?)"
            )


def _finish(rec: dict[str, Any], where: str, plausible: bool = True) -> dict[str, Any]:
    if plausible:
        check_plausible(rec, where)
    rec.pop("_acc_columns", None)
    rec.pop("_gyr_columns", None)
    rec["t"] = _check_time(np.asarray(rec["t"], dtype=np.float64), where)
    return rec


def _convert3(
    path: Path, header: list[str], rows: list[list[str]], names: Sequence[str], quantity: str,
    unit: str | None,
) -> tuple[np.ndarray, str]:
    """Three columns of one quantity, converted; returns (values, conventions unit)."""
    header_units = {unit_from_header(n) for n in names}
    header_units.discard(None)
    if len(header_units) > 1:
        raise ReaderError(f"{path}: columns {list(names)}: mixed units {sorted(header_units)}")
    hu = header_units.pop() if header_units else None
    if unit is None and hu is None:
        raise ReaderError(
            f"{path}: column {names[0]!r}: no {quantity} unit given and none in the header; "
            f"pass units={{'{quantity}': ...}}"
        )
    if unit is not None and hu is not None:
        fu, fh = unit_factor(quantity, unit, where=f"{path}: column {names[0]!r}"), unit_factor(
            quantity, hu, where=f"{path}: column {names[0]!r}")
        if fu != fh:
            raise ReaderError(
                f"{path}: column {names[0]!r}: the header says {hu!r} but units= says {unit!r}; "
                "ambiguous, fix one of them"
            )
    u = unit if unit is not None else hu
    factor = unit_factor(quantity, u, where=f"{path}: column {names[0]!r}")
    x = np.stack([_column(path, header, rows, n) for n in names], axis=-1)
    if factor is None:
        return _as_counts(x, f"{path}: column {names[0]!r}"), "LSB"
    return (x * factor), _CANONICAL[quantity]


# --------------------------------------------------------------------------------------- formats

def read_generic_csv(
    path: str | Path,
    columns: Mapping[str, str],
    units: Mapping[str, str] | None = None,
    *,
    fs: float | None = None,
    skip_rows: int = 0,
) -> dict[str, Any]:
    """Any CSV with a header row, given a column mapping and units.

    Args:
        path: the CSV file.
        columns: conventions name -> CSV header name, for any of ``t``, ``acc_x..acc_z``,
            ``gyr_x..gyr_z``, ``mag_x..mag_z``, ``temp``. Without ``t``, ``fs`` is required and
            ``t = n / fs``.
        units: quantity -> unit for ``t`` (s, ms, us, ns), ``acc`` (g, mg, m/s^2, LSB), ``gyr``
            (rad/s, mrad/s, deg/s, LSB), ``mag`` (uT, gauss). A unit may instead be written in
            the header, ``Name (unit)``; where both exist they must agree.
        fs: nominal sample rate (Hz), stored as ``fs``.
        skip_rows: lines to skip before the header.

    Returns:
        The recording dict (``t`` in s, ``acc`` in g or LSB, ``gyr`` in rad/s or LSB).

    Raises:
        ReaderError: missing column, unknown/conflicting/implausible unit (names the column).
    """
    path = Path(path)
    units = dict(units or {})
    header, rows = _read_table(path, skip_rows)
    rec: dict[str, Any] = {}
    if "t" in columns:
        tu = units.get("t") or unit_from_header(columns["t"])
        if tu is None:
            raise ReaderError(f"{path}: column {columns['t']!r}: no time unit given and none in the header")
        rec["t"] = _column(path, header, rows, columns["t"]) * unit_factor("t", tu, where=f"{path}: column {columns['t']!r}")
    elif fs is not None:
        rec["t"] = np.arange(len(rows)) / float(fs)
    else:
        raise ReaderError(f"{path}: no time column mapped ('t') and no fs given")
    for q in ("acc", "gyr", "mag"):
        names = [columns.get(f"{q}_{a}") for a in "xyz"]
        if all(n is None for n in names):
            continue
        if any(n is None for n in names):
            raise ReaderError(f"{path}: map all three of {q}_x, {q}_y, {q}_z")
        x, u = _convert3(path, header, rows, names, q, units.get(q))
        rec[q] = x
        if q != "mag":
            rec[f"{q}_unit"] = u
            rec[f"_{q}_columns"] = repr(names[0])
    if "acc" not in rec and "gyr" not in rec:
        raise ReaderError(f"{path}: map at least acc_x..acc_z or gyr_x..gyr_z")
    if "temp" in columns:
        rec["temp"] = _column(path, header, rows, columns["temp"])
    if fs is not None:
        rec["fs"] = float(fs)
    return _finish(rec, str(path))


def read_imu_tk(acc_path: str | Path, gyr_path: str | Path, *, time_unit: str = "s") -> dict[str, Any]:
    """imu_tk ASCII: one whitespace-separated ``t x y z`` file per sensor, raw counts.

    Both files must share the time column (imu_tk's test data does). Values are kept as integer
    counts (LSB); the imu_tk test recordings are unsigned 16-bit ADC counts centred near 32768.
    """
    out = {}
    for key, p in (("acc", acc_path), ("gyr", gyr_path)):
        p = Path(p)
        try:
            a = np.loadtxt(p, ndmin=2)
        except ValueError as e:
            raise ReaderError(f"{p}: not a whitespace-separated numeric 't x y z' file ({e})") from None
        if a.shape[1] != 4:
            raise ReaderError(f"{p}: expected 4 columns 't x y z', found {a.shape[1]}")
        out[key] = a
    ta, tg = out["acc"][:, 0], out["gyr"][:, 0]
    if ta.shape != tg.shape or not np.allclose(ta, tg):
        raise ReaderError(f"{gyr_path}: column 't': time differs from {acc_path}; resample first")
    tf = unit_factor("t", time_unit, where=f"{acc_path}: column 't'")
    t = ta * tf
    rec = {
        "t": t,
        "acc": _as_counts(out["acc"][:, 1:], f"{acc_path}: columns 'x y z'"),
        "gyr": _as_counts(out["gyr"][:, 1:], f"{gyr_path}: columns 'x y z'"),
        "acc_unit": "LSB",
        "gyr_unit": "LSB",
        "fs": float(1.0 / np.median(np.diff(t))),
    }
    return _finish(rec, str(acc_path))


_IMUCAL_PHYS = ("gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z")


def read_imucal(
    path: str | Path,
    *,
    fs: float,
    acc_unit: str | None = None,
    gyr_unit: str | None = None,
    sections: str | Path | None = None,
) -> dict[str, Any]:
    """imucal / pandas CSV: ``n_samples`` (or ``samples``) index, ``acc_*``, ``gyr_*``, optional ``part``.

    Two variants exist: a continuous session in physical units (imucal's example session:
    m/s^2 and deg/s, which must be stated, the header carries no units) and an annotated session
    of raw counts (``part`` column naming the Ferraris section; units ``"a.u."`` = LSB). The
    index column is a sample counter, not time: ``t = index / fs`` and ``fs`` is required.
    Annotated rows are re-ordered by sample index; ``section`` (N,) int and ``section_names``
    record the parts. A ``sections`` JSON (``{"x_p": {"start": i, "end": j}, ...}``) labels a
    continuous session the same way (-1 outside every section).
    """
    path = Path(path)
    header, rows = _read_table(path)
    idx_name = "n_samples" if "n_samples" in header else "samples" if "samples" in header else None
    if idx_name is None:
        raise ReaderError(f"{path}: no 'n_samples' or 'samples' index column; header has {header}")
    n = _column(path, header, rows, idx_name)
    has_part = "part" in header
    if has_part:
        acc_unit = acc_unit or "a.u."
        gyr_unit = gyr_unit or "a.u."
    if acc_unit is None or gyr_unit is None:
        raise ReaderError(
            f"{path}: columns 'acc_x'/'gyr_x' carry no unit; pass acc_unit (e.g. 'm/s^2') and "
            "gyr_unit (e.g. 'deg/s') for this imucal session"
        )
    acc, au = _convert3(path, header, rows, ("acc_x", "acc_y", "acc_z"), "acc", acc_unit)
    gyr, gu = _convert3(path, header, rows, ("gyr_x", "gyr_y", "gyr_z"), "gyr", gyr_unit)
    order = np.argsort(n, kind="stable")
    rec: dict[str, Any] = {
        "t": n[order] / float(fs), "acc": acc[order], "gyr": gyr[order], "acc_unit": au,
        "gyr_unit": gu, "fs": float(fs), "_acc_columns": "'acc_x'", "_gyr_columns": "'gyr_x'",
    }
    if has_part:
        parts = np.array([r[header.index("part")].strip() for r in rows])[order]
        names = sorted(set(parts.tolist()))
        rec["section"] = np.array([names.index(p) for p in parts], dtype=np.int32)
        rec["section_names"] = np.array(names)
    elif sections is not None:
        spec = json.loads(Path(sections).read_text())
        names = list(spec)
        sec = np.full(len(n), -1, dtype=np.int32)
        ni = n[order]
        for k, nm in enumerate(names):
            sec[(ni >= spec[nm]["start"]) & (ni <= spec[nm]["end"])] = k
        rec["section"] = sec
        rec["section_names"] = np.array(names)
    return _finish(rec, str(path))


def _quat_columns_xyzw_to_wxyz(q_xyzw: np.ndarray) -> np.ndarray:
    q = np.concatenate([q_xyzw[:, 3:4], q_xyzw[:, :3]], axis=1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _slerp_to(t_src: np.ndarray, q_src: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    """Quaternion (scalar first) slerp of a pose track onto new times (held at the ends)."""
    q_src = q_src.copy()
    # make consecutive quaternions share a hemisphere
    for i in range(1, len(q_src)):
        if np.dot(q_src[i], q_src[i - 1]) < 0:
            q_src[i] = -q_src[i]
    j = np.clip(np.searchsorted(t_src, t_dst) - 1, 0, len(t_src) - 2)
    u = np.clip((t_dst - t_src[j]) / (t_src[j + 1] - t_src[j]), 0.0, 1.0)[:, None]
    q0, q1 = q_src[j], q_src[j + 1]
    d = np.clip(np.sum(q0 * q1, axis=1, keepdims=True), -1.0, 1.0)
    th = np.arccos(d)
    s = np.sin(th)
    small = s < 1e-8
    w0 = np.where(small, 1 - u, np.sin((1 - u) * th) / np.where(small, 1, s))
    w1 = np.where(small, u, np.sin(u * th) / np.where(small, 1, s))
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _attach_pose(rec: dict[str, Any], t_gt: np.ndarray, pos: np.ndarray, q_wxyz: np.ndarray,
                 max_gap: float) -> None:
    """Interpolate a pose track to the IMU times (linear / slerp, held at the ends).

    ``ref_valid`` (N,) bool marks IMU samples inside the track and not across a gap longer than
    ``max_gap`` s; elsewhere the pose is only the nearest held value. The original track is kept
    as ``gt_t``, ``gt_pos``, ``gt_quat``.
    """
    t = rec["t"]
    rec["pos_ref"] = np.stack([np.interp(t, t_gt, pos[:, k]) for k in range(3)], -1)
    rec["quat_ref"] = _slerp_to(t_gt, q_wxyz, t)
    j = np.clip(np.searchsorted(t_gt, t) - 1, 0, len(t_gt) - 2)
    gap = (t_gt[j + 1] - t_gt[j]) > max_gap
    rec["ref_valid"] = ~gap & (t >= t_gt[0]) & (t <= t_gt[-1])
    rec["gt_t"], rec["gt_pos"], rec["gt_quat"] = t_gt, pos, q_wxyz


def _exact_time(text: str) -> int | float:
    """An integer time stamp kept exact (ns since 1970 need 61 bits), else a float."""
    text = text.strip()
    try:
        return int(text)
    except ValueError:
        return float(text)


_EUROC_IMU = ("w_RS_S_x", "w_RS_S_y", "w_RS_S_z", "a_RS_S_x", "a_RS_S_y", "a_RS_S_z")
_EUROC_POSE = ("p_RS_R_x", "p_RS_R_y", "p_RS_R_z", "q_RS_w", "q_RS_x", "q_RS_y", "q_RS_z")


def _strip_units(header: list[str]) -> list[str]:
    return [_UNIT_IN_NAME.sub("", h).strip() for h in header]


def read_euroc(imu_path: str | Path, pose_path: str | Path | None = None, *, max_gap: float = 0.05) -> dict[str, Any]:
    """EuRoC / ASL CSV: ``imu0/data.csv`` (+ ``vicon0/data.csv`` or ground-truth estimate).

    Header ``#timestamp [ns],w_RS_S_x [rad s^-1],...,a_RS_S_x [m s^-2],...``; the pose file has
    ``p_RS_R_x [m],...,q_RS_w [],q_RS_x [],...`` (quaternion **scalar first**, body to world).
    Time is converted from ns to s (relative times keep float64 precision: ``t`` counts from the
    first IMU sample, ``t0_ns`` keeps the offset). Poses are interpolated to IMU times
    (``pos_ref``, ``quat_ref``; ``ref_valid`` is False across gaps over ``max_gap`` s).
    """
    imu_path = Path(imu_path)
    header, rows = _read_table(imu_path)
    names = _strip_units(header)
    tu = unit_from_header(header[0]) or "ns"
    t_int = [_exact_time(r[0]) for r in rows]  # exact integer ns: float64 cannot hold 1.4e18 + 1
    t0 = t_int[0]
    tf = unit_factor("t", tu, where=f"{imu_path}: column {header[0]!r}")
    t = np.array([x - t0 for x in t_int], dtype=np.float64) * tf
    hdr = dict(zip(names, header))
    gyr, gu = _convert3(imu_path, header, rows, [hdr[n] for n in _EUROC_IMU[:3]], "gyr", None)
    acc, au = _convert3(imu_path, header, rows, [hdr[n] for n in _EUROC_IMU[3:]], "acc", None)
    rec: dict[str, Any] = {"t": t, "acc": acc, "gyr": gyr, "acc_unit": au, "gyr_unit": gu,
                           "t0_ns": float(t0) * tf * 1e9,
                           "_acc_columns": repr(hdr[_EUROC_IMU[3]]), "_gyr_columns": repr(hdr[_EUROC_IMU[0]])}
    if pose_path is not None:
        pose_path = Path(pose_path)
        ph, prow = _read_table(pose_path)
        pn = _strip_units(ph)
        phdr = dict(zip(pn, ph))
        ptu = unit_from_header(ph[0]) or "ns"
        ptf = unit_factor("t", ptu, where=f"{pose_path}: column {ph[0]!r}")
        tg = np.array([(_exact_time(r[0]) - t0) * tf if ptf == tf else _exact_time(r[0]) * ptf - t0 * tf
                       for r in prow], dtype=np.float64)
        for n in _EUROC_POSE:
            if n not in phdr:
                raise ReaderError(f"{pose_path}: column {n!r} not found; header has {ph}")
        pos = np.stack([_column(pose_path, ph, prow, phdr[n]) for n in _EUROC_POSE[:3]], -1)
        q = np.stack([_column(pose_path, ph, prow, phdr[n]) for n in _EUROC_POSE[3:]], -1)
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        _attach_pose(rec, tg, pos, q, max_gap)
    return _finish(rec, str(imu_path))


_TUMVI_IMU = ("angular_velocity.x", "angular_velocity.y", "angular_velocity.z",
              "linear_acceleration.x", "linear_acceleration.y", "linear_acceleration.z")
_TUMVI_GT = ("transform.translation.x", "transform.translation.y", "transform.translation.z",
             "transform.rotation.x", "transform.rotation.y", "transform.rotation.z", "transform.rotation.w")


def read_tumvi(imu_path: str | Path, gt_path: str | Path | None = None, *, max_gap: float = 0.05) -> dict[str, Any]:
    """TUM-VI CSV (ROS message field names, as exported by Brossard et al.'s tools).

    IMU: ``Time`` (Unix s), ``angular_velocity.*`` (rad/s), ``linear_acceleration.*`` (m/s^2,
    specific force). Ground truth: ``transform.translation.*`` (m) and ``transform.rotation.*``
    in ROS order **x, y, z, w** (scalar last), re-ordered here to the conventions' scalar-first
    Hamilton ``[w, x, y, z]``. The original TUM-VI ``mav0/imu0/data.csv`` uses the EuRoC layout:
    it is read by :func:`read_euroc`. ``t`` counts from the first IMU sample (``t0`` keeps the
    Unix offset, so float64 keeps microsecond precision).
    """
    imu_path = Path(imu_path)
    header, rows = _read_table(imu_path)
    if "angular_velocity.x" not in header:
        return read_euroc(imu_path, gt_path, max_gap=max_gap)
    traw = _column(imu_path, header, rows, "Time")
    t0 = traw[0]
    gyr = np.stack([_column(imu_path, header, rows, n) for n in _TUMVI_IMU[:3]], -1)
    acc = np.stack([_column(imu_path, header, rows, n) for n in _TUMVI_IMU[3:]], -1) / G0
    rec: dict[str, Any] = {"t": traw - t0, "acc": acc, "gyr": gyr, "acc_unit": "g", "gyr_unit": "rad/s",
                           "t0": float(t0), "_acc_columns": "'linear_acceleration.x'",
                           "_gyr_columns": "'angular_velocity.x'"}
    if gt_path is not None:
        gt_path = Path(gt_path)
        gh, grows = _read_table(gt_path)
        tg = _column(gt_path, gh, grows, "Time") - t0
        pos = np.stack([_column(gt_path, gh, grows, n) for n in _TUMVI_GT[:3]], -1)
        q_xyzw = np.stack([_column(gt_path, gh, grows, n) for n in _TUMVI_GT[3:]], -1)
        _attach_pose(rec, tg, pos, _quat_columns_xyzw_to_wxyz(q_xyzw), max_gap)
    return _finish(rec, str(imu_path))


MPU6050_ACC_LSB_PER_G = 16384.0  # +-2 g default full scale
MPU6050_GYR_LSB_PER_RADS = 131.0 * 180.0 / math.pi  # +-250 deg/s default full scale


def read_mpu6050(path: str | Path) -> dict[str, Any]:
    """MPU-6050 Arduino log (tomisuarez2/ImuCalibration): ``key,value`` metadata lines, a header
    ``ax,ay,az,gx,gy,gz`` and signed 16-bit counts; no time column.

    ``t = n / Fs`` from the ``Fs`` metadata line (required). The datasheet scales of the default
    ranges (+-2 g: 16384 LSB/g; +-250 deg/s: 131 LSB/(deg/s)) are stored as ``acc_lsb_per_g`` and
    ``gyr_lsb_per_rads``; the other metadata lines as ``meta_<name>``.
    """
    path = Path(path)
    lines = path.read_text().splitlines()
    meta: dict[str, float] = {}
    k = 0
    while k < len(lines) and not lines[k].strip().lower().startswith("ax"):
        parts = lines[k].split(",")
        if len(parts) != 2:
            raise ReaderError(f"{path}: line {k + 1}: expected 'name,value' metadata or the 'ax,...' header")
        try:
            meta[parts[0].strip()] = float(parts[1])
        except ValueError:
            raise ReaderError(f"{path}: line {k + 1}: metadata value {parts[1]!r} is not a number") from None
        k += 1
    if k == len(lines):
        raise ReaderError(f"{path}: no 'ax,ay,az,gx,gy,gz' header line")
    if "Fs" not in meta:
        raise ReaderError(f"{path}: no 'Fs' metadata line: the sample rate is unknown and there is no time column")
    header, rows = _read_table(path, skip=k)
    acc = _as_counts(np.stack([_column(path, header, rows, n) for n in ("ax", "ay", "az")], -1), f"{path}: column 'ax'")
    gyr = _as_counts(np.stack([_column(path, header, rows, n) for n in ("gx", "gy", "gz")], -1), f"{path}: column 'gx'")
    fs = meta["Fs"]
    rec: dict[str, Any] = {
        "t": np.arange(len(rows)) / fs, "acc": acc, "gyr": gyr, "acc_unit": "LSB", "gyr_unit": "LSB",
        "fs": fs, "acc_lsb_per_g": MPU6050_ACC_LSB_PER_G, "gyr_lsb_per_rads": MPU6050_GYR_LSB_PER_RADS,
    }
    for name, v in meta.items():
        if name != "Fs":
            rec["meta_" + re.sub(r"\W+", "_", name.strip().lower())] = v
    return _finish(rec, str(path))


def read_fusion(path: str | Path) -> dict[str, Any]:
    """x-io Fusion CSV: ``Time (s), Gyroscope X (deg/s), ..., Accelerometer X (g), ...,
    Magnetometer X (uT), ...`` with units in the header (converted explicitly; ``mag`` in uT).
    """
    path = Path(path)
    header, _ = _read_table(path)
    cols: dict[str, str] = {}
    for h in header:
        base = _UNIT_IN_NAME.sub("", h).strip().lower()
        for q, word in (("gyr", "gyroscope"), ("acc", "accelerometer"), ("mag", "magnetometer")):
            for a in "xyz":
                if base == f"{word} {a}":
                    cols[f"{q}_{a}"] = h
        if base == "time":
            cols["t"] = h
    if "t" not in cols:
        raise ReaderError(f"{path}: no 'Time (s)' column; header has {header}")
    return read_generic_csv(path, cols)


def read(format: str, files: Sequence[str | Path], **options: Any):
    """Read ``files`` in ``format`` into a validated :class:`jaxcal.recording.Recording`.

    Same arguments as :func:`read_dict`; format-specific extras go to ``Recording.extra``.
    """
    from jaxcal.recording import recording_from_dict

    return recording_from_dict(read_dict(format, files, **options), source=str(files[0]) if files else "")


def read_dict(format: str, files: Sequence[str | Path], **options: Any) -> dict[str, Any]:
    """Read ``files`` in ``format`` (one of :data:`FORMATS`) into a recording dict.

    ``imu_tk``: ``[acc_file, gyr_file]``; ``imucal``: ``[csv]`` or ``[csv, sections.json]``
    (options ``fs``, ``acc_unit``, ``gyr_unit``); ``euroc``/``tumvi``: ``[imu_csv]`` or
    ``[imu_csv, pose_csv]``; ``mpu6050``/``fusion``: ``[csv]``; ``csv``: ``[csv]`` with options
    ``columns``, ``units``, ``fs``, ``skip_rows``.
    """
    files = [Path(f) for f in files]
    for f in files:
        if not f.is_file():
            raise ReaderError(f"{f}: no such file")

    def want(lo: int, hi: int) -> None:
        if not lo <= len(files) <= hi:
            raise ReaderError(f"format {format!r} takes {lo}..{hi} files, got {len(files)}")

    if format == "imu_tk":
        want(2, 2)
        return read_imu_tk(files[0], files[1], **options)
    if format == "imucal":
        want(1, 2)
        if "fs" not in options:
            raise ReaderError(f"{files[0]}: imucal CSVs hold a sample index, not time: pass fs")
        return read_imucal(files[0], sections=files[1] if len(files) > 1 else None, **options)
    if format == "euroc":
        want(1, 2)
        return read_euroc(files[0], files[1] if len(files) > 1 else None, **options)
    if format == "tumvi":
        want(1, 2)
        return read_tumvi(files[0], files[1] if len(files) > 1 else None, **options)
    if format == "mpu6050":
        want(1, 1)
        return read_mpu6050(files[0])
    if format == "fusion":
        want(1, 1)
        return read_fusion(files[0])
    if format == "csv":
        want(1, 1)
        if "columns" not in options:
            raise ReaderError(f"{files[0]}: the generic csv format needs a column mapping (columns=...)")
        return read_generic_csv(files[0], **options)
    raise ReaderError(f"unknown format {format!r}; expected one of {list(FORMATS)}")


def save_npz(rec: Mapping[str, Any], path: str | Path, compressed: bool = True) -> None:
    """Write a recording dict as the conventions' ``.npz`` (float64 physical arrays -> float32
    where the precision allows; ``t`` stays float64, counts stay integers)."""
    out = {}
    for k, v in rec.items():
        a = np.asarray(v)
        if k not in ("t", "gt_t") and a.dtype == np.float64 and a.ndim > 0:
            a = a.astype(np.float32)
        out[k] = a
    (np.savez_compressed if compressed else np.savez)(path, **out)


def load_npz(path: str | Path) -> dict[str, Any]:
    """Read a conventions ``.npz`` into a dict (0-d arrays become Python scalars/str)."""
    with np.load(path, allow_pickle=False) as z:
        return {k: (z[k].item() if z[k].ndim == 0 else z[k]) for k in z.files}
