"""Kalibr's IMU noise file ``imu.yaml`` (and the noise part of OpenVINS's ``kalibr_imu_chain.yaml``),
written and read.

Written by ``jaxcal noise``: :func:`kalibr_imu_yaml` / :func:`openvins_imu_chain` (the dicts, from
:func:`jaxcal.allan.fit_noise` results) and :func:`kalibr_yaml_text` / :func:`openvins_yaml_text` (the
files' text). Read by ``jaxcal export --noise``: :func:`read_noise_yaml` / :func:`noise_fields` (the
checked keys, :data:`NOISE_KEYS`, that the Kalibr and OpenVINS exports carry;
:func:`missing_noise_keys` names those an export lacks). Keys and units as on Kalibr's wiki page
"IMU Noise Model": SI, continuous time; each key holds the largest value over the three axes.

Pure functions, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import yaml

from jaxcal.allan import NoiseParams
from jaxcal.safe_yaml import load_yaml

__all__ = [
    "NOISE_KEYS",
    "kalibr_imu_yaml",
    "kalibr_yaml_text",
    "missing_noise_keys",
    "noise_fields",
    "openvins_imu_chain",
    "openvins_yaml_text",
    "opencv_body",
    "read_noise_yaml",
]

NOISE_KEYS = (
    "accelerometer_noise_density",
    "accelerometer_random_walk",
    "gyroscope_noise_density",
    "gyroscope_random_walk",
    "rostopic",
    "update_rate",
)
"""The keys of Kalibr's ``imu.yaml`` (IMU noise model, SI units, continuous time), which
:func:`noise_fields` reads and both YAML exports carry when given."""


def noise_fields(doc: Mapping[str, Any]) -> dict[str, Any]:
    """The noise keys (:data:`NOISE_KEYS`) of a Kalibr ``imu.yaml``, checked, for a YAML export's ``imu_fields``.

    ``doc`` is the parsed file: Kalibr's flat ``imu.yaml`` (the keys at top level, as
    ``jaxcal noise`` and Kalibr's wiki write it) or a chain file with them under ``imu0`` (OpenVINS's
    ``kalibr_imu_chain.yaml``). The four densities (``>= 0``, SI units: m/s^2/sqrt(Hz),
    m/s^3/sqrt(Hz), rad/s/sqrt(Hz), rad/s^2/sqrt(Hz)) and ``update_rate`` (Hz, ``> 0``) are required,
    ``rostopic`` (a non-empty string) is taken when present. Other keys are ignored.

    Args:
        doc: the parsed YAML document.

    Raises:
        ValueError: not a mapping, a key missing, or a value of the wrong kind (one line).
    """
    if not isinstance(doc, Mapping):
        raise ValueError(f"expected a YAML mapping of Kalibr imu.yaml keys, got {type(doc).__name__}")
    if isinstance(doc.get("imu0"), Mapping):
        doc = doc["imu0"]
    numbers = [k for k in NOISE_KEYS if k != "rostopic"]
    missing = [k for k in numbers if k not in doc]
    if missing:
        raise ValueError(f"no {', '.join(missing)} (the Kalibr imu.yaml noise keys)")
    out: dict[str, Any] = {}
    for k in numbers:
        v = doc[k]
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        if not ok or v < 0 or (k == "update_rate" and v == 0):
            want = "a rate > 0 in Hz" if k == "update_rate" else "a finite number >= 0"
            raise ValueError(f"{k} must be {want}, got {v!r}")
        out[k] = float(v)
    if "rostopic" in doc:
        if not isinstance(doc["rostopic"], str) or not doc["rostopic"]:
            raise ValueError(f"rostopic must be a topic name, got {doc['rostopic']!r}")
        out["rostopic"] = doc["rostopic"]
    return {k: out[k] for k in NOISE_KEYS if k in out}


def missing_noise_keys(d: Mapping[str, Any]) -> list[str]:
    """The :data:`NOISE_KEYS` that a YAML export's dict (``{"imu0": {...}}``) lacks."""
    imu = d.get("imu0", {})
    return [k for k in NOISE_KEYS if k not in imu]


def opencv_body(text: str) -> str:
    """``text`` without an OpenCV ``%YAML:1.0`` first line (OpenVINS's files have one)."""
    if text.startswith("%YAML:"):
        return text.split("\n", 1)[1] if "\n" in text else ""
    return text


def read_noise_yaml(text: str) -> dict[str, Any]:
    """The checked noise keys (:func:`noise_fields`) of a Kalibr ``imu.yaml``'s text (an OpenCV
    ``%YAML:1.0`` first line is skipped).

    Raises:
        ValueError: not valid YAML, or what :func:`noise_fields` refuses (one line).
    """
    try:
        return noise_fields(load_yaml(opencv_body(text)))
    except yaml.YAMLError as e:
        raise ValueError(f"not valid YAML ({str(e).strip().splitlines()[0]})") from None


# ----------------------------------------------------------------------------- written by jaxcal noise


def _scalar(v) -> float:
    """One number for a yaml key: the largest over axes (the conservative choice for a filter)."""
    return float(np.max(np.asarray(v, dtype=np.float64)))


