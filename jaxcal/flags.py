"""Command-line flags of typed options: the :class:`Flag` record and its value parsers.

A method's options type (a ``NamedTuple``, :mod:`jaxcal.methods`) declares the flags of its fields
in a class attribute ``FLAGS: dict[field, Flag]``; ``jaxcal calibrate`` builds its flags from the
registered methods' declarations (a field several types share is declared once and reused), so a
new option needs no edit in :mod:`jaxcal.cli`. A reader (:class:`jaxcal.formats.Format`) declares
its keyword options' flags the same way (``Format.flags``), read by ``jaxcal import``. The parsers are argparse types: text in, a value
out, ``argparse.ArgumentTypeError`` with a one-line message on bad text. No I/O.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import Any, NamedTuple

from jaxcal.constants import SENSORS

__all__ = ["SEED_MAX", "Flag", "choice", "count", "degs_to_rads", "int_tuple", "mapping", "real", "seed", "sensors", "turns"]

SEED_MAX = 2**32 - 1  # jax.random.PRNGKey takes 32-bit seeds; larger ones overflow or alias


class Flag(NamedTuple):
    """A command-line flag of an option field.

    Args:
        flag: the flag, e.g. ``--lr``.
        parse: text -> the flag's value (raises ``argparse.ArgumentTypeError``); ``None`` for a
            switch (``const`` is its value).
        conv: the flag's value -> the option's (e.g. deg/s -> rad/s), or ``None``.
        help: what it does (the methods that take it and the default are added).
        metavar: the value's name in the help.
        const: the value of a switch (``parse`` is ``None``).
        show_default: the default as the help shows it (``None``: the option's default).
        choices: the values the flag takes, checked by argparse and shown as ``{a,b}`` when there is no
            ``metavar`` (``None``: any that ``parse`` takes).
    """

    flag: str
    parse: Callable[[str], Any] | None
    conv: Callable[[Any], Any] | None
    help: str
    metavar: str | None = None
    const: Any = None
    show_default: Any = None
    choices: tuple[str, ...] | None = None


def seed(text: str) -> int:
    """A PRNG seed: an integer in [0, 2**32 - 1]."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer seed, got {text!r}") from None
    if not 0 <= v <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"seed must lie in [0, {SEED_MAX}], got {text}")
    return v


def real(low: float, high: float = math.inf, *, open_low: bool = True) -> Callable[[str], float]:
    """An argparse type: a finite float in ``(low, high]`` (``[low, high]`` if not ``open_low``)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        inside = (v > low if open_low else v >= low) and v <= high
        if not (math.isfinite(v) and inside):
            rng = f"{'(' if open_low else '['}{low:g}, {high:g}{']' if math.isfinite(high) else ')'}"
            raise argparse.ArgumentTypeError(f"expected a finite number in {rng}, got {text!r}")
        return v

    return parse


def count(low: int, high: int) -> Callable[[str], int]:
    """An argparse type: an integer in ``[low, high]``."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not low <= v <= high:
            raise argparse.ArgumentTypeError(f"expected an integer in [{low}, {high}], got {text}")
        return v

    return parse


def choice(*names: str) -> Callable[[str], str]:
    """An argparse type: one of ``names``."""

    def parse(text: str) -> str:
        if text not in names:
            raise argparse.ArgumentTypeError(f"expected one of {', '.join(names)}, got {text!r}")
        return text

    return parse


def mapping(text: str) -> dict[str, str]:
    """``NAME=VALUE[,NAME=VALUE...]`` as a dict (names and values stripped)."""
    out = {}
    for item in text.split(","):
        if "=" not in item:
            raise argparse.ArgumentTypeError(f"expected NAME=VALUE[,NAME=VALUE...], got {text!r}")
        k, v = item.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def int_tuple(text: str) -> tuple[int, ...]:
    """Comma- or space-separated positive integers (layer widths)."""
    try:
        vals = tuple(int(v) for v in text.replace(",", " ").split())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not vals or any(v <= 0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected positive layer widths, got {text!r}")
    return vals


def sensors(text: str) -> tuple[str, ...]:
    """``acc``, ``gyr`` or ``acc,gyr``."""
    vals = tuple(v for v in text.replace(",", " ").split())
    if not vals or any(v not in SENSORS for v in vals):
        raise argparse.ArgumentTypeError(f"expected acc, gyr or acc,gyr, got {text!r}")
    return vals


def turns(text: str) -> tuple[tuple[float, float], ...]:
    """``START-END[,START-END...]`` in seconds, each ``START < END``."""
    try:
        out = tuple(tuple(float(x) for x in part.split("-")) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START-END[,START-END...] in seconds, got {text!r}") from None
    if not all(math.isfinite(v) for x in out for v in x):
        raise argparse.ArgumentTypeError(f"turn times must be finite numbers of seconds, got {text!r}")
    if any(len(x) != 2 or x[1] <= x[0] for x in out):
        raise argparse.ArgumentTypeError(f"each turn needs START-END with START < END, got {text!r}")
    return out


def degs_to_rads(v: float) -> float:
    """deg/s -> rad/s (a flag in degrees for an option in radians)."""
    return v * math.pi / 180.0
