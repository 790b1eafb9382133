"""The record every outside format registers (:class:`Format`) and the types its functions pass.

A format is an outside file layout or tool that jaxcal reads or writes. Its :class:`Format` names
what it can do, each direction optional:

* ``read(files, **options) -> Recording``: a recording in, e.g. EuRoC CSV or a ROS bag
  (``jaxcal.read``, ``jaxcal import``; the keyword options' flags declared in ``flags``, as
  :class:`jaxcal.flags.Flag` records, a flag several readers take once in :data:`SHARED_FLAGS`);
* ``export(model, ExportOptions) -> Exported``: a linear model out as file text (``jaxcal export``);
* ``parse(text) -> document`` and ``import_model(document, drop_g_sensitivity) -> Imported``: a
  calibration file back as a ``linear`` model (``jaxcal import-model``).

Pure types and data, no I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

from jaxcal import flags
from jaxcal.flags import Flag
from jaxcal.methods import CalibrationModel
from jaxcal.recording import Recording

if TYPE_CHECKING:
    from jaxcal.formats.ros_input import RosTool

__all__ = ["SHARED_FLAGS", "ExportOptions", "Exported", "Format", "Imported"]

SHARED_FLAGS: dict[str, Flag] = {
    "fs": Flag("--fs", flags.real(0.0, 1e9), None, "sample rate in Hz (imucal, csv without a time column)"),
}
"""The ``jaxcal import`` flags of reader options that several readers take (``Format.flags``), declared once."""


class ExportOptions(NamedTuple):
    """What an export may take besides the model (each format uses the fields in its ``export_options``).

    Args:
        name: C identifier prefix (``c``).
        noise: checked Kalibr ``imu.yaml`` noise keys (:func:`jaxcal.formats.noise_yaml.noise_fields`;
            ``kalibr``, ``openvins``), or ``None``.
        units: ``kalibr``, ``openvins``: ``"ros"`` (the default: the intrinsics on a ROS driver's
            ``sensor_msgs/Imu`` input, m/s^2 and rad/s; :mod:`jaxcal.formats.ros_input`) or ``"model"``
            (on the model's own input unit, as before).
        datasheet: ``kalibr``, ``openvins`` with ``units="ros"``: a raw (LSB) model's datasheet scales
            ``acc_lsb_per_g`` / ``gyr_lsb_per_rads`` (one number or three), the conversion its driver applies.
    """

    name: str = "jaxcal_cal"
    noise: Mapping[str, Any] | None = None
    units: str = "ros"
    datasheet: Mapping[str, Any] | None = None


class Exported(NamedTuple):
    """An export's file text.

    Args:
        text: the whole file, as written.
        missing_noise: the Kalibr noise keys the file lacks (YAML exports; empty otherwise).
        not_carried: what the file does not give the tool that reads it, one phrase each (YAML exports).
    """

    text: str
    missing_noise: tuple[str, ...] = ()
    not_carried: tuple[str, ...] = ()


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
        flags: ``option ->`` its ``jaxcal import`` flag (:class:`jaxcal.flags.Flag`, the option's
            name as its ``dest``, default ``None``: not given), for the keyword options of ``read``
            the command line offers; a flag another reader shares comes from :data:`SHARED_FLAGS`.
            ``jaxcal import`` offers every registered reader's flags and passes the ones given to
            ``read`` (a ``TypeError`` from an option ``read`` does not take is refused naming its flag).
        read_help: what ``jaxcal import``'s FORMAT help says of the reader after its name, e.g.
            ``"ACC GYR files"`` (readers in a row with the same text are named together).
        files_help: what ``jaxcal import``'s FILE help says of the reader's paths, or ``""``.
        export: ``export(model, ExportOptions) -> Exported``, or ``None``.
        suffix: the file suffix of ``export``'s output (e.g. ``".yaml"``).
        export_options: the :class:`ExportOptions` fields ``export`` uses besides the model.
        parse: ``parse(text) -> document`` of an import file, or ``None``.
        import_model: ``import_model(document, drop_g_sensitivity) -> Imported``, or ``None``.
        ros_tool: the ROS-fed tool that reads ``export``'s ``imu0`` file
            (:class:`~jaxcal.formats.ros_input.RosTool`: Kalibr, OpenVINS), or ``None``; its file has
            no key for a time offset or transform against a reference
            (:data:`~jaxcal.formats.ros_input.IMU0_LIMITS`).
    """

    name: str
    doc: str
    read: Callable[..., Recording] | None = None
    files: tuple[int, int] = (1, 1)
    paths_are_files: bool = True
    own_options: tuple[str, ...] = ()
    needs: Mapping[str, str] | None = None
    flags: Mapping[str, Flag] | None = None
    read_help: str = ""
    files_help: str = ""
    export: Callable[[CalibrationModel, ExportOptions], Exported] | None = None
    suffix: str = ""
    export_options: tuple[str, ...] = ()
    parse: Callable[[str], Any] | None = None
    import_model: Callable[[Any, bool], Imported] | None = None
    ros_tool: RosTool | None = None
