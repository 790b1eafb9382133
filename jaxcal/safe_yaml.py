"""Bounded YAML loading for the files jaxcal reads (Kalibr / OpenVINS calibrations, ``imu.yaml``).

``yaml.safe_load`` builds no arbitrary objects, but it expands aliases: ten lines of nested
anchors (``a: &a [x, x, ...]``, ``b: &b [*a, *a, ...]``, ...) become billions of nodes as soon as
anything walks the result (issue 27: 8 GB in a minute). :func:`load_yaml` composes the node graph
first (aliases stay shared there), counts the nodes the result would hold with every alias
expanded, and refuses more than ``max_nodes``, a text over ``max_chars`` or nesting deeper than
``max_depth``, before anything is built. Pure: text in, plain Python data out.
"""

from __future__ import annotations

from typing import Any

import yaml

__all__ = ["YamlLimitError", "load_yaml", "MAX_CHARS", "MAX_NODES", "MAX_DEPTH"]

MAX_CHARS = 1 << 20  # a calibration file is a few kB
MAX_NODES = 100_000  # nodes after alias expansion
MAX_DEPTH = 64


class YamlLimitError(ValueError):
    """A YAML text beyond :func:`load_yaml`'s bounds (one line)."""


def _expanded(node: yaml.Node, memo: dict[int, int], depth: int, max_depth: int, stack: set[int]) -> int:
    """Nodes under ``node`` (itself included) with aliases expanded; shared nodes counted once per use."""
    k = id(node)
    if k in memo:
        return memo[k]
    if depth > max_depth:
        raise YamlLimitError(f"nested deeper than {max_depth} levels")
    if k in stack:
        raise YamlLimitError("an alias refers to its own ancestor (a recursive structure)")
    stack.add(k)
    n = 1
    if isinstance(node, yaml.SequenceNode):
        n += sum(_expanded(c, memo, depth + 1, max_depth, stack) for c in node.value)
    elif isinstance(node, yaml.MappingNode):
        n += sum(_expanded(a, memo, depth + 1, max_depth, stack) + _expanded(b, memo, depth + 1, max_depth, stack)
                 for a, b in node.value)
    stack.discard(k)
    memo[k] = n
    return n


def load_yaml(text: str, max_chars: int = MAX_CHARS, max_nodes: int = MAX_NODES, max_depth: int = MAX_DEPTH) -> Any:
    """``yaml.safe_load(text)`` within bounds.

    Args:
        text: the YAML text.
        max_chars: longest text accepted.
        max_nodes: most nodes the loaded value may hold, every alias expanded.
        max_depth: deepest nesting accepted.

    Raises:
        YamlLimitError: beyond a bound (one line, nothing expanded).
        yaml.YAMLError: text that does not parse.
    """
    if len(text) > max_chars:
        raise YamlLimitError(f"{len(text)} characters, more than the {max_chars} a calibration file needs")
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except RecursionError:
        raise YamlLimitError("nested too deeply to parse") from None
    if node is None:
        return None
    size = _expanded(node, {}, 0, max_depth, set())
    if size > max_nodes:
        raise YamlLimitError(f"its aliases expand to {size:.3g} values, more than {max_nodes} (an alias bomb?)")
    loader = yaml.SafeLoader(text)
    try:
        return loader.get_single_data()
    finally:
        loader.dispose()
