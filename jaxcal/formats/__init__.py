"""Outside formats as plug-ins: the registry behind ``jaxcal.read``, ``jaxcal import``, ``jaxcal export``
and ``jaxcal import-model``.

:data:`REGISTRY` is an ordinary dict (name -> :class:`~jaxcal.formats.base.Format`) filled below when
this package is imported. One module per outside format or tool, each holding both directions and
its own keys:

* recordings in (:func:`read`): ``imu_tk`` (:mod:`~jaxcal.formats.imu_tk`), ``imucal``
  (:mod:`~jaxcal.formats.imucal`), ``euroc`` (:mod:`~jaxcal.formats.euroc`), ``tumvi``
  (:mod:`~jaxcal.formats.tumvi`), ``mpu6050`` (:mod:`~jaxcal.formats.mpu6050`), ``fusion``
  (x-io, :mod:`~jaxcal.formats.xio`), ``broad`` (:mod:`~jaxcal.formats.broad`), ``csv``
  (:mod:`~jaxcal.formats.generic_csv`), ``rosbag`` (:mod:`~jaxcal.formats.rosbag`);
* linear models out (:func:`export`) and back (:func:`import_model`): ``imucal`` (its
  CalibrationInfo JSON), ``json`` (:mod:`~jaxcal.formats.jaxcal_json`), ``c`` (export only,
  :mod:`~jaxcal.formats.c_header`), ``kalibr`` (:mod:`~jaxcal.formats.kalibr`), ``openvins``
  (:mod:`~jaxcal.formats.openvins`).

Shared pieces: :mod:`~jaxcal.formats.table` (units, text tables, :class:`ReaderError`,
``finish_recording``), :mod:`~jaxcal.formats.pose` (reference pose tracks),
:mod:`~jaxcal.formats.linear_io` (a linear model's applied form, checked matrices),
:mod:`~jaxcal.formats.yaml_doc` (the YAML exports' text) and :mod:`~jaxcal.formats.noise_yaml`
(Kalibr's ``imu.yaml`` noise keys, written by ``jaxcal noise`` and read by ``export --noise``).

Adding a format: write a module with its functions and a ``FORMAT = Format(...)``, then add one line
``register(module.FORMAT)`` below (or call :func:`register` from your own code).
``tests/test_formats_contract.py`` runs every registered format through its directions.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from jaxcal.formats import (
    broad,
    c_header,
    euroc,
    generic_csv,
    imu_tk,
    imucal,
    jaxcal_json,
    kalibr,
    linear_io,
    mpu6050,
    openvins,
    ros_input,
    rosbag,
    tumvi,
    xio,
)
from jaxcal.formats.base import Exported, ExportOptions, Format, Imported
from jaxcal.formats.table import ReaderError
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.recording import Recording

__all__ = [
    "REGISTRY",
    "ExportOptions",
    "Exported",
    "Format",
    "Imported",
    "ReaderError",
    "export",
    "not_linear_message",
    "exporters",
    "get",
    "import_model",
    "importers",
    "names",
    "read",
    "read_document",
    "readers",
    "register",
]

REGISTRY: dict[str, Format] = {}
"""Every outside format by name, in registration order."""


def register(fmt: Format) -> None:
    """Register (or replace) ``fmt`` under ``fmt.name``.

    Args:
        fmt: a :class:`~jaxcal.formats.base.Format`.
    """
    REGISTRY[fmt.name] = fmt


def names() -> tuple[str, ...]:
    """The registered format names, in registration order."""
    return tuple(REGISTRY)


def readers() -> tuple[str, ...]:
    """The formats :func:`read` takes (a recording in)."""
    return tuple(n for n, f in REGISTRY.items() if f.read is not None)


def exporters() -> tuple[str, ...]:
    """The formats :func:`export` writes (a linear model out)."""
    return tuple(n for n, f in REGISTRY.items() if f.export is not None)


def importers() -> tuple[str, ...]:
    """The formats :func:`import_model` reads (a linear model back)."""
    return tuple(n for n, f in REGISTRY.items() if f.import_model is not None)


def get(name: str) -> Format | None:
    """The format registered as ``name``, or ``None``.

    Args:
        name: a format name, e.g. ``"euroc"``.
    """
    return REGISTRY.get(name)


def read(format: str, files: Sequence[str | Path], **options: Any) -> Recording:
    """Read ``files`` in ``format`` into a validated :class:`jaxcal.recording.Recording`.

    Format-specific extras (``meta_*``, ``movement``, ``t0_ns``) go to ``Recording.extra``.

    Args:
        format: one of :func:`readers`.
        files: ``imu_tk``: ``[acc_file, gyr_file]``; ``imucal``: ``[csv]`` or ``[csv, sections.json]``;
            ``euroc`` / ``tumvi``: ``[imu_csv]`` or ``[imu_csv, pose_csv]``; ``mpu6050`` / ``fusion``:
            ``[csv]``; ``broad``: ``[trial.mat]``; ``csv``: ``[csv]``; ``rosbag``: one bag (a ROS1 ``.bag``,
            a ROS2 directory, an ``.mcap`` / ``.db3``) or the ``.bag`` parts of one split recording.
        **options: the format's keyword options: ``imucal``: ``fs`` (required), ``acc_unit``,
            ``gyr_unit``; ``euroc`` / ``tumvi``: ``max_gap``; ``imu_tk``: ``time_unit``; ``csv``:
            ``columns`` (required), ``units``, ``fs``, ``skip_rows``; ``rosbag``: ``imu_topic``
            (required), ``pose_topic``, ``pose_frame``, ``time``, ``max_gap``.

    Raises:
        ReaderError: unknown format, wrong number of files, a missing file, a required option
            missing, or bad content (the message names the file, the column and the reason).
        RecordingError: the result breaks the conventions (:func:`jaxcal.recording.validate_recording`).
    """
    files = [Path(f) for f in files]
    fmt = REGISTRY.get(format)
    if fmt is None or fmt.read is None or fmt.paths_are_files:
        for f in files:
            if not f.is_file():
                raise ReaderError(f"{f}: no such file")
    if fmt is None or fmt.read is None:
        raise ReaderError(f"unknown format {format!r}; expected one of {list(readers())}")
    lo, hi = fmt.files
    if not lo <= len(files) <= hi:
        raise ReaderError(f"format {format!r} takes {lo}..{hi} files, got {len(files)}")
    for opt, what in (fmt.needs or {}).items():
        if options.get(opt) is None:
            raise ReaderError(f"format {format!r} needs {opt}={what}")
    return fmt.read(files, **options)


def export(format: str, model: CalibrationModel, options: ExportOptions | None = None) -> Exported:
    """The file text of ``model`` in ``format``.

    Args:
        format: one of :func:`exporters`.
        model: a linear model (``linear``, ``multipos``, ``online``).
        options: :class:`ExportOptions` (``None``: the defaults).

    Raises:
        ModelError: unknown format, or what the format refuses (a non-linear model, a missing sensor,
            a singular matrix; one line).
    """
    fmt = REGISTRY.get(format)
    if fmt is None or fmt.export is None:
        raise ModelError(f"unknown export format {format!r} ({', '.join(exporters())})")
    if not linear_io.is_linear(model):
        raise ModelError(not_linear_message(model, format))
    return fmt.export(model, options or ExportOptions())


def not_linear_message(model: CalibrationModel, format: str) -> str:
    """Why ``model`` cannot be exported as ``format`` (one line): the format it was asked for, the
    methods whose models it holds, and for a ``diagnosed`` model its effects that no export carries.

    Args:
        model: a model whose method is not linear.
        format: the export format asked for.
    """
    msg = (f"model of method '{model.method}' is not linear: the {format} export holds one affine calibration "
           f"{linear_io.EQUATION} per sensor, which only the methods {', '.join(linear_io.linear_methods())} fit")
    effects = model.meta.get("effects") if model.method == "diagnosed" else None
    if isinstance(effects, dict):
        named = "; ".join(f"{s}: {', '.join(map(str, v))}" for s, v in effects.items() if v) or "none"
        fmt = REGISTRY.get(format)
        imu0 = fmt is not None and fmt.ros_tool is not None  # an imu0 file: no key for an offset against a reference
        msg += (f"; the effects it carries ({named}) would be lost, and "
                + (ros_input.IMU0_LIMITS if imu0 else f"the {format} file has no place for them")
                + "; `jaxcal calibrate --method multipos`, `online` or `linear` fits an exportable model")
    return msg


def _importer(fmt: str) -> Format:
    f = REGISTRY.get(fmt)
    if f is None or f.import_model is None or f.parse is None:
        raise ModelError(f"unknown import format {fmt!r} ({', '.join(importers())})")
    return f


def read_document(fmt: str, text: str) -> Any:
    """The parsed document of an import file's text: JSON (imucal, json) or YAML (kalibr, openvins).

    An OpenCV ``%YAML:1.0`` first line (OpenVINS's files) is skipped.

    Args:
        fmt: one of :func:`importers`.
        text: the file's text.

    Raises:
        ModelError: unknown format or text that does not parse (one line).
    """
    return _importer(fmt).parse(text)


def import_model(fmt: str, doc: Any, drop_g_sensitivity: bool = False) -> Imported:
    """A parsed calibration file of format ``fmt`` (:func:`importers`) as a jaxcal ``linear`` model.

    Args:
        fmt: ``imucal``, ``json``, ``kalibr`` or ``openvins``.
        doc: the parsed document (:func:`read_document`).
        drop_g_sensitivity: import a gyro g-sensitivity (imucal ``K_ga``, Kalibr ``A``, OpenVINS ``Tg``)
            as zero instead of into ``state/gyr/G`` (not used by ``json``).

    Raises:
        ModelError: unknown format, or what the format's reader refuses (one line).
    """
    return _importer(fmt).import_model(doc, drop_g_sensitivity)


register(imu_tk.FORMAT)
register(imucal.FORMAT)
register(euroc.FORMAT)
register(tumvi.FORMAT)
register(mpu6050.FORMAT)
register(xio.FORMAT)
register(broad.FORMAT)
register(generic_csv.FORMAT)
register(rosbag.FORMAT)
register(jaxcal_json.FORMAT)
register(c_header.FORMAT)
register(kalibr.FORMAT)
register(openvins.FORMAT)
