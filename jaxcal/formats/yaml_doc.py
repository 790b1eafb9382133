"""What the two YAML exports (Kalibr, OpenVINS) share: the document text, the ``jaxcal_*`` keys, parsing.

Both exports write the intrinsics on a ROS driver's input (m/s^2, rad/s; :func:`export_cals` with
:mod:`jaxcal.formats.ros_input`, the conversion in the ``jaxcal_*`` keys and the header) or, with
``units="model"``, on the model's own input unit, and the bias, which neither tool holds as a
constant, under the extra keys ``jaxcal_b_a`` / ``jaxcal_b_g`` (:func:`jaxcal_fields`; read back by
:func:`yaml_bias_units` and :func:`to_model_unit`); :func:`ros_notes` says in the header what the
tool does not get. :func:`document_text` writes the
file: a ``#`` comment header stating the convention, ``%YAML:1.0`` first for OpenCV readers, sequences
indented under their keys, floats as their shortest round-trip ``repr``. :func:`parse_yaml` reads one
back within :mod:`jaxcal.safe_yaml`'s bounds.

Pure functions, no I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import yaml

from jaxcal._version import __version__
from jaxcal.constants import PHYS_UNIT
from jaxcal.formats.base import Exported, ExportOptions
from jaxcal.formats.linear_io import IMU_SENSORS, linear_cals, matrix, model_units, physical_cals, rows
from jaxcal.formats.noise_yaml import missing_noise_keys, opencv_body
from jaxcal.formats.ros_input import ROS_UNIT, UNITS, RosInput, RosTool, not_carried, ros_cals, ros_input
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.multipos.heldout import jackknife_sd
from jaxcal.safe_yaml import YamlLimitError, load_yaml
from jaxcal.sensor import LinearCal

__all__ = [
    "document_text",
    "export_cals",
    "exported",
    "file_bias_sd",
    "fold_arrays",
    "fold_models",
    "imu0",
    "imu_dict",
    "intrinsics_sd",
    "jaxcal_fields",
    "merge",
    "ordered",
    "parse_yaml",
    "ros_notes",
    "to_model_unit",
    "yaml_bias_units",
    "yaml_export",
]


def jaxcal_fields(model: CalibrationModel, cals: Mapping[str, LinearCal], ros: RosInput | None = None) -> dict[str, Any]:
    """The ``jaxcal_*`` keys of a YAML export: biases and input units of the file's equation, method and version.

    With ``ros`` (:func:`export_cals`) the input is the ROS driver's (m/s^2, rad/s) and the keys add
    ``jaxcal_units: ros``, the model's own input unit and the driver's conversion per sensor
    (``jaxcal_model_unit_*``, ``jaxcal_ros_per_model_unit_*``), which the import undoes.
    """
    if ros is None:
        units = {s: model_units(model, s)[0] or "unit not recorded" for s in IMU_SENSORS}
    else:
        units = dict(ROS_UNIT)
    out: dict[str, Any] = {
        "jaxcal_b_a": [float(v) for v in cals["acc"].b],
        "jaxcal_b_g": [float(v) for v in cals["gyr"].b],
        "jaxcal_input_unit_acc": units["acc"],
        "jaxcal_input_unit_gyr": units["gyr"],
    }
    for s, key in (("acc", "jaxcal_b_a_sd"), ("gyr", "jaxcal_b_g_sd")):
        sd = file_bias_sd(model, s, ros)
        if sd is not None:
            out[key] = [float(v) for v in sd]
    if ros is not None:
        out["jaxcal_units"] = "ros"
        for s in IMU_SENSORS:
            out[f"jaxcal_model_unit_{s}"] = ros.model_unit[s]
            out[f"jaxcal_ros_per_model_unit_{s}"] = [float(v) for v in ros.per_model_unit[s]]
    return {**out, "jaxcal_method": model.method, "jaxcal_version": __version__}


def file_bias_sd(model: CalibrationModel, sensor: str, ros: RosInput | None = None) -> np.ndarray | None:
    """The standard error of ``sensor``'s fitted bias in the file's input unit, when the fit recorded
    one (``meta["held_out"]["bias_sd"]``, the model's input unit: ``multipos``'s delete-one-pose
    jackknife); ``None`` otherwise. With ``ros`` it is converted as the bias is (``|c|`` times it).

    Args:
        model: the exported model.
        sensor: ``acc`` or ``gyr``.
        ros: the ROS conversion (:func:`export_cals`), or ``None`` for the model's own unit.
    """
    rec = ((model.meta or {}).get("held_out") or {}).get("bias_sd") or {}
    v = rec.get(sensor)
    if v is None:
        return None
    sd = np.asarray(v, np.float64)
    return sd * np.abs(ros.per_model_unit[sensor]) if ros is not None else sd


def fold_arrays(model: CalibrationModel) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]] | None:
    """``(A, b)`` per sensor, each ``(F, 3, 3)`` / ``(F, 3)``: the held-out folds' calibrations the fit
    recorded (``meta["held_out"]["fold_cals"]``, ``multipos``'s determined delete-one-pose folds);
    ``None`` when the model records fewer than two folds, or not the same number for each sensor.

    Args:
        model: the exported model.
    """
    rec = ((model.meta or {}).get("held_out") or {}).get("fold_cals") or {}
    folds = {s: rec.get(s) for s in IMU_SENSORS}
    if any(f is None for f in folds.values()):
        return None
    A = {s: np.asarray(folds[s]["A"], np.float64) for s in IMU_SENSORS}
    b = {s: np.asarray(folds[s]["b"], np.float64) for s in IMU_SENSORS}
    n = {len(A[s]) for s in IMU_SENSORS} | {len(b[s]) for s in IMU_SENSORS}
    if len(n) != 1 or n.pop() < 2:
        return None
    return A, b


def fold_models(model: CalibrationModel) -> list[CalibrationModel]:
    """``model`` once per held-out fold that the fit recorded (:func:`fold_arrays`), each with that
    fold's ``A``, ``b`` for both sensors (a g-sensitivity stays the whole fit's); ``[]`` without folds.

    Args:
        model: the exported model.
    """
    arrays = fold_arrays(model)
    if arrays is None:
        return []
    A, b = arrays
    out = []
    for k in range(len(A["acc"])):
        state = dict(model.state)
        for s in IMU_SENSORS:
            p = state[s]
            p = dict(p._asdict()) if hasattr(p, "_asdict") else dict(p)
            state[s] = {**p, "S": np.linalg.inv(A[s][k]), "b": b[s][k]}
        out.append(CalibrationModel(model.method, model.sensors, state, model.meta))
    return out


def intrinsics_sd(model: CalibrationModel, ros: RosInput | None,
                  intrinsics: Callable[[CalibrationModel, Mapping[str, LinearCal]], Mapping[str, Any]]) -> dict[str, Any] | None:
    """The standard error of every number a format's ``intrinsics`` write, by the delete-a-group
    jackknife (:func:`jaxcal.multipos.jackknife_sd`) over the model's held-out folds
    (:func:`fold_models`), each fold's file parameters computed as the file's are: on the same input
    (``ros``, the whole model's conversion, or the model's unit) by the same ``intrinsics``. The
    result mirrors ``intrinsics``' mapping (matrices as rows; numbers only, which OpenCV's reader
    takes); ``None`` without folds. The file's header says how it was made (:func:`not_carried`).

    Args:
        model: the exported model.
        ros: the conversion the file uses (:func:`export_cals`), or ``None`` (the model's unit).
        intrinsics: ``(model, cals) -> mapping`` of the format's calibration keys, ``cals`` as
            :func:`export_cals` gives them.
    """
    folds = fold_models(model)
    if not folds:
        return None
    vals = []
    for m in folds:
        phys = physical_cals(m)
        vals.append(intrinsics(m, phys if ros is None else ros_cals(phys, ros)))

    def sd(leaves: list) -> Any:
        if isinstance(leaves[0], Mapping):
            out = {k: sd([v[k] for v in leaves]) for k in leaves[0]}
            return {k: v for k, v in out.items() if v is not None}
        try:
            a = np.asarray(leaves, np.float64)
        except (TypeError, ValueError):
            return None  # a name, not a number
        return rows(jackknife_sd(a)) if a.ndim == 3 else jackknife_sd(a).tolist()

    return sd(vals)


def export_cals(model: CalibrationModel, units: str, datasheet: Mapping[str, Any] | None) -> tuple[dict[str, LinearCal], RosInput | None]:
    """``acc``, ``gyr`` -> the ``x = A (y - b)`` a YAML export writes (m/s^2, rad/s), and the ROS conversion.

    Args:
        model: a linear model with both sensors.
        units: ``"ros"``: ``y`` is the ROS driver's input (:func:`~jaxcal.formats.ros_input.ros_cals`);
            ``"model"``: ``y`` in the model's input unit (:func:`~jaxcal.formats.linear_io.physical_cals`, ``None``).
        datasheet: a raw model's datasheet scales (``units="ros"`` only).

    Raises:
        ModelError: an unknown ``units``, datasheet scales with ``units="model"``, or what the
            exports refuse (a non-linear model, a missing sensor).
    """
    if units not in UNITS:
        raise ModelError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
    phys = physical_cals(model)
    if units == "model":
        if datasheet:
            raise ModelError("datasheet scales convert a raw model to a ROS driver's input: they go with units 'ros'")
        return phys, None
    ros = ros_input(model, linear_cals(model), datasheet)
    return ros_cals(phys, ros), ros


def imu_dict(model: CalibrationModel, imu: dict[str, Any], cals: Mapping[str, LinearCal], ros: RosInput | None,
             imu_fields: Mapping[str, Any] | None, order: tuple[str, ...], sd: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """``{"imu0": ...}`` of a YAML export: the format's ``imu`` keys, then :func:`jaxcal_fields` (and
    ``jaxcal_intrinsics_sd``: ``sd``, :func:`intrinsics_sd`, when given), then the caller's
    ``imu_fields`` (:func:`merge`), in ``order`` (:func:`ordered`)."""
    extra = {} if sd is None else {"jaxcal_intrinsics_sd": dict(sd)}
    return {"imu0": ordered(merge({**imu, **jaxcal_fields(model, cals, ros), **extra}, imu_fields), order)}


def yaml_export(tool: RosTool, convention: str, build: Callable[..., tuple[dict[str, Any], RosInput | None]],
                model: CalibrationModel, options: ExportOptions, opencv: bool) -> Exported:
    """A YAML export's file: ``build(model, noise, units, datasheet) -> (dict, RosInput | None)``, with the
    header lines on its input and on what ``tool`` (the format's ``ros_tool``) does not get (:func:`ros_notes`,
    :func:`~jaxcal.formats.ros_input.not_carried`)."""
    d, ros = build(model, options.noise, options.units, options.datasheet)
    lost = not_carried(tool, options.units, has_bias_sd=all(file_bias_sd(model, s) is not None for s in IMU_SENSORS),
                       intrinsics_folds=_n_folds(model) if "jaxcal_intrinsics_sd" in d["imu0"] else 0)
    return exported(convention, d, opencv, ros_notes(tool.name, ros, lost), lost)


def _n_folds(model: CalibrationModel) -> int:
    """How many held-out folds :func:`intrinsics_sd` jackknifed (0 without them)."""
    arrays = fold_arrays(model)
    return 0 if arrays is None else len(arrays[0]["acc"])


def ros_notes(tool: str, ros: RosInput | None, not_carried: Sequence[str]) -> list[str]:
    """The header lines of a YAML export saying what its input is and what ``tool`` does not get from it."""
    lines = []
    if ros is not None:
        lines += [f"Input (jaxcal_units: ros): the samples a ROS driver publishes in sensor_msgs/Imu, "
                  f"{ROS_UNIT['acc']} and {ROS_UNIT['gyr']}; the driver's conversion of the model's input:"]
        lines += [f"  {s}: {ros.how[s]}" for s in IMU_SENSORS]
        lines += ["The biases jaxcal_b_a, jaxcal_b_g (and their standard errors jaxcal_b_a_sd, jaxcal_b_g_sd, when the fit "
                  "recorded them) are in those units (jaxcal_ros_per_model_unit_* x the model's bias)."]
    return lines + [f"Not carried to {tool}:"] + [f"  - {n}" for n in not_carried]


def merge(imu: dict[str, Any], extra: Mapping[str, Any] | None) -> dict[str, Any]:
    """``imu`` with the caller's ``extra`` keys added after it (``ValueError`` if one would replace a key)."""
    clash = sorted(set(extra or {}) & set(imu))
    if clash:
        raise ValueError(f"imu_fields may not replace the calibration keys {', '.join(clash)}")
    return {**imu, **(extra or {})}


