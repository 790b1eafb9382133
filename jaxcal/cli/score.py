"""``jaxcal score``: a model's figures on another recording (held out when the model was not fitted
on it), against every truth that recording carries: labels, ``seq`` ids, rests, its mocap.

::

    jaxcal score MODEL.npz RECORDING [--out SCORE.json] [--rest-bias SEC] [--allow-extrapolation]

The scoring is :func:`jaxcal.eval.transfer.score_outputs` of ``jaxcal apply``'s output; one line per
row is printed, and ``--out`` writes the rows as JSON.
"""

from __future__ import annotations

import argparse
import json

from jaxcal.cli.core import PROG, Command, UsageError, _check_out_file, _progress, _real, register_command
from jaxcal.recording import atomic_output

__all__: list[str] = []

_TITLE = {"labels": "labels", "sequences": "sequence ends", "rests": "rests", "mocap": "mocap"}


def _add_score(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", metavar="MODEL", help="model file written by `jaxcal calibrate` or `diagnose --model-out`")
    p.add_argument("recording", metavar="RECORDING",
                   help="recording to score it on (.npz or .csv): labels (acc_ref, gyr_ref), seq ids, rests between "
                        "motions, or a pose reference (mocap); held out when the model was fitted on another recording")
    p.add_argument("--out", metavar="SCORE.json", default=None, help="also write the rows as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    p.add_argument("--rest-bias", type=_real(0.0), default=None, metavar="SEC",
                   help="score with this power-up's gyro bias (the mean calibrated gyro over the first SEC seconds, at "
                        "rest) in place of the model's, as `jaxcal apply --rest-bias` writes it")
    p.add_argument("--allow-extrapolation", action="store_true",
                   help="score even where the recording lies outside the model's fitted range (warn instead of refusing)")


def _run_score(args: argparse.Namespace) -> int:
    from jaxcal.cli.calibrate import applied_output, rest_bias
    from jaxcal.eval.transfer import score_outputs
    from jaxcal.methods.summary import quality_text

    if args.out is not None:
        if not args.out.lower().endswith(".json"):
            raise UsageError(f"--out {args.out}: the scores are written as .json")
        _check_out_file(args.out, [args.model, args.recording])
    model, rec, out = applied_output(args.model, args.recording, args.allow_extrapolation)
    if args.rest_bias is not None:
        out = rest_bias(out, rec, args.rest_bias, _progress(args))
    rows = score_outputs(rec, out)
    if not rows:
        raise UsageError(f"{args.recording}: nothing to score against: no labels (acc_ref, gyr_ref), no pose reference "
                         "(pos_ref, quat_ref), and rests and seq ids need both acc and gyr")
    print(f"{args.model} ({model.method}) on {args.recording}:")
    for name, row in rows.items():
        print(f"  {_TITLE[name]}: {quality_text(row)}")
    if args.out is not None:
        doc = {"model": args.model, "method": model.method, "recording": args.recording, "rest_bias_s": args.rest_bias,
               "scores": rows}
        try:
            with atomic_output(args.out) as tmp:
                tmp.write_text(json.dumps(doc, indent=1) + "\n")
        except OSError as e:
            raise UsageError(f"{args.out}: cannot write ({e.strerror or e})") from None
        print(f"{PROG}: wrote {args.out}")
    return 0


register_command(
    "score",
    Command(
        "score a model on another recording (labels, seq ids, rests, mocap)",
        _add_score,
        _run_score,
        "Apply MODEL to RECORDING and score the output against every truth the recording carries: its labels "
        "(RMS, mg and deg/s), each sequence's first and last samples (seq ids), its rests and the motions between them "
        "(| |f| - 1 g | RMS, carried-gravity median), its pose reference (RMS in the trusted band). The items are chosen "
        "from the recording alone, so two models are scored on the same ones. Held out when MODEL was fitted on "
        "another recording.",
    ),
)
