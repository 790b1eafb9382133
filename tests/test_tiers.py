"""The two tiers of the suite: ``make test`` (``-m 'not slow'``) and ``make test-all`` (everything).

A long check may move to the slow tier only if a fast test still covers its property (issue 30:
"move long checks behind `slow`, each naming the fast test that still covers its property"). The
slow test says so in its docstring, on a line ``Fast cover: tests/FILE.py::TEST`` (one or more ids,
comma separated; a parametrised slow case says it in its function's docstring). This module checks
every such claim from the source alone: each slow test names at least one cover, and each cover is
a test function that exists in that file and is not itself in the slow tier.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

TESTS = Path(__file__).resolve().parent
COVER = re.compile(r"Fast cover:\s*(.+?)(?:\n\s*\n|$)", re.S)
TEST_ID = re.compile(r"tests/(\w+\.py)::(\w+)")


def _is_slow_mark(node: ast.AST) -> bool:
    """``pytest.mark.slow`` (bare or called)."""
    node = node.func if isinstance(node, ast.Call) else node
    return isinstance(node, ast.Attribute) and node.attr == "slow" and ast.unparse(node).endswith("mark.slow")


def _has_slow_param(fn: ast.FunctionDef) -> bool:
    """A ``pytest.param(..., marks=pytest.mark.slow)`` among the function's parametrisations."""
    for dec in fn.decorator_list:
        for sub in ast.walk(dec):
            if isinstance(sub, ast.keyword) and sub.arg == "marks" and any(_is_slow_mark(n) for n in ast.walk(sub.value)):
                return True
    return False


def _tests_of(path: Path) -> dict[str, tuple[bool, bool, str]]:
    """Every top-level ``test_*`` function of a file: (whole test slow, some case slow, docstring)."""
    tree = ast.parse(path.read_text())
    module_slow = any(
        isinstance(n, ast.Assign) and any(getattr(t, "id", "") == "pytestmark" for t in n.targets)
        and any(_is_slow_mark(m) for m in ast.walk(n.value))
        for n in tree.body
    )
    out = {}
    for fn in tree.body:
        if isinstance(fn, ast.FunctionDef) and fn.name.startswith("test_"):
            slow = module_slow or any(_is_slow_mark(d) for d in fn.decorator_list)
            out[fn.name] = (slow, _has_slow_param(fn), ast.get_docstring(fn) or "")
    return out


def covers_named(doc: str) -> list[tuple[str, str]]:
    """The ``(file, test)`` ids on a docstring's ``Fast cover:`` line(s)."""
    return [m for block in COVER.findall(doc) for m in TEST_ID.findall(block)]


ALL = {p.name: _tests_of(p) for p in sorted(TESTS.glob("test_*.py"))}


def test_cover_lines_are_read():
    doc = "Checks X.\n\nFast cover: tests/test_a.py::test_b,\n    tests/test_c.py::test_d (the d part).\n"
    assert covers_named(doc) == [("test_a.py", "test_b"), ("test_c.py", "test_d")]
    assert covers_named("no cover here") == []


def test_every_slow_test_names_a_fast_test_that_exists():
    missing, wrong = [], []
    for fname, tests in ALL.items():
        for name, (slow, slow_case, doc) in tests.items():
            if not (slow or slow_case):
                continue
            ids = covers_named(doc)
            if not ids:
                missing.append(f"{fname}::{name}")
            for f, t in ids:
                if t not in ALL.get(f, {}) or ALL[f][t][0]:
                    wrong.append(f"{fname}::{name} -> {f}::{t}")
    assert not missing, f"slow tests that name no fast cover ('Fast cover: tests/FILE.py::TEST'): {missing}"
    assert not wrong, f"named covers that do not exist or are slow themselves: {wrong}"


def test_the_fast_tier_is_most_of_the_suite():
    """The slow tier holds the long end-to-end checks, not the suite: fewer than 1 in 10 tests."""
    n = sum(len(t) for t in ALL.values())
    slow = sum(s for t in ALL.values() for s, _, _ in t.values())
    assert n > 300 and slow < n / 10, (slow, n)
