"""BROAD trial files (Laidig et al. 2021; MATLAB 5 ``.mat``, CC BY 4.0)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.constants import G0
from jaxcal.formats.base import Format
from jaxcal.formats.pose import unit_quaternions
from jaxcal.formats.table import ReaderError, finish_recording, positive_rate
from jaxcal.recording import Recording, implausible

__all__ = ["FORMAT", "read_broad"]


_BROAD_VARS = {"imu_acc": 3, "imu_gyr": 3, "opt_quat": 4, "opt_pos": 3}


def _mat_variable(path: Path, m: Mapping[str, Any], name: str, cols: int, n: int | None) -> np.ndarray:
    """MATLAB variable ``name`` as a float64 (N, cols) array of real numbers (N = ``n`` if given)."""
    if name not in m:
        have = sorted(k for k in m if not k.startswith("__"))
        raise ReaderError(f"{path}: variable {name!r} not found; not a BROAD trial file? it has {have[:12]}")
    a = np.asarray(m[name])
    if a.dtype.kind not in "iuf":
        raise ReaderError(f"{path}: variable {name!r}: expected real numbers, got dtype {a.dtype}")
    if a.ndim != 2 or a.shape[1] != cols or (n is not None and a.shape[0] != n):
        want = f"({'N' if n is None else n}, {cols})"
        raise ReaderError(f"{path}: variable {name!r}: expected shape {want}, got {a.shape}")
    return a.astype(np.float64)


def read_broad(path: str | Path) -> Recording:
    """BROAD trial file (Laidig et al. 2021, *Data* 6(7):72; ``data_mat/NN_<trial>.mat``, CC BY 4.0).

    A MATLAB 5 file (read with :func:`scipy.io.loadmat`) holding ``imu_acc`` (N, 3) m/s^2
    (specific force), ``imu_gyr`` (N, 3) rad/s, ``opt_quat`` (N, 4) Hamilton ``[w, x, y, z]``
    rotating IMU-frame vectors into ENU (body to world, z up: the conventions' order and
    direction, kept as is), ``opt_pos`` (N, 3) m, ``sampling_rate`` (Hz), and optionally
    ``imu_mag`` (N, 3) uT, ``movement`` (N, 1) 0/1 and the ``info`` text. There are no time
    stamps: ``t = k / sampling_rate``. The optical reference is already synchronised and
    expressed for the IMU frame by the dataset authors.

    Returns the :class:`~jaxcal.recording.Recording`: ``acc`` in g (m/s^2 / 9.80665), ``gyr`` in
    rad/s, ``pos_ref``, ``quat_ref`` (finite rows renormalised), ``fs``, ``ref_valid`` (N,) bool
    (rows where both ``opt_pos`` and ``opt_quat`` are finite) and, where the file has them, ``mag``
    (uT), ``extra["movement"]`` (N,) bool and ``extra["meta_info"]``. Reference gaps stay NaN
    (never filled); a row with any NaN is a gap and is made all NaN.

    Raises:
        ReaderError: not a readable MAT file, a missing variable, a wrong shape or dtype,
            non-finite IMU values, an infinite reference value or a non-unit quaternion (the
            message names the file and the variable).
    """
    path = Path(path)
    try:
        import scipy.io
    except ImportError:  # pragma: no cover - scipy is a dependency
        raise ReaderError(f"{path}: reading BROAD .mat files needs scipy") from None
    try:
        m = scipy.io.loadmat(path)
    except NotImplementedError:
        raise ReaderError(f"{path}: a MATLAB v7.3 (HDF5) file; BROAD's data_mat files are MATLAB 5, "
                          "use those") from None
    except Exception as e:  # scipy raises many types on a damaged or foreign file
        raise ReaderError(f"{path}: not a readable MATLAB .mat file ({type(e).__name__}: "
                          f"{' '.join(str(e).split())[:120]})") from None
    acc = _mat_variable(path, m, "imu_acc", 3, None)
    n = acc.shape[0]
    if n < 2:
        raise ReaderError(f"{path}: variable 'imu_acc': {n} samples; need at least 2")
    x = {"imu_acc": acc}
    for name, cols in list(_BROAD_VARS.items())[1:]:
        x[name] = _mat_variable(path, m, name, cols, n)
    if "sampling_rate" not in m:
        raise ReaderError(f"{path}: variable 'sampling_rate' not found; the sample rate is unknown "
                          "and the file has no time stamps")
    sr = np.asarray(m["sampling_rate"])
    if sr.size != 1 or sr.dtype.kind not in "iuf":
        raise ReaderError(f"{path}: variable 'sampling_rate': expected one number, got {sr.dtype} of shape {sr.shape}")
    fs = positive_rate(sr.item(), f"{path}: variable 'sampling_rate'")
    for name in ("imu_acc", "imu_gyr"):
        bad = np.argwhere(~np.isfinite(x[name]))
        if bad.size:
            raise ReaderError(f"{path}: variable {name!r} row {int(bad[0][0])}: non-finite value")
    ref = {}
    for name in ("opt_pos", "opt_quat"):
        v = x[name].copy()
        big = np.argwhere(np.isinf(v))
        if big.size:
            raise ReaderError(f"{path}: variable {name!r} row {int(big[0][0])}: infinite value "
                              "(a reference gap is NaN)")
        v[np.isnan(v).any(axis=1)] = np.nan
        ref[name] = v
    q = ref["opt_quat"]
    ok = np.isfinite(q).all(axis=1)
    if ok.any():
        q[ok] = unit_quaternions(q[ok], f"{path}: variable 'opt_quat' (finite rows)")
    rec: dict[str, Any] = {
        "t": np.arange(n) / fs, "acc": x["imu_acc"] / G0, "gyr": x["imu_gyr"], "acc_unit": "g",
        "gyr_unit": "rad/s", "fs": fs, "pos_ref": ref["opt_pos"], "quat_ref": q,
        "ref_valid": ok & np.isfinite(ref["opt_pos"]).all(axis=1),
    }
    for s, name in (("acc", "imu_acc"), ("gyr", "imu_gyr")):
        why = implausible(s, rec[s], "after unit conversion")
        if why:
            raise ReaderError(f"{path}: variable {name!r}: {why}; BROAD stores m/s^2 and rad/s")
    if "imu_mag" in m:
        rec["mag"] = _mat_variable(path, m, "imu_mag", 3, n)
    if "movement" in m:
        mv = np.asarray(m["movement"])
        if mv.size != n or mv.dtype.kind not in "biuf" or not np.all((mv == 0) | (mv == 1)):
            raise ReaderError(f"{path}: variable 'movement': expected {n} flags of 0/1, "
                              f"got {mv.dtype} of shape {mv.shape}")
        rec["movement"] = mv.reshape(n).astype(bool)
    if "info" in m:
        info = np.asarray(m["info"])
        if info.dtype.kind == "U" and info.size == 1:
            rec["meta_info"] = str(info.item())
    return finish_recording(rec, str(path), plausible=False)



def _read(files: list[Path], **options: Any) -> Recording:
    return read_broad(files[0], **options)


FORMAT = Format("broad", "BROAD trial file (MATLAB 5 .mat) with its optical reference", read=_read,
                read_help="BROAD trial .mat")
