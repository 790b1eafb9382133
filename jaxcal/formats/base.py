"""The record every outside format registers (:class:`Format`) and the types its functions pass.

A format is an outside file layout or tool that jaxcal reads or writes. Its :class:`Format` names
what it can do, each direction optional:

* ``read(files, **options) -> Recording``: a recording in, e.g. EuRoC CSV or a ROS bag
  (``jaxcal.read``, ``jaxcal import``);
* ``export(model, ExportOptions) -> Exported``: a linear model out as file text (``jaxcal export``);
* ``parse(text) -> document`` and ``import_model(document, drop_g_sensitivity) -> Imported``: a
  calibration file back as a ``linear`` model (``jaxcal import-model``).

Pure types, no I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

from jaxcal.methods import CalibrationModel
from jaxcal.recording import Recording

__all__ = ["ExportOptions", "Exported", "Format", "Imported"]


class ExportOptions(NamedTuple):
    """What an export may take besides the model (each format uses the fields in its ``export_options``).

    Args:
        name: C identifier prefix (``c``).
        noise: checked Kalibr ``imu.yaml`` noise keys (:func:`jaxcal.formats.noise_yaml.noise_fields`;
            ``kalibr``, ``openvins``), or ``None``.
    """

    name: str = "jaxcal_cal"
    noise: Mapping[str, Any] | None = None


class Exported(NamedTuple):
    """An export's file text.

    Args:
        text: the whole file, as written.
        missing_noise: the Kalibr noise keys the file lacks (YAML exports; empty otherwise).
    """

    text: str
    missing_noise: tuple[str, ...] = ()


class Imported(NamedTuple):
    """What an import returns.

    Args:
        model: a ``linear`` :class:`~jaxcal.methods.CalibrationModel` (forward ``S``, ``b`` per sensor,
            and the gyro g-sensitivity ``G`` when the file has one).
        notes: one-line remarks on what the import assumed or dropped (e.g. a bias the file lacks).
    """

    model: CalibrationModel
    notes: tuple[str, ...]


@dataclass(frozen=True)
class Format:
    """One outside format: its name, a one-line description, and the directions it supports.

    Args:
        name: the name given to ``jaxcal.read`` / ``jaxcal import`` / ``export --format`` / ``import-model``.
        doc: one line saying what the format is.
        read: ``read(files: list[Path], **options) -> Recording``, or ``None``.
        files: the least and most number of paths ``read`` takes.
        paths_are_files: ``read``'s paths must be existing files (checked before reading); ``False``
            when the reader checks its own paths (a ROS2 bag is a directory).
        own_options: keyword options of ``read`` that no other reader takes (the CLI refuses them
            with any other format, and this format refuses the other readers' options).
        needs: ``option -> what it is`` for the keyword options ``read`` cannot do without.
        export: ``export(model, ExportOptions) -> Exported``, or ``None``.
        suffix: the file suffix of ``export``'s output (e.g. ``".yaml"``).
        export_options: the :class:`ExportOptions` fields ``export`` uses besides the model.
        parse: ``parse(text) -> document`` of an import file, or ``None``.
        import_model: ``import_model(document, drop_g_sensitivity) -> Imported``, or ``None``.
    """

    name: str
    doc: str
    read: Callable[..., Recording] | None = None
    files: tuple[int, int] = (1, 1)
    paths_are_files: bool = True
    own_options: tuple[str, ...] = ()
    needs: Mapping[str, str] | None = None
    export: Callable[[CalibrationModel, ExportOptions], Exported] | None = None
    suffix: str = ""
    export_options: tuple[str, ...] = ()
    parse: Callable[[str], Any] | None = None
    import_model: Callable[[Any, bool], Imported] | None = None
