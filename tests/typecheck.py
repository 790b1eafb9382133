"""Run-time shape and type checks of ``jaxcal`` while the suite runs: an import hook.

:func:`install` (called by ``tests/conftest.py`` before anything imports ``jaxcal``) rewrites each
``jaxcal`` module as it is imported:

- a function whose annotations hold a jaxtyping array type (``Float[Array, "N 3"]``, or any name
  the module imports from ``jaxtyping``) is wrapped in ``jaxtyping.jaxtyped(typechecker=beartype.beartype)``:
  shapes and dtypes are checked, and the dimension letters of one call must agree;
- a function annotated only with other types (``float``, ``str``, a NamedTuple) gets :func:`plain`,
  ``beartype.beartype`` on the annotations that resolve;
- a class gets ``jaxtyping.jaxtyped`` (a dataclass's fields are then checked when it is built);
- a function with no annotation, or under ``@typing.no_type_check``, is left as it is.

jaxtyping's own hook (``--jaxtyping-packages=jaxcal,beartype.beartype``, used until stop 46) checks
the same annotations, but it wraps every function in ``jaxtyped``, annotated or not, closures
included. That wrapper binds the call's signature (``inspect.Signature.bind``) on every call, and a
closure's ``def`` builds and compiles a new checker each time it runs. Measured (one run each, serially,
back to back, cold compilation cache; not a repeated measurement): ``tests/test_plausibility.py`` alone took 60.4 s with that hook
and 42.3 s with no checks (cProfile: 320 000 wrapped calls, 24 000 ``compile`` calls), 43.7 s with this
one; ``test_plausibility``, ``test_noise_cli``, ``test_hostile_inputs``, ``test_allan`` and
``test_diagnose_real`` together 136.8 s with jaxtyping's hook and 118.6 s with this one, the same
tests passing. Files whose time is compiling gain nothing (``test_cli`` + ``test_multipos``: 171 s
either way).

The rewritten modules are compiled from source on each import and never written to ``__pycache__``,
so a checked module cannot be picked up outside the suite.
"""

from __future__ import annotations

import ast
import importlib.machinery
import importlib.util
import sys
import typing
from collections.abc import Sequence

import beartype

_ARRAY_HINT = "jaxtyping.jaxtyped(typechecker=beartype.beartype)"
_PLAIN_HINT = "typecheck.plain"


def _resolved(ann, ns: dict):
    """An annotation evaluated in ``ns``, or None where it cannot be (as jaxtyping does, which reads
    such an annotation as ``Any``): a name defined later in the module, or not a type."""
    def probe(value):
        del value

    probe.__annotations__ = {"value": ann}  # set, not written: this module's annotations are strings
    try:
        return typing.get_type_hints(probe, ns, include_extras=True)["value"]
    except Exception:
        return None


def plain(fn):
    """``beartype.beartype`` on the annotations that resolve when the function is defined; the
    others are not checked (what ``jaxtyped(typechecker=beartype)`` does, without its per-call
    signature binding)."""
    ann = {k: _resolved(v, fn.__globals__) for k, v in fn.__annotations__.items()}
    saved = fn.__annotations__
    fn.__annotations__ = {k: v for k, v in ann.items() if v is not None}
    try:
        return beartype.beartype(fn)
    finally:
        fn.__annotations__ = saved


def _decorator(src: str) -> ast.expr:
    return ast.parse(src, mode="eval").body


def _is_no_type_check(node: ast.expr) -> bool:
    node = node.func if isinstance(node, ast.Call) else node
    return (isinstance(node, ast.Name) and node.id == "no_type_check") or (
        isinstance(node, ast.Attribute) and node.attr == "no_type_check")


