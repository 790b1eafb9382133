"""``jaxcal export``: a linear model as JSON, a C header, or Kalibr/OpenVINS intrinsics."""

from __future__ import annotations

import argparse
import json
import sys

from jaxcal.cli.core import PROG, Command, UsageError, _check_out_file, register_command
from jaxcal.methods import ModelError
from jaxcal.model_file import load_model
from jaxcal.recording import atomic_output

__all__: list[str] = []


# ----------------------------------------------------------------------------- export

_EXPORT_SUFFIX = {"json": ".json", "c": ".h", "kalibr": ".yaml", "openvins": ".yaml"}


def _c_identifier(text: str) -> str:
    if not (text.isascii() and text.replace("_", "a").isalnum() and not text[0].isdigit()):
        raise argparse.ArgumentTypeError(f"expected a C identifier (letters, digits, '_'), got {text!r}")
    return text


def _add_export(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", metavar="MODEL", help="linear model file written by `jaxcal calibrate` (linear, multipos, online)")
    p.add_argument("--format", required=True, choices=tuple(_EXPORT_SUFFIX),
                   help="json: plain JSON with the apply equation written out; c: dependency-free C99 header; "
                   "kalibr: Kalibr scale-misalignment IMU intrinsics (YAML); openvins: OpenVINS kalibr_imu_chain.yaml "
                   "intrinsics (kalibr and openvins need acc and gyr)")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="file to write (.json for json, .h for c, .yaml for kalibr and openvins)")
    p.add_argument("--name", type=_c_identifier, default="jaxcal_cal",
                   help="c: prefix of the header's identifiers (default jaxcal_cal)")


def _run_export(args: argparse.Namespace) -> int:
    from jaxcal import export  # imported on use, like diagnose

    suffix = _EXPORT_SUFFIX[args.format]
    if not args.out.lower().endswith(suffix):
        raise UsageError(f"--out {args.out}: the {args.format} export is written as {suffix}")
    _check_out_file(args.out, [args.model])
    model = load_model(args.model)
    try:
        if args.format == "json":
            text = json.dumps(export.to_json(model), indent=2) + "\n"
        elif args.format == "kalibr":
            text = export.yaml_document("kalibr", export.to_kalibr(model))
        elif args.format == "openvins":
            text = export.yaml_document("openvins", export.to_openvins(model))
        else:
            text = export.to_c_header(model, args.name)
    except ModelError as e:  # a non-linear model, a missing sensor, a singular matrix: say which file
        raise ModelError(f"{args.model}: {e}") from None
    try:
        with atomic_output(args.out) as tmp, open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
    except OSError as e:
        raise UsageError(f"{args.out}: cannot write ({e.strerror or e})") from None
    print(f"{PROG}: wrote {args.out} ({args.format}: {model.method} model, {export.EQUATION} for "
          f"{', '.join(model.sensors)})", file=sys.stderr)
    return 0


register_command(
    "export",
    Command(
        "write a linear model as plain JSON, a C99 header, or Kalibr/OpenVINS IMU intrinsics",
        _add_export,
        _run_export,
        "Write the linear calibration x = A @ (y - b) of each sensor of MODEL (methods linear, multipos, "
        "online) as plain JSON (--format json) or a dependency-free C99 header with an apply function "
        "(--format c), or as Kalibr's scale-misalignment / OpenVINS's kalibr_imu_chain.yaml IMU intrinsics "
        "(--format kalibr|openvins: YAML, acc in m/s^2 and gyr in rad/s from raw samples in the model's input "
        "unit; both sensors needed). Non-linear models (nn, cubic, online-thesis) are refused.",
    ),
)
