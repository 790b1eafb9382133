"""A dependency-free C99 header applying a linear model in firmware (:func:`to_c_header`).

It writes ``A`` and ``b`` of the applied form ``x = A @ (y - b)``, never the forward ``S``, as IEEE
doubles that round-trip exactly, with an apply function per sensor (the gyroscope's takes the
calibrated accelerometer when the model has a g-sensitivity). Export only; pure.
"""

from __future__ import annotations

import math
import re

from jaxcal._version import __version__
from jaxcal.formats.base import Exported, ExportOptions, Format
from jaxcal.formats.linear_io import EQUATION, EQUATION_GSENS, g_sensitivity, linear_cals, model_units
from jaxcal.methods import CalibrationModel, ModelError

__all__ = ["FORMAT", "to_c_header"]

_C_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def _c_double(v: float) -> str:
    """A C double literal that parses back to exactly ``v`` (shortest round-trip repr)."""
    if not math.isfinite(v):
        raise ModelError(f"non-finite calibration value {v!r} cannot be exported")
    return repr(float(v))


def _c_comment(text: str) -> str:
    """``text`` made safe inside a C block comment."""
    return text.replace("*/", "* /")


def to_c_header(model: CalibrationModel, name: str = "jaxcal_cal") -> str:
    """A dependency-free C99 header applying a linear model in firmware.

    Per sensor ``s``: ``static const double <name>_<s>_A[3][3]`` and ``<name>_<s>_b[3]``, and
    ``static inline void <name>_apply_<s>(const double y[3], double x[3])`` computing
    ``x = A (y - b)`` (``y`` and ``x`` may be the same array). A comment block states the convention
    and the units.

    Args:
        model: a linear model (see :func:`linear_cals`).
        name: prefix of every identifier and of the include guard; a C identifier.

    Raises:
        ModelError: the model is not linear.
        ValueError: ``name`` is not a C identifier.
    """
    if not _C_NAME.match(name):
        raise ValueError(f"C name {name!r} is not an identifier (letters, digits, '_'; not starting with a digit)")
    cals = linear_cals(model)
    G = g_sensitivity(model)
    guard = f"{name.upper()}_H"
    lines = [
        f"/* {name}.h: IMU calibration exported by jaxcal {_c_comment(__version__)} "
        f"(method '{_c_comment(model.method)}').",
        " *",
        f" * Convention, per sensor:  {EQUATION}",
        " *   y: one raw sample (3 values) in the sensor's input unit;",
        " *   b: bias in the same unit, subtracted first;",
        " *   A: 3x3 matrix, A[i][j] = row i, column j, multiplying the column vector (y - b) from the left",
        " *      (A is the inverse of the forward model's S in y = S x + b);",
        " *   x: calibrated sample in the output unit.",
        " * Values are IEEE-754 doubles written to round-trip exactly. C99, no dependencies.",
    ]
    for s in cals:
        unit_in, unit_out = model_units(model, s)
        call = f"{name}_apply_{s}(y, acc_cal, x)" if (s == "gyr" and G is not None) else f"{name}_apply_{s}(y, x)"
        lines.append(f" *   {s}: input {_c_comment(unit_in or 'unit not recorded')}, output {unit_out}; {call}")
    if G is not None:
        lines += [" *",
                  f" * The gyroscope has a g-sensitivity G ((rad/s)/g):  {EQUATION_GSENS}",
                  f" *   x_acc: the calibrated accelerometer sample (g) of the same instant ({name}_apply_acc's output),",
                  f" *   passed as acc_cal; G = {name}_gyr_G[3][3], rows first."]
    lines += [" */", f"#ifndef {guard}", f"#define {guard}", ""]
    for s, cal in cals.items():
        rows = ",\n".join("    {" + ", ".join(_c_double(v) for v in row) + "}" for row in cal.A)
        lines += [
            f"static const double {name}_{s}_A[3][3] = {{\n{rows}\n}};",
            f"static const double {name}_{s}_b[3] = {{{', '.join(_c_double(v) for v in cal.b)}}};",
            "",
        ]
        if s == "gyr" and G is not None:
            grows = ",\n".join("    {" + ", ".join(_c_double(v) for v in row) + "}" for row in G)
            lines += [
                f"static const double {name}_gyr_G[3][3] = {{\n{grows}\n}};",
                "",
                "/* x = A (y - b) - G acc_cal for the gyr sensor (acc_cal: calibrated accelerometer, g); any of",
                " * y, acc_cal, x may be the same array. */",
                f"static inline void {name}_apply_gyr(const double y[3], const double acc_cal[3], double x[3])",
                "{",
                f"    const double d0 = y[0] - {name}_gyr_b[0];",
                f"    const double d1 = y[1] - {name}_gyr_b[1];",
                f"    const double d2 = y[2] - {name}_gyr_b[2];",
                "    const double f0 = acc_cal[0], f1 = acc_cal[1], f2 = acc_cal[2];",
                "    int i;",
                "    for (i = 0; i < 3; ++i) {",
                f"        x[i] = ({name}_gyr_A[i][0] * d0 + {name}_gyr_A[i][1] * d1 + {name}_gyr_A[i][2] * d2)",
                f"             - ({name}_gyr_G[i][0] * f0 + {name}_gyr_G[i][1] * f1 + {name}_gyr_G[i][2] * f2);",
                "    }",
                "}",
                "",
            ]
            continue
        lines += [
            f"/* x = A (y - b) for the {s} sensor; y and x may be the same array. */",
            f"static inline void {name}_apply_{s}(const double y[3], double x[3])",
            "{",
            f"    const double d0 = y[0] - {name}_{s}_b[0];",
            f"    const double d1 = y[1] - {name}_{s}_b[1];",
            f"    const double d2 = y[2] - {name}_{s}_b[2];",
            "    int i;",
            "    for (i = 0; i < 3; ++i) {",
            f"        x[i] = {name}_{s}_A[i][0] * d0 + {name}_{s}_A[i][1] * d1 + {name}_{s}_A[i][2] * d2;",
            "    }",
            "}",
            "",
        ]
    lines += [f"#endif /* {guard} */", ""]
    return "\n".join(lines)


def _export(model: CalibrationModel, options: ExportOptions) -> Exported:
    return Exported(to_c_header(model, options.name))


FORMAT = Format("c", "a dependency-free C99 header with an apply function per sensor", export=_export, suffix=".h",
                export_options=("name",))