def jaxtyping_names(tree: ast.Module) -> set[str]:
    """The names a module binds to jaxtyping: ``from jaxtyping import Float`` gives ``Float``,
    ``import jaxtyping as jt`` gives ``jt``."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module == "jaxtyping":
            names |= {a.asname or a.name for a in node.names}
        elif isinstance(node, ast.Import):
            names |= {a.asname or a.name for a in node.names if a.name == "jaxtyping"}
    return names


def _mentions(expr: ast.AST | None, names: set[str]) -> bool:
    """Whether an annotation refers to one of ``names`` (also inside a quoted annotation)."""
    if expr is None:
        return False
    for node in ast.walk(expr):
        if isinstance(node, ast.Name) and node.id in names:
            return True
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            try:
                inner = ast.parse(node.value, mode="eval")
            except SyntaxError:
                continue  # a shape string such as "N 3"
            if _mentions(inner, names):
                return True
    return False


def annotations_of(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> list[ast.expr]:
    """Every annotation of a function's parameters and return."""
    a = fn.args
    params = [*a.posonlyargs, *a.args, *a.kwonlyargs, *(p for p in (a.vararg, a.kwarg) if p is not None)]
    return [x for x in [*(p.annotation for p in params), fn.returns] if x is not None]


def checker_for(fn: ast.FunctionDef | ast.AsyncFunctionDef, names: set[str]) -> str | None:
    """The decorator a function gets (see the module docstring), or None."""
    ann = annotations_of(fn)
    if not ann:
        return None
    return _ARRAY_HINT if any(_mentions(x, names) for x in ann) else _PLAIN_HINT


class Instrument(ast.NodeTransformer):
    """Adds the decorators of :func:`checker_for` (innermost, as jaxtyping's hook does: ``jax.jit``,
    ``custom_jvp`` and ``property`` stay outside) and ``jaxtyped`` on classes (outermost, after
    ``@dataclass``)."""

    def __init__(self, names: set[str]):
        self.names = names

    def visit_Module(self, node: ast.Module) -> ast.Module:
        at = next((i for i, s in enumerate(node.body) if not (
            (isinstance(s, ast.ImportFrom) and s.module == "__future__")
            or (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant)))), len(node.body))
        node.body[at:at] = [ast.Import(names=[ast.alias(m)]) for m in ("beartype", "jaxtyping", "typecheck")]
        self.generic_visit(node)
        return node

    def _function(self, node):
        if any(_is_no_type_check(d) for d in node.decorator_list):
            return node
        hint = checker_for(node, self.names)
        if hint is not None:
            node.decorator_list.append(_decorator(hint))
        self.generic_visit(node)
        return node

    visit_FunctionDef = _function
    visit_AsyncFunctionDef = _function

    def visit_ClassDef(self, node: ast.ClassDef) -> ast.ClassDef:
        if any(_is_no_type_check(d) for d in node.decorator_list):
            return node
        node.decorator_list.insert(0, _decorator(_ARRAY_HINT))
        self.generic_visit(node)
        return node


def instrument_source(source: str, path: str = "<source>") -> ast.Module:
    """The module's syntax tree with the checks added."""
    tree = ast.parse(source, filename=path)
    tree = Instrument(jaxtyping_names(tree)).visit(tree)
    return ast.fix_missing_locations(tree)


class _Loader(importlib.machinery.SourceFileLoader):
    def get_code(self, fullname):
        # from source every time: no bytecode is read from or written to __pycache__
        path = self.get_filename(fullname)
        source = importlib.util.decode_source(self.get_data(path))
        return compile(instrument_source(source, path), path, "exec", dont_inherit=True)


class _Finder:
    def __init__(self, packages: Sequence[str]):
        self.packages = tuple(packages)

    def find_spec(self, fullname, path=None, target=None):
        if not any(fullname == p or fullname.startswith(p + ".") for p in self.packages):
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path, target)
        if spec is not None and type(spec.loader) is importlib.machinery.SourceFileLoader:
            spec.loader = _Loader(spec.loader.name, spec.loader.path)
        return spec


def install(packages: Sequence[str]) -> None:
    """Check ``packages`` (and their submodules) when they are next imported. Raises if one is
    imported already: its functions would go unchecked."""
    early = [m for m in sys.modules if any(m == p or m.startswith(p + ".") for p in packages)]
    if early:
        raise RuntimeError(f"imported before the type-check hook was installed: {sorted(early)[:5]}")
    sys.meta_path.insert(0, _Finder(packages))
