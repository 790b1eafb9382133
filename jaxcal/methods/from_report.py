"""What a ``jaxcal diagnose`` report names, as a calibration method's options (issue 26: "use what
``diagnose`` finds").

A method's options type may declare ``EFFECTS = {(sensor, effect): field}``: a boolean option that
puts that vocabulary effect into the method's model (``online`` and ``multipos``: the gyroscope's
``g_sensitivity``). :func:`options_from_report` switches on the options of the effects a report
names and lists the named effects the method's model cannot hold. Effects the report only
estimated on request (``forced``) are not findings and are passed over.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

__all__ = ["FromReport", "named_in_report", "options_from_report"]


class FromReport(NamedTuple):
    """The options with the report's findings switched on, and what was and was not used.

    Attributes:
        options: the method's options.
        modelled: ``"sensor effect"`` of each named effect the options now model.
        not_modelled: ``"sensor effect"`` of each named effect the method's model has no option for.
    """

    options: Any
    modelled: tuple[str, ...]
    not_modelled: tuple[str, ...]


def named_in_report(report: Any) -> tuple[tuple[str, str], ...]:
    """The ``(sensor, effect)`` pairs a ``report.json`` dict names as findings (not ``forced``), in
    its order; ``ValueError`` if it is not a report (``docs/CONVENTIONS.md``)."""
    effects = report.get("effects") if isinstance(report, Mapping) else None
    if not isinstance(effects, list):
        raise ValueError("not a `jaxcal diagnose` report: no `effects` list")
    out = []
    for i, e in enumerate(effects):
        if not (isinstance(e, Mapping) and isinstance(e.get("sensor"), str) and isinstance(e.get("name"), str)):
            raise ValueError(f"not a `jaxcal diagnose` report: effects[{i}] has no `sensor` and `name`")
        if not e.get("forced", False) and (e["sensor"], e["name"]) not in out:
            out.append((e["sensor"], e["name"]))
    return tuple(out)


def options_from_report(options: Any, report: Any) -> FromReport:
    """``options`` with the boolean option of every effect ``report`` names switched on.

    Args:
        options: a method's options (a NamedTuple; its type's ``EFFECTS`` maps ``(sensor, effect)``
            to a field; a type without one models none).
        report: a ``report.json`` dict of ``jaxcal diagnose`` (with or without a reference).
    """
    table: Mapping[tuple[str, str], str] = getattr(type(options), "EFFECTS", {})
    modelled, not_modelled, on = [], [], {}
    for sensor, name in named_in_report(report):
        field = table.get((sensor, name))
        (modelled if field else not_modelled).append(f"{sensor} {name}")
        if field:
            on[field] = True
    return FromReport(options._replace(**on), tuple(modelled), tuple(not_modelled))