class _IndentedDumper(yaml.SafeDumper):
    """PyYAML's safe dumper with block sequences indented under their key (``key:\n  - [..]``).

    PyYAML writes ``key:\n- [..]`` by default, which YAML allows but OpenCV's ``cv::FileStorage``
    (OpenVINS's configuration reader) refuses ("Incorrect indentation").
    """

    def increase_indent(self, flow: bool = False, indentless: bool = False) -> None:  # noqa: D102 - PyYAML API
        return super().increase_indent(flow, False)


def _represent_str(dumper: yaml.SafeDumper, value: str) -> yaml.ScalarNode:
    """Quote strings that start like a number (``0.1.0``): OpenCV's reader parses them as numbers and fails."""
    style = '"' if value[:1].isdigit() or value[:1] in "+-." else None
    return dumper.represent_scalar("tag:yaml.org,2002:str", value, style=style)


_IndentedDumper.add_representer(str, _represent_str)


def document_text(convention: str, d: Mapping[str, Any], opencv: bool, notes: Sequence[str] = ()) -> str:
    """The YAML text of a YAML export's dict.

    A ``#`` comment header states the ``convention``; with ``opencv`` the file starts with
    ``%YAML:1.0`` as OpenVINS's own configuration files do (its OpenCV reader expects it; a YAML reader
    skips that first line). Sequences are indented under their keys as OpenCV's reader requires. When
    ``d["imu0"]`` lacks any of the Kalibr noise keys (:func:`~jaxcal.formats.noise_yaml.missing_noise_keys`),
    a comment line names them. Floats are written with their shortest round-trip ``repr``.

    Args:
        convention: the format's convention text (several lines).
        d: the export's dict.
        opencv: write OpenCV's ``%YAML:1.0`` first line.
        notes: more header lines after the convention (e.g. :func:`ros_notes`).
    """
    head = [f"# IMU calibration exported by jaxcal {__version__}.", "#"]
    head += [f"# {line}".rstrip() for line in convention.splitlines()]
    if notes:
        head += ["#"] + [f"# {line}".rstrip() for line in notes]
    missing = missing_noise_keys(d)
    if missing:
        head += ["#", f"# Missing IMU noise keys (Kalibr imu.yaml, SI units): {', '.join(missing)}.",
                 "# Add them before the tool reads this file, e.g. `jaxcal export ... --noise imu.yaml` (from `jaxcal noise`)."]
    body = yaml.dump(dict(d), Dumper=_IndentedDumper, sort_keys=False, default_flow_style=None, width=200)
    first = ["%YAML:1.0"] if opencv else []
    return "\n".join(first + head) + "\n" + body


