"""The :class:`Recording` type: its fields, the key tables of CONVENTIONS.md that name them, and
:class:`RecordingError` (one line: what and where). The package docstring (:mod:`jaxcal.recording`)
has the table of keys, shapes and units."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jaxcal.constants import PHYS_UNIT, SENSORS

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


def _fail(source: str, msg: str) -> RecordingError:
    """A :class:`RecordingError` whose one-line message starts with ``source`` (when given)."""
    text = f"{source}: {msg}" if source else msg
    return RecordingError(" ".join(text.split("\n")))
