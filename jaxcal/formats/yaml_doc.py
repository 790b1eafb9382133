"""What the two YAML exports (Kalibr, OpenVINS) share: the document text, the ``jaxcal_*`` keys, parsing.

Both exports keep the raw input ``y`` in the model's own input unit and write the bias, which
neither tool holds as a constant, under the extra keys ``jaxcal_b_a`` / ``jaxcal_b_g``
(:func:`jaxcal_fields`; read back by :func:`yaml_bias_units`). :func:`document_text` writes the
file: a ``#`` comment header stating the convention, ``%YAML:1.0`` first for OpenCV readers, sequences
indented under their keys, floats as their shortest round-trip ``repr``. :func:`parse_yaml` reads one
back within :mod:`jaxcal.safe_yaml`'s bounds.

Pure functions, no I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import yaml

from jaxcal._version import __version__
from jaxcal.constants import PHYS_UNIT
from jaxcal.formats.base import Exported
from jaxcal.formats.linear_io import IMU_SENSORS, matrix, model_units
from jaxcal.formats.noise_yaml import missing_noise_keys, opencv_body
from jaxcal.methods import CalibrationModel, ModelError
from jaxcal.safe_yaml import YamlLimitError, load_yaml
from jaxcal.sensor import LinearCal

__all__ = [
    "document_text",
    "exported",
    "imu0",
    "jaxcal_fields",
    "merge",
    "ordered",
    "parse_yaml",
    "yaml_bias_units",
]


def jaxcal_fields(model: CalibrationModel, cals: Mapping[str, LinearCal]) -> dict[str, Any]:
    """The ``jaxcal_*`` keys of a YAML export: raw biases, input units, method and version."""
    units = {s: model_units(model, s)[0] or "unit not recorded" for s in IMU_SENSORS}
    return {
        "jaxcal_b_a": [float(v) for v in cals["acc"].b],
        "jaxcal_b_g": [float(v) for v in cals["gyr"].b],
        "jaxcal_input_unit_acc": units["acc"],
        "jaxcal_input_unit_gyr": units["gyr"],
        "jaxcal_method": model.method,
        "jaxcal_version": __version__,
    }


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


def document_text(convention: str, d: Mapping[str, Any], opencv: bool) -> str:
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
    """
    head = [f"# IMU calibration exported by jaxcal {__version__}.", "#"]
    head += [f"# {line}".rstrip() for line in convention.splitlines()]
    missing = missing_noise_keys(d)
    if missing:
        head += ["#", f"# Missing IMU noise keys (Kalibr imu.yaml, SI units): {', '.join(missing)}.",
                 "# Add them before the tool reads this file, e.g. `jaxcal export ... --noise imu.yaml` (from `jaxcal noise`)."]
    body = yaml.dump(dict(d), Dumper=_IndentedDumper, sort_keys=False, default_flow_style=None, width=200)
    first = ["%YAML:1.0"] if opencv else []
    return "\n".join(first + head) + "\n" + body


def exported(convention: str, d: Mapping[str, Any], opencv: bool) -> Exported:
    """A YAML export's file (:func:`document_text`) with the noise keys it lacks."""
    return Exported(document_text(convention, d, opencv), tuple(missing_noise_keys(d)))


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
    """Raw bias (``jaxcal_b_a``/``_g``, zero when absent) and input units of a YAML export."""
    bias, units = {}, {}
    for s, key in (("acc", "jaxcal_b_a"), ("gyr", "jaxcal_b_g")):
        if key in imu:
            bias[s] = matrix(imu, key, (3,), where)
        else:
            bias[s] = np.zeros(3)
            notes.append(f"no {key}: {s} bias taken as 0 (the tool estimates it online)")
        unit = imu.get(f"jaxcal_input_unit_{s}")
        if unit in ("LSB", PHYS_UNIT[s]):
            units[s] = unit
        else:
            units[s] = "LSB"
            notes.append(f"{s} input unit {unit!r} taken as raw numbers (jaxcal unit LSB)")
    return bias, units


