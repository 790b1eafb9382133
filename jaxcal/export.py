"""The model exports' and imports' old import path: every name re-exported from :mod:`jaxcal.formats`.

Each format now lives in its own module (``jaxcal/formats/``: ``jaxcal_json``, ``c_header``,
``kalibr``, ``openvins``, ``imucal``; the shared applied form ``x = A @ (y - b)`` in ``linear_io``, the
Kalibr ``imu.yaml`` noise keys in ``noise_yaml``), and :func:`import_model` / :func:`read_document`
dispatch through :data:`jaxcal.formats.REGISTRY`. This module keeps ``jaxcal.export.to_kalibr`` and
the rest where users import them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from jaxcal.formats import import_model, importers, kalibr, openvins, read_document
from jaxcal.formats.base import Imported
from jaxcal.formats.c_header import to_c_header
from jaxcal.formats.imucal import IMUCAL_CONVENTION, IMUCAL_FORMAT_VERSION, from_imucal, scale_misalignment, to_imucal
from jaxcal.formats.jaxcal_json import JSON_FORMAT, from_json_export, to_json
from jaxcal.formats.kalibr import KALIBR_CONVENTION, KALIBR_KEYS, from_kalibr, to_kalibr
from jaxcal.formats.linear_io import (
    EQUATION,
    EQUATION_GSENS,
    g_sensitivity,
    is_linear,
    linear_cals,
    linear_methods,
    lower_times_rotation,
    physical_cals,
)
from jaxcal.formats.noise_yaml import NOISE_KEYS, missing_noise_keys, noise_fields
from jaxcal.formats.openvins import OPENVINS_CONVENTION, OPENVINS_KEYS, from_openvins, to_openvins

__all__ = [
    "EQUATION",
    "EQUATION_GSENS",
    "IMPORT_FORMATS",
    "IMUCAL_CONVENTION",
    "IMUCAL_FORMAT_VERSION",
    "JSON_FORMAT",
    "KALIBR_CONVENTION",
    "KALIBR_KEYS",
    "NOISE_KEYS",
    "OPENVINS_CONVENTION",
    "OPENVINS_KEYS",
    "Imported",
    "from_imucal",
    "from_json_export",
    "from_kalibr",
    "from_openvins",
    "g_sensitivity",
    "import_model",
    "is_linear",
    "linear_cals",
    "linear_methods",
    "lower_times_rotation",
    "missing_noise_keys",
    "noise_fields",
    "physical_cals",
    "read_document",
    "scale_misalignment",
    "to_c_header",
    "to_imucal",
    "to_json",
    "to_kalibr",
    "to_openvins",
    "yaml_document",
]

IMPORT_FORMATS = importers()
"""The formats :func:`import_model` reads (:func:`jaxcal.formats.importers`)."""

_YAML_DOCUMENTS = {"kalibr": kalibr.document, "openvins": openvins.document}


def yaml_document(fmt: str, d: Mapping[str, Any]) -> str:
    """The YAML text of :func:`to_kalibr`'s (``fmt="kalibr"``) or :func:`to_openvins`'s (``"openvins"``) dict
    (:func:`jaxcal.formats.kalibr.document`, :func:`jaxcal.formats.openvins.document`).

    Args:
        fmt: ``"kalibr"`` or ``"openvins"``.
        d: the export's dict.

    Raises:
        ValueError: unknown ``fmt``.
    """
    if fmt not in _YAML_DOCUMENTS:
        raise ValueError(f"unknown YAML export format {fmt!r} (kalibr, openvins)")
    return _YAML_DOCUMENTS[fmt](d)
