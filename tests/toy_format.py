"""A toy outside format: the whole of what a new reader and a new export format need
(see ``test_formats_contract.py``).

Recordings: a text file, ``# toy-imu`` on the first line, then one whitespace-separated row
``t ax ay az gx gy gz`` per sample (s, g, rad/s). Models: a text file, ``# toy-cal`` on the first
line, then per sensor one row ``sensor A00 A01 A02 A10 A11 A12 A20 A21 A22 b0 b1 b2 input_unit``
(the applied form ``x = A (y - b)``), and with a gyro g-sensitivity a row ``G g00 ... g22``
((rad/s)/g). Both directions of both kinds are here, with the shared
helpers of :mod:`jaxcal.formats`; register it with one line, ``formats.register(toy_format.FORMAT)``.
The reader's one keyword option, ``time_scale``, declares its ``jaxcal import`` flag
(``--toy-time-scale``) in ``FORMAT.flags``: the command line needs no edit for it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxcal import flags
from jaxcal.flags import Flag
from jaxcal.formats.base import Exported, ExportOptions, Format, Imported
from jaxcal.formats.linear_io import g_sensitivity, imported_model, inv, keep_gsens, linear_cals, model_units
from jaxcal.formats.table import ReaderError, finish_recording, read_text
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.recording import Recording

__all__ = ["FORMAT", "recording_text"]

_REC_HEAD, _CAL_HEAD = "# toy-imu", "# toy-cal"


def recording_text(rec: Recording) -> str:
    """``rec`` (acc in g, gyr in rad/s) as a toy recording file (numbers as shortest round-trip ``repr``)."""
    rows = np.concatenate([np.asarray(rec.t)[:, None], rec.acc, rec.gyr], axis=1)
    return _REC_HEAD + "\n" + "".join(" ".join(repr(float(v)) for v in r) + "\n" for r in rows)


def _read(files: list[Path], time_scale: float = 1.0) -> Recording:
    path = files[0]
    lines = read_text(path).splitlines()
    if not lines or lines[0].strip() != _REC_HEAD:
        raise ReaderError(f"{path}: no {_REC_HEAD!r} first line; not a toy recording")
    try:
        x = np.array([[float(c) for c in ln.split()] for ln in lines[1:] if ln.strip()], np.float64)
    except ValueError:
        raise ReaderError(f"{path}: a row that is not 7 numbers") from None
    if x.ndim != 2 or x.shape[1] != 7:
        raise ReaderError(f"{path}: rows must be 't ax ay az gx gy gz'")
    rec = {"t": x[:, 0] * time_scale, "acc": x[:, 1:4], "gyr": x[:, 4:7], "acc_unit": "g", "gyr_unit": "rad/s"}
    return finish_recording(rec, str(path))


def _export(model: CalibrationModel, options: ExportOptions) -> Exported:
    lines = [_CAL_HEAD]
    for s, cal in linear_cals(model).items():
        nums = [*np.ravel(cal.A), *cal.b]
        lines.append(" ".join([s, *(repr(float(v)) for v in nums), model_units(model, s)[0] or "LSB"]))
    G = g_sensitivity(model)
    if G is not None:
        lines.append(" ".join(["G", *(repr(float(v)) for v in np.ravel(G))]))
    return Exported("\n".join(lines) + "\n")


def _parse(text: str) -> list[list[str]]:
    lines = text.splitlines()
    if not lines or lines[0].strip() != _CAL_HEAD:
        raise ModelError(f"no {_CAL_HEAD!r} first line; not a toy calibration")
    return [ln.split() for ln in lines[1:] if ln.strip()]


def _import(doc: list[list[str]], drop_g_sensitivity: bool = False) -> Imported:
    fwd, units, G, notes = {}, {}, None, []
    for row in doc:
        if row[:1] == ["G"] and len(row) == 10:
            G = np.array([float(c) for c in row[1:]]).reshape(3, 3)
            continue
        if len(row) != 14 or row[0] not in ("acc", "gyr"):
            raise ModelError("a toy calibration row is 'sensor' + 12 numbers + 'input_unit'")
        v = np.array([float(c) for c in row[1:13]])
        fwd[row[0]] = (inv(v[:9].reshape(3, 3), "A", f"toy {row[0]}"), v[9:])
        units[row[0]] = row[13]
    if G is not None and not keep_gsens(G, "G", "toy", drop_g_sensitivity, notes):
        G = None
    return Imported(imported_model(fwd, units, {"format": "toy", "notes": notes}, G), tuple(notes))


FORMAT = Format("toy", "a toy text format (a test plug-in): recordings in, linear models out and back", read=_read,
                export=_export, suffix=".toy", parse=_parse, import_model=_import, read_help="a toy text file",
                flags={"time_scale": Flag("--toy-time-scale", flags.real(0.0, 1e6), None,
                                          "toy: seconds per unit of the file's t column (default 1)", "S")})
