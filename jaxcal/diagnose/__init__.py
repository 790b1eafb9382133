"""``jaxcal diagnose``: find the physics a sensor model left out, name it, model it, prove the fit.

Pipeline (CONVENTIONS.md "Discrepancy vocabulary"; every stage a pure function handing a typed
result to the next):

1. :func:`~jaxcal.diagnose.prepare.prepare`: reference motion (given or derived from a pose),
   physical outputs, train / held-out time blocks -> :class:`~jaxcal.diagnose.prepare.Prepared`.
   Without a reference motion, :func:`~jaxcal.diagnose.noref.prepare_noref` builds the same
   :class:`~jaxcal.diagnose.prepare.Prepared` from the IMU itself (the accelerometer against the
   gravity the gyroscope carries, the gyroscope at rest): a mode is a choice of residual
   (:class:`~jaxcal.diagnose.core.Mode`), and steps 2-5 run unchanged (``"reference": "none"``).
2. :mod:`~jaxcal.diagnose.offset`: coarse time-offset search; baseline fit (``diag``: thesis
   eq. 4.6, or ``affine``: eq. 2.3) and regressors of every vocabulary effect
   (:mod:`~jaxcal.diagnose.vocabulary`, one record per effect) by JAX autodiff.
3. :mod:`~jaxcal.diagnose.stages` / :mod:`~jaxcal.diagnose.select`: AR-prewhitened chi-square
   tests, forward selection gated by held-out improvement, minimum detectable sizes, confounding
   and excitation warnings; :mod:`~jaxcal.diagnose.locate` says where a residual lives.
4. The promise (every named effect lowers the printed held-out rms and lies in its plausible
   range) and :mod:`~jaxcal.diagnose.refit`: joint optimistix refit of baseline + named effects,
   with standard errors.
5. :mod:`~jaxcal.diagnose.report`: ``report.json`` dict, ``report.md``, figures.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

from jaxcal.diagnose.core import diagnose_banded, diagnose_prepared, prepare
from jaxcal.diagnose.noref import NorefConfig, diagnose_noref, has_reference, noref_report
from jaxcal.diagnose.report import build_report_banded, figures, figures_banded, report_markdown, write_report
from jaxcal.diagnose.select import SelectConfig
from jaxcal.recording import Recording

__all__ = ["diagnose_recording", "noref_report", "NorefConfig", "diagnose_banded", "diagnose_prepared", "SelectConfig", "prepare", "report_markdown", "write_report"]


def diagnose_recording(
    rec: Recording,
    baseline: str = "diag",
    out_dir=None,
    config: SelectConfig = SelectConfig(),
    pose_sigma: float | None = None,
    with_figures: bool | None = None,
    force: Mapping[str, tuple[str, ...]] | None = None,
    keep_fit: bool = False,
    reference: str = "auto",
    noref: NorefConfig = NorefConfig(),
) -> dict:
    """Diagnose a recording against the baseline sensor model; returns the ``report.json`` dict.

    Args:
        rec: :class:`jaxcal.recording.Recording` (build one from arrays with
            :func:`jaxcal.recording.recording_from_dict`): ``t``, ``acc``/``gyr`` (LSB with spec
            metadata, or g / rad/s with ``*_unit``), and the reference motion (``acc_ref``/``gyr_ref``,
            or ``pos_ref`` + ``quat_ref``), optional ``temp``.
        baseline: ``"diag"`` (default, thesis eq. 4.6) or ``"affine"`` (eq. 2.3).
        out_dir: if given, ``report.json``, ``report.md`` and the figures are written there.
        config: test level, power for detectable sizes, coarse time-offset range, ...
        pose_sigma: smoothing (s) when the reference is derived from a pose; None (default): each
            sensor's from where the reference keeps its gain against it (:mod:`jaxcal.diagnose.band`).
        with_figures: build figures (default: only when ``out_dir`` is given); returned under the
            report's ``"_figures"`` key when built without ``out_dir``.
        force: per sensor, effects estimated whatever the tests say (``{"acc": ("lever_arm",
            "time_offset")}``; :func:`jaxcal.diagnose.align.align_recording` uses it, and
            ``experiments/field_diagnose.py`` to measure the coverage of concealed effects).
        keep_fit: also return the diagnosis itself, ``(preps, results)`` of
            :func:`diagnose_banded`, under the report's ``"_fit"`` key (``jaxcal diagnose
            --model-out`` turns it into a ``diagnosed`` model with
            :func:`jaxcal.methods.diagnosed.diagnosed_model_state`); reference mode only.
        reference: ``"auto"`` (default): against the reference motion when the recording has one,
            otherwise against itself (:mod:`jaxcal.diagnose.noref`); ``"motion"``: require one;
            ``"none"``: ignore any reference and diagnose from the IMU's self-consistency.
        noref: settings of the reference-free mode.

    Raises:
        TypeError: ``rec`` is not a :class:`~jaxcal.recording.Recording`.
        ValueError: bad input (no reference motion, unknown baseline, too few samples).
    """
    if baseline not in ("diag", "affine"):
        raise ValueError(f"unknown baseline {baseline!r} (expected diag or affine)")
    if reference not in ("auto", "motion", "none"):
        raise ValueError(f"unknown reference {reference!r} (expected auto, motion or none)")
    t0 = time.perf_counter()
    build_figs = (out_dir is not None) if with_figures is None else with_figures
    if reference == "none" or (reference == "auto" and not has_reference(rec)):
        prep, results, ref = diagnose_noref(rec, baseline, config, noref, force)
        rep = noref_report(prep, results, ref, baseline, time.perf_counter() - t0, noref)
        figs = figures(prep, results) if build_figs else None
        preps = {s: prep for s in results}
    else:
        preps, results = diagnose_banded(rec, baseline, config, force, pose_sigma)
        rep = build_report_banded(preps, results, baseline, time.perf_counter() - t0)
        figs = figures_banded(preps, results) if build_figs else None
    if out_dir is not None:
        write_report(out_dir, rep, figs)
        if figs:
            import matplotlib.pyplot as plt

            for f in figs.values():
                plt.close(f)
    elif figs:
        rep["_figures"] = figs
    if keep_fit:
        rep["_fit"] = (preps, results)
    return rep