def kalibr_imu_yaml(acc_noise: NoiseParams, gyr_noise: NoiseParams, rate_hz: float, topic: str) -> dict:
    """Kalibr's ``imu.yaml`` as a dict (write it with ``yaml.safe_dump``).

    Keys and units as on Kalibr's wiki page "IMU Noise Model": ``accelerometer_noise_density``
    [m/s^2/sqrt(Hz)], ``accelerometer_random_walk`` [m/s^3/sqrt(Hz)], ``gyroscope_noise_density``
    [rad/s/sqrt(Hz)], ``gyroscope_random_walk`` [rad/s^2/sqrt(Hz)] (continuous-time densities),
    ``update_rate`` [Hz], ``rostopic``. ``acc_noise`` must come from m/s^2 data and ``gyr_noise``
    from rad/s data; each key holds the largest value over the three axes. These are the sensor's
    own (Allan) values, with no inflation for unmodelled effects.

    Args:
        acc_noise: :func:`fit_noise` of the accelerometer in m/s^2.
        gyr_noise: :func:`fit_noise` of the gyroscope in rad/s.
        rate_hz: IMU rate [Hz].
        topic: the IMU's ROS topic.
    """
    return {
        "accelerometer_noise_density": _scalar(acc_noise.N),
        "accelerometer_random_walk": _scalar(acc_noise.K),
        "gyroscope_noise_density": _scalar(gyr_noise.N),
        "gyroscope_random_walk": _scalar(gyr_noise.K),
        "update_rate": float(rate_hz),
        "rostopic": str(topic),
    }


def openvins_imu_chain(acc_noise: NoiseParams, gyr_noise: NoiseParams, rate_hz: float, topic: str) -> dict:
    """The noise part of OpenVINS's ``kalibr_imu_chain.yaml``: the Kalibr keys under ``imu0``.

    OpenVINS reads the same four key names and units as Kalibr (its ``kalibr_imu_chain.yaml``),
    plus ``T_i_b`` (identity here), ``time_offset`` (0) and ``update_rate``. The intrinsics keys
    (``Tw``, ``Ta``, ``R_IMUtoGYRO``, ...) belong to a calibration export, not to noise.

    Args:
        acc_noise: :func:`fit_noise` of the accelerometer in m/s^2.
        gyr_noise: :func:`fit_noise` of the gyroscope in rad/s.
        rate_hz: IMU rate [Hz].
        topic: the IMU's ROS topic.
    """
    k = kalibr_imu_yaml(acc_noise, gyr_noise, rate_hz, topic)
    eye = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    return {
        "imu0": {
            "T_i_b": eye,
            **{key: k[key] for key in k if key not in ("update_rate",)},
            "time_offset": 0.0,
            "update_rate": k["update_rate"],
        }
    }


def kalibr_yaml_text(d: dict, combine: str = "largest over the three axes", notes: tuple[str, ...] = ()) -> str:
    """Kalibr's ``imu.yaml`` text (the layout of Kalibr's wiki example, with comments).

    Args:
        d: :func:`kalibr_imu_yaml` dict.
        combine: how the axes were combined (written as a comment).
        notes: more one-line comments (e.g. the report's warnings).
    """
    extra = "".join(f"# note: {n}\n" for n in notes)
    return (
        "# Kalibr IMU noise parameters (https://github.com/ethz-asl/kalibr/wiki/IMU-Noise-Model), written by jaxcal noise\n"
        f"# from the Allan deviation of a static stretch; each value is the {combine} (conservative).\n"
        "# These are the sensor's own values: a filter on dynamic data usually needs them inflated (see noise.json / README).\n"
        f"{extra}"
        "\n#Accelerometers\n"
        f"accelerometer_noise_density: {d['accelerometer_noise_density']!r}  #Noise density (continuous-time) [m/s^2/sqrt(Hz)]\n"
        f"accelerometer_random_walk: {d['accelerometer_random_walk']!r}  #Bias random walk [m/s^3/sqrt(Hz)]\n"
        "\n#Gyroscopes\n"
        f"gyroscope_noise_density: {d['gyroscope_noise_density']!r}  #Noise density (continuous-time) [rad/s/sqrt(Hz)]\n"
        f"gyroscope_random_walk: {d['gyroscope_random_walk']!r}  #Bias random walk [rad/s^2/sqrt(Hz)]\n"
        "\n"
        f"rostopic: {d['rostopic']}  #the IMU ROS topic\n"
        f"update_rate: {d['update_rate']!r}  #Hz (for discretization of the values above)\n"
    )


def openvins_yaml_text(d: dict) -> str:
    """OpenVINS's ``kalibr_imu_chain.yaml`` noise part: ``%YAML:1.0`` first (OpenVINS's OpenCV reader
    expects it; a YAML reader skips that line), then ``imu0`` with Kalibr's noise keys.

    Args:
        d: :func:`openvins_imu_chain` dict.
    """
    head = ("%YAML:1.0\n# OpenVINS kalibr_imu_chain.yaml noise keys, written by jaxcal noise (same numbers and units as imu.yaml;\n"
            "# largest over the three axes). T_i_b is identity and time_offset 0: no extrinsics are estimated here.\n")
    return head + yaml.safe_dump(d, sort_keys=False, default_flow_style=None, width=200)
