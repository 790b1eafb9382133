"""The diagnosis of a recording: a mode prepares it, the shared stages diagnose each sensor.

A mode is a choice of residual: the reference mode prepares a recording against its reference
motion (:func:`~jaxcal.diagnose.prepare.prepare`), the reference-free mode against itself
(:func:`jaxcal.diagnose.noref.prepare_noref`); both hand a
:class:`~jaxcal.diagnose.prepare.Prepared` to the same stages (:mod:`jaxcal.diagnose.stages`:
coarse offset -> baseline fit -> candidate tests and selection -> detectability -> the promise and
the refit with intervals). What else differs between modes is one :class:`Mode` record.
:func:`diagnose_sensors` runs the stages over the sensors of one recording (one Bonferroni family).

This module re-exports the names that lived here before the stages were split out
(``prepare``, ``Prepared``, ``SensorResult``, ``diagnose_sensor``, ...).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import NamedTuple

from jaxcal.diagnose.effects import EXCITE
from jaxcal.diagnose.handoffs import SensorResult
from jaxcal.diagnose.prepare import Prepared, measured_inputs, prepare, require_recording, split_blocks
from jaxcal.diagnose.select import SelectConfig, candidates
from jaxcal.diagnose.stages import FORCED, UNIT_OF, diagnose_sensor
from jaxcal.recording import Recording

__all__ = [
    "EXCITE",
    "Prepared",
    "require_recording",
    "split_blocks",
    "prepare",
    "measured_inputs",
    "SensorResult",
    "UNIT_OF",
    "FORCED",
    "Mode",
    "REFERENCE",
    "count_tests",
    "diagnose_sensor",
    "diagnose_sensors",
    "diagnose_prepared",
    "diagnose_banded",
]


def _same_config(sensor: str, cfg: SelectConfig) -> SelectConfig:
    return cfg


def _keep_all(sensor: str, warning: str) -> bool:
    return True


class Mode(NamedTuple):
    """What a mode of ``diagnose`` sets besides its residual (host side, static).

    Args:
        name: the report's ``"reference"`` (``"motion"``, ``"none"``).
        share_clock: the gyroscope's coarse clock offset guides the accelerometer's search (both
            are compared with one reference clock).
        sensor_config: ``(sensor, cfg) -> cfg`` the settings of one sensor's stages.
        keep_warning: ``(sensor, warning) -> bool``, the warnings that apply in this mode.
    """

    name: str
    share_clock: bool = True
    sensor_config: Callable[[str, SelectConfig], SelectConfig] = _same_config
    keep_warning: Callable[[str, str], bool] = _keep_all


REFERENCE = Mode("motion")
"""Against the reference motion (mocap, labels): the residual of :func:`prepare`."""


def count_tests(kind: str, prep: Prepared, cfg: SelectConfig = SelectConfig(), mode: Mode | None = None) -> int:
    """The Bonferroni count of a prepared recording: the candidates of all its sensors that the
    mode tests (``mode.sensor_config``'s ``exclude``), and a saturation test per sensor in raw counts.

    Args:
        kind: baseline, ``"diag"`` or ``"affine"``.
        prep: the prepared recording.
        cfg: test level and search settings.
        mode: the mode (None: the reference mode's, which excludes nothing by default).
    """
    conf = (lambda s: cfg) if mode is None else (lambda s: mode.sensor_config(s, cfg))
    return sum(len(candidates(kind, sd, conf(s).exclude)) + (sd.raw is not None) for s, sd in prep.sensors.items())


def diagnose_sensors(preps: Mapping[str, Prepared], kind: str, cfg: SelectConfig, n_tests: int,
                     force: Mapping[str, tuple[str, ...]] | None = None, mode: Mode = REFERENCE) -> dict[str, SensorResult]:
    """:func:`~jaxcal.diagnose.stages.diagnose_sensor` for every sensor, each from its own
    :class:`Prepared` (``preps[s].sensors[s]``), the gyroscope first (with ``mode.share_clock``
    its coarse clock offset, the sharper, guides the accelerometer's search). Returns
    ``{sensor: SensorResult}`` in the order of ``preps``.

    Args:
        preps: ``{sensor: Prepared}``; one shared :class:`Prepared` may serve every sensor.
        kind: baseline, ``"diag"`` or ``"affine"``.
        cfg: test level and search settings.
        n_tests: the Bonferroni count (:func:`count_tests`).
        force: ``{sensor: effect names}`` estimated whatever the tests say; None: none.
        mode: the mode's settings.
    """
    force = dict(force or {})
    out: dict[str, SensorResult] = {}
    for s in sorted(preps, key=lambda k: k != "gyr"):
        ps = preps[s]
        hint = None
        if mode.share_clock and s != "gyr" and "gyr" in out and out["gyr"].tau_lin != 0.0:
            hint = int(round(out["gyr"].tau_lin / ps.dt))
        res = diagnose_sensor(kind, ps.sensors[s], mode.sensor_config(s, cfg), n_tests, meas=measured_inputs(ps, s),
                              force=tuple(force.get(s, ())), lag_hint=hint)
        out[s] = res._replace(warnings=[w for w in res.warnings if mode.keep_warning(s, w)])
    return {s: out[s] for s in preps}


def diagnose_prepared(prep: Prepared, kind: str, cfg: SelectConfig = SelectConfig(),
                      force: Mapping[str, tuple[str, ...]] | None = None) -> dict[str, SensorResult]:
    """:func:`diagnose_sensors` for every sensor of one :class:`Prepared` recording (one Bonferroni
    family over all of them) against its reference motion; ``force`` per sensor.

    Args:
        prep: a prepared recording (:func:`prepare`).
        kind: baseline, ``"diag"`` or ``"affine"``.
        cfg: test level and search settings.
        force: ``{sensor: effect names}`` estimated whatever the tests say; None: none.
    """
    return diagnose_sensors({s: prep for s in prep.sensors}, kind, cfg, count_tests(kind, prep), force)


def diagnose_banded(rec: Recording, kind: str, cfg: SelectConfig = SelectConfig(), force: Mapping[str, tuple[str, ...]] | None = None,
                    pose_sigma: float | None = None) -> tuple[dict[str, Prepared], dict[str, SensorResult]]:
    """Prepare and diagnose a recording, each sensor in its own trusted band.

    With a pose-derived reference and ``pose_sigma=None``, :mod:`jaxcal.diagnose.band` may give
    the accelerometer a wider kernel than the gyroscope (the position's second derivative is
    noisier than the rotation's first); each sensor is then prepared with its own kernel and
    decimation and diagnosed there, the gyroscope first (its clock offset guides the
    accelerometer's search). Returns ``({sensor: Prepared},
    {sensor: SensorResult})``; one shared :class:`Prepared` when a single kernel serves both.

    Args:
        rec: the recording.
        kind: baseline, ``"diag"`` or ``"affine"``.
        cfg: test level and search settings.
        force: ``{sensor: effect names}`` estimated whatever the tests say; None: none.
        pose_sigma: Gaussian width (s) of a pose-derived reference; None chooses it per sensor.
    """
    prep = prepare(rec, pose_sigma=pose_sigma)
    if not prep.sensors:
        raise ValueError("no sensor with a matching reference to diagnose")
    sig = prep.sigma_by_sensor or {}
    if prep.band is None or len(set(sig.values())) <= 1:
        res = diagnose_prepared(prep, kind, cfg, force)
        return {s: prep for s in res}, res
    preps = {s: (prep if sig[s] == prep.pose_sigma else prepare(rec, pose_sigma=sig[s], band=prep.band))._replace(
        band=prep.band, sigma_by_sensor=sig) for s in prep.sensors}
    return preps, diagnose_sensors(preps, kind, cfg, count_tests(kind, prep), force)
