"""The suite's run-time type checks (``tests/typecheck.py``): which functions get which checker,
and that ``jaxcal`` is checked in this very run."""

from __future__ import annotations

import ast

import numpy as np
import pytest
import typecheck

SOURCE = '''
from jaxtyping import Float as F
def arrays(x: F[Array, "N 3"]) -> float: ...
def quoted(x: "F[Array, 'N']"): ...
def scalars(x: float, name: str = "a") -> int: ...
def bare(x, y=1): ...
@no_type_check
def opted_out(x: F[Array, "N"]):
    def inner(y: float): ...
class Model:
    def method(self, x: F[Array, "3"]) -> None: ...
'''


def _decorators():
    tree = typecheck.instrument_source(SOURCE)
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            out[node.name] = [ast.unparse(d) for d in node.decorator_list]
    return out


def test_each_function_gets_the_checker_its_annotations_need():
    d = _decorators()
    array, plain = "jaxtyping.jaxtyped(typechecker=beartype.beartype)", "typecheck.plain"
    assert d["arrays"] == [array] and d["quoted"] == [array] and d["method"] == [array]
    assert d["scalars"] == [plain]
    assert d["bare"] == []
    assert d["opted_out"] == ["no_type_check"] and d["inner"] == []  # nothing under no_type_check
    assert d["Model"] == [array]


def test_jaxcal_is_checked_in_this_run():
    """A shape the annotation forbids is refused: the hook is installed before jaxcal is imported."""
    from jaxcal.metrics import euclidean_error

    assert euclidean_error(np.zeros((4, 3)), np.ones((4, 3))).shape == (4,)
    with pytest.raises(Exception, match="(?i)type-check|shape|violat"):
        euclidean_error(np.zeros((4, 3)), np.ones((5, 3)))  # "... 3" twice: the batch dims must agree
    with pytest.raises(Exception, match="(?i)type-check|shape|violat"):
        euclidean_error(np.zeros((4, 2)), np.ones((4, 2)))


def test_plain_checks_what_resolves_and_leaves_the_rest():
    def f(x: int, y: "NotDefinedAnywhere", z: "typing.NamedTuple | None" = None) -> str:  # noqa: F821
        return str(x)

    before = dict(f.__annotations__)
    g = typecheck.plain(f)
    assert g(1, object()) == "1"  # y and z do not resolve: unchecked, as jaxtyping reads them (Any)
    with pytest.raises(Exception, match="(?i)violat"):
        g("1", None)
    assert f.__annotations__ == before  # the function itself is untouched


def test_a_late_install_is_refused():
    with pytest.raises(RuntimeError, match="imported before"):
        typecheck.install(["jaxcal"])
