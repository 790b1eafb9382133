"""``jaxcal export``: a linear model as JSON, a C header, Kalibr/OpenVINS intrinsics or imucal's
CalibrationInfo; ``jaxcal import-model``: such a file (imucal, json, kalibr, openvins) back as a
``linear`` model. Both dispatch through :data:`jaxcal.formats.REGISTRY` (its exporters and importers)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from jaxcal.cli.core import PROG, Command, UsageError, _add_datasheet_flags, _check_out_file, register_command
from jaxcal.recording import atomic_output

__all__: list[str] = []


# ----------------------------------------------------------------------------- export

def _c_identifier(text: str) -> str:
    if not (text.isascii() and text.replace("_", "a").isalnum() and not text[0].isdigit()):
        raise argparse.ArgumentTypeError(f"expected a C identifier (letters, digits, '_'), got {text!r}")
    return text


def _add_export(p: argparse.ArgumentParser) -> None:
    from jaxcal import formats  # imported when the command is parsed, not when it registers

    p.add_argument("model", metavar="MODEL", help="linear model file written by `jaxcal calibrate` (linear, multipos, online)")
    p.add_argument("--format", required=True, choices=formats.exporters(),
                   help="json: plain JSON with the apply equation written out; c: dependency-free C99 header; "
                   "kalibr: Kalibr scale-misalignment IMU intrinsics (YAML); openvins: OpenVINS kalibr_imu_chain.yaml "
                   "intrinsics; imucal: imucal's FerrarisCalibrationInfo JSON (kalibr, openvins and imucal need acc and gyr)")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="file to write (.json for json and imucal, .h for c, .yaml for kalibr and openvins)")
    p.add_argument("--name", type=_c_identifier, default="jaxcal_cal",
                   help="c: prefix of the header's identifiers (default jaxcal_cal)")
    p.add_argument("--noise", metavar="IMU_YAML", default=None,
                   help="kalibr, openvins: a Kalibr imu.yaml (e.g. from `jaxcal noise`) whose noise densities, random "
                   "walks, update_rate and rostopic go into the file (without it, a comment names the missing keys)")
    p.add_argument("--units", choices=("ros", "model"), default=None,
                   help="kalibr, openvins: ros (default): the intrinsics on what a ROS driver publishes in "
                   "sensor_msgs/Imu (m/s^2, rad/s; a model fitted on g: the driver's m/s^2 = g x 9.80665; a raw model: "
                   "the datasheet conversion of --acc-lsb-per-g / --gyr-lsb-per-rads, or the model's own mean scale); "
                   "model: on the model's own input unit, as before")
    _add_datasheet_flags(p, "kalibr, openvins with --units ros, a raw (LSB) model: the driver divides by")


def _read_noise(path: str) -> dict:
    """The checked noise keys of a Kalibr imu.yaml file (UsageError naming the file otherwise)."""
    from jaxcal.formats.noise_yaml import read_noise_yaml

    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise UsageError(f"--noise {path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    try:
        return read_noise_yaml(text)
    except ValueError as e:
        raise UsageError(f"--noise {path}: {e}") from None


def _run_export(args: argparse.Namespace) -> int:
    from jaxcal import formats
    from jaxcal.formats.linear_io import EQUATION
    from jaxcal.methods import ModelError
    from jaxcal.model_file import load_model

    fmt = formats.get(args.format)
    if not args.out.lower().endswith(fmt.suffix):
        raise UsageError(f"--out {args.out}: the {args.format} export is written as {fmt.suffix}")
    datasheet = {k: v if len(v) > 1 else v[0] for k, v in (("acc_lsb_per_g", args.acc_lsb_per_g),
                                                          ("gyr_lsb_per_rads", args.gyr_lsb_per_rads)) if v is not None}
    given = {"noise": args.noise is not None, "units": args.units is not None, "datasheet": bool(datasheet)}
    for opt in [o for o, g in given.items() if g and o not in fmt.export_options]:
        takes = " or ".join(f.name for f in formats.REGISTRY.values() if opt in f.export_options)
        flag = {"datasheet": "--acc-lsb-per-g / --gyr-lsb-per-rads"}.get(opt, f"--{opt}")
        raise UsageError(f"{flag} goes with --format {takes}, not {args.format}")
    if any(len(v) not in (1, 3) for v in (args.acc_lsb_per_g, args.gyr_lsb_per_rads) if v is not None):
        raise UsageError("--acc-lsb-per-g / --gyr-lsb-per-rads take one value or three")
    if datasheet and args.units == "model":
        raise UsageError("--acc-lsb-per-g / --gyr-lsb-per-rads convert a raw model to a ROS driver's input: they go with --units ros")
    _check_out_file(args.out, [args.model] + ([args.noise] if args.noise else []))
    noise = _read_noise(args.noise) if args.noise is not None else None
    model = load_model(args.model)
    try:
        exported = formats.export(args.format, model, formats.ExportOptions(args.name, noise, args.units or "ros", datasheet))
    except ModelError as e:  # a non-linear model, a missing sensor, a singular matrix: say which file
        raise ModelError(f"{args.model}: {e}") from None
    missing, note = exported.missing_noise, ""
    if missing and noise is None:
        note = f"; no IMU noise keys ({', '.join(missing)}): pass --noise imu.yaml (e.g. from `{PROG} noise`)"
    elif missing:
        note = f"; --noise {args.noise} has no {', '.join(missing)}"
    try:
        with atomic_output(args.out) as tmp, open(tmp, "w", encoding="utf-8") as fh:
            fh.write(exported.text)
    except OSError as e:
        raise UsageError(f"{args.out}: cannot write ({e.strerror or e})") from None
    print(f"{PROG}: wrote {args.out} ({args.format}: {model.method} model, {EQUATION} for "
          f"{', '.join(model.sensors)}){note}", file=sys.stderr)
    if exported.not_carried:
        print(f"{PROG}: not carried into {args.out} (said in its header): {'; '.join(exported.not_carried)}", file=sys.stderr)
    return 0


register_command(
    "export",
    Command(
        "write a linear model as plain JSON, a C99 header, Kalibr/OpenVINS IMU intrinsics or imucal's CalibrationInfo",
        _add_export,
        _run_export,
        "Write the linear calibration x = A @ (y - b) of each sensor of MODEL (methods linear, multipos, "
        "online) as plain JSON (--format json) or a dependency-free C99 header with an apply function "
        "(--format c), as Kalibr's scale-misalignment / OpenVINS's kalibr_imu_chain.yaml IMU intrinsics "
        "(--format kalibr|openvins: YAML, acc in m/s^2 and gyr in rad/s from what a ROS driver publishes in "
        "sensor_msgs/Imu, the driver's conversion written in the file; --units model: from raw samples in the "
        "model's input unit; both sensors needed; --noise adds a Kalibr imu.yaml's noise keys; what the file "
        "cannot carry is said in its header and on one stderr line), or as imucal's "
        "FerrarisCalibrationInfo JSON (--format imucal: m/s^2 and deg/s, read by imucal's "
        "CalibrationInfo.from_json_file). Each file states its convention. Non-linear models (nn, cubic, "
        "online-thesis) are refused.",
    ),
)


# ----------------------------------------------------------------------------- import-model


def _add_import_model(p: argparse.ArgumentParser) -> None:
    from jaxcal import formats

    p.add_argument("format", metavar="FORMAT", choices=formats.importers(),
                   help="imucal: imucal's CalibrationInfo JSON (Ferraris, Turntable; written by imucal or by "
                   "`jaxcal export --format imucal`); json: `jaxcal export --format json`; kalibr, openvins: the YAML "
                   "`jaxcal export --format kalibr|openvins` writes")
    p.add_argument("file", metavar="FILE", help="the calibration file to read")
    p.add_argument("--out", required=True, metavar="MODEL", help="model file to write (.npz), method linear")
    p.add_argument("--drop-g-sensitivity", action="store_true",
                   help="import a gyroscope g-sensitivity (imucal K_ga, Kalibr A, OpenVINS Tg) as zero instead of "
                   "into the model's state/gyr/G (which `jaxcal apply` applies with the calibrated accelerometer)")


def _run_import_model(args: argparse.Namespace) -> int:
    from jaxcal import formats
    from jaxcal.formats.linear_io import g_sensitivity
    from jaxcal.methods import ModelError
    from jaxcal.model_file import save_model

    if not args.out.lower().endswith(".npz"):
        raise UsageError(f"--out {args.out}: model files are .npz")
    _check_out_file(args.out, [args.file])
    try:
        text = Path(args.file).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise UsageError(f"{args.file}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    try:
        imported = formats.import_model(args.format, formats.read_document(args.format, text), args.drop_g_sensitivity)
    except ModelError as e:
        raise ModelError(f"{args.file}: {e}") from None
    model = imported.model
    model.meta["imported_from"]["file"] = os.path.basename(args.file)
    save_model(model, args.out)
    notes = "".join(f"; {n}" for n in imported.notes)
    units = ", ".join(f"{s} {model.meta['units'][s]}" for s in model.sensors)
    if g_sensitivity(model) is not None:
        notes += "; with the gyroscope g-sensitivity (state/gyr/G)"
    print(f"{PROG}: wrote {args.out} (linear model from {args.format} {args.file}; input units {units}){notes}",
          file=sys.stderr)
    return 0


register_command(
    "import-model",
    Command(
        "read an imucal, jaxcal JSON, Kalibr or OpenVINS calibration file as a jaxcal linear model",
        _add_import_model,
        _run_import_model,
        "Read FILE, a calibration in FORMAT (imucal: imucal's FerrarisCalibrationInfo JSON, written by imucal or "
        "jaxcal; json: jaxcal's plain JSON export; kalibr, openvins: the YAML jaxcal exports), and write it as a "
        "jaxcal model of method linear that `jaxcal apply` uses; a non-zero gyroscope g-sensitivity becomes its "
        "state/gyr/G (unless --drop-g-sensitivity). What a linear model cannot hold (a lever arm, another IMU "
        "model) is refused with one line; assumptions (a bias or unit the file lacks) are printed.",
    ),
)