def exported(convention: str, d: Mapping[str, Any], opencv: bool, notes: Sequence[str] = (),
             not_carried: Sequence[str] = ()) -> Exported:
    """A YAML export's file (:func:`document_text`) with the noise keys it lacks and what it does not carry."""
    return Exported(document_text(convention, d, opencv, notes), tuple(missing_noise_keys(d)), tuple(not_carried))


def parse_yaml(text: str) -> Any:
    """The parsed YAML of an import file's text (an OpenCV ``%YAML:1.0`` first line is skipped).

    Raises:
        ModelError: text that does not parse, or exceeds :func:`jaxcal.safe_yaml.load_yaml`'s bounds (one line).
    """
    try:
        return load_yaml(opencv_body(text))
    except YamlLimitError as e:
        raise ModelError(f"YAML refused: {e}") from None
    except (ValueError, yaml.YAMLError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ModelError(f"not valid YAML ({first})") from None


def ordered(d: Mapping[str, Any], order: tuple[str, ...]) -> dict[str, Any]:
    """``d`` with the keys of ``order`` first, in that order, then the others as they come."""
    return {**{k: d[k] for k in order if k in d}, **{k: v for k, v in d.items() if k not in order}}


def imu0(doc: Any, where: str) -> Mapping[str, Any]:
    """The ``imu0`` mapping of a parsed YAML export (one-line :class:`ModelError` when there is none)."""
    if not isinstance(doc, Mapping) or not isinstance(doc.get("imu0"), Mapping):
        raise ModelError(f"{where}: no 'imu0' mapping")
    return doc["imu0"]


def yaml_bias_units(imu: Mapping[str, Any], where: str, notes: list[str]) -> tuple[dict, dict]:
    """Bias (``jaxcal_b_a``/``_g``, zero when absent) in the file's input unit, and the model's input units
    (``jaxcal_model_unit_*`` of a ``jaxcal_units: ros`` file, else ``jaxcal_input_unit_*``)."""
    bias, units = {}, {}
    for s, key in (("acc", "jaxcal_b_a"), ("gyr", "jaxcal_b_g")):
        if key in imu:
            bias[s] = matrix(imu, key, (3,), where)
        else:
            bias[s] = np.zeros(3)
            notes.append(f"no {key}: {s} bias taken as 0 (the tool estimates it online)")
        unit = imu.get(f"jaxcal_model_unit_{s}", imu.get(f"jaxcal_input_unit_{s}"))
        if unit in ("LSB", PHYS_UNIT[s]):
            units[s] = unit
        else:
            units[s] = "LSB"
            notes.append(f"{s} input unit {unit!r} taken as raw numbers (jaxcal unit LSB)")
    return bias, units


def to_model_unit(fwd: Mapping[str, tuple[np.ndarray, np.ndarray]], imu: Mapping[str, Any],
                  where: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Forward ``(S, b)`` on the file's input as forward ``(S, b)`` on the model's input unit.

    A ``jaxcal_units: ros`` file's input is ``c * y`` (``c`` = ``jaxcal_ros_per_model_unit_*``), so
    ``S_model = diag(1/c) S`` and ``b_model = b / c``; any other file's input is the model's own.

    Raises:
        ModelError: a ``ros`` file without a usable conversion (one line).
    """
    if imu.get("jaxcal_units") != "ros":
        return dict(fwd)
    out = {}
    for s, (S, b) in fwd.items():
        c = matrix(imu, f"jaxcal_ros_per_model_unit_{s}", (3,), where)
        if np.any(c == 0):
            raise ModelError(f"{where}: jaxcal_ros_per_model_unit_{s} has a zero")
        out[s] = (S / c[:, None], b / c)
    return out
