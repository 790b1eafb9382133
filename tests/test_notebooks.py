"""Every notebook in notebooks/ runs top to bottom (small settings) in a fresh kernel.

The fast tier runs ``03_discrepancy`` in a kernel and checks every notebook's code against the
library it calls without running it (:func:`test_notebook_code_names_what_the_library_has`); the
four longer notebooks (150 s together on the 2-core CI machine) run in the slow tier.
"""

import ast
import importlib
import inspect
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
FAST = {"03_discrepancy"}


def _code(path: Path) -> ast.Module:
    """A notebook's code cells as one module (IPython's ``%`` and ``!`` lines dropped)."""
    nb = nbformat.read(path, as_version=4)
    lines = [ln for c in nb.cells if c.cell_type == "code" for ln in c.source.splitlines() if not ln.lstrip().startswith(("%", "!"))]
    return ast.parse("\n".join(lines), filename=str(path))


def _bound_names(tree: ast.Module) -> dict[str, object]:
    """The names the notebook imports from ``jaxcal`` or ``experiments``, bound to the objects."""
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in ("jaxcal", "experiments"):
            mod = importlib.import_module(node.module)
            for a in node.names:
                obj = getattr(mod, a.name, None)
                if obj is None:
                    obj = importlib.import_module(f"{node.module}.{a.name}")  # a submodule
                out[a.asname or a.name] = obj
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in ("jaxcal", "experiments"):
                    out[a.asname or a.name.split(".")[0]] = importlib.import_module(a.name if a.asname else a.name.split(".")[0])
    return out


def _resolve(node: ast.AST, names: dict[str, object]):
    """The object an expression ``name.attr.attr`` stands for, or None if it is not rooted in ``names``."""
    if isinstance(node, ast.Name):
        return names.get(node.id)
    if isinstance(node, ast.Attribute):
        base = _resolve(node.value, names)
        if base is None:
            return None
        assert hasattr(base, node.attr), f"{ast.unparse(node)}: {getattr(base, '__name__', base)!r} has no {node.attr!r}"
        return getattr(base, node.attr)
    return None


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_code_names_what_the_library_has(path):
    """Without running it: every ``jaxcal``/``experiments`` name a notebook imports exists, every
    attribute it reads from them exists, every keyword it passes to one of their functions is a
    parameter of that function, and every ``../data/`` file it names is in the repository: the ways
    a notebook breaks when the library moves on."""
    tree = _code(path)
    names = _bound_names(tree)
    assert names, f"{path.name} imports nothing from jaxcal"
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            _resolve(node, names)
        if isinstance(node, ast.Call):
            fn = _resolve(node.func, names)
            if fn is None or not callable(fn) or isinstance(fn, type) and issubclass(fn, BaseException):
                continue
            try:
                params = inspect.signature(fn).parameters
            except (TypeError, ValueError):
                continue
            if any(p.kind is p.VAR_KEYWORD for p in params.values()):
                continue
            for kw in node.keywords:
                assert kw.arg is None or kw.arg in params, f"{path.name}: {ast.unparse(node.func)} takes no {kw.arg!r}"
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.startswith("../data/"):
            assert (path.parent / node.value).exists(), f"{path.name}: {node.value} is not in the repository"


@pytest.mark.parametrize(
    "path", [p if p.stem in FAST else pytest.param(p, marks=pytest.mark.slow) for p in NOTEBOOKS], ids=[p.stem for p in NOTEBOOKS]
)
def test_notebook_runs(path, monkeypatch):
    """The notebook runs top to bottom in a fresh kernel, every code cell without an error.

    Fast cover: tests/test_notebooks.py::test_notebook_code_names_what_the_library_has (every
    notebook's names, attributes, keywords and data files checked against the library without a
    kernel), and this test's ``03_discrepancy`` case, which stays in the fast tier (a kernel runs).
    """
    # The kernel inherits the environment: the inline backend renders figures (the Makefile's Agg would not).
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
    # Every code cell ran and none raised (nbclient raises CellExecutionError otherwise).
    assert all(c.get("execution_count") for c in nb.cells if c.cell_type == "code")
