"""Near-threshold scan: log every numeric assertion's margin (opt-in pytest plugin + report).

Enabled only when ``JAXCAL_MARGIN_LOG`` names a file (``make margins`` does that, five runs under
different conditions); a normal ``make test`` never loads the recording code.

What is logged, one JSON line per passing assertion:

* plain ``assert`` statements whose expression is a comparison ``a < b``, ``a <= b``, ``a > b``,
  ``a >= b`` (possibly inside ``bool(...)`` / ``all(...)`` / ``jnp.all(...)`` / ``np.all(...)``,
  elementwise for arrays) or ``a == pytest.approx(b, ...)``: both sides are evaluated again in the
  test's own frame (assert expressions here are pure);
* ``np.testing.assert_allclose(actual, desired, rtol, atol)``.

The margin is how many times the observed quantity could grow before the assertion fails:
``b / a`` for ``a < b`` with positive sides (``a / b`` for ``a > b``), ``tol / |a - b|`` for approx,
``1 / max(|a - b| / (atol + rtol |b|))`` for ``assert_allclose``, ``(1 - b) / (1 - a)`` for a fraction
``a > b`` with ``0.5 <= b < 1`` (its shortfall from 1 may grow that much); a margin under 3 marks a
near-threshold test.  Comparisons whose sides have opposite signs, or are zero, log ``inf``.

Report: ``python -m tests.margins RUN1.jsonl RUN2.jsonl ...`` prints, per assertion, the smallest
margin over the runs and the spread of the observed value between runs.
"""

from __future__ import annotations

import ast
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

_OPS = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">="}
_WRAPPERS = {"bool", "all", "float", "jnp.all", "np.all", "numpy.all"}


def _ratio(lo, hi):
    """Elementwise margin of ``lo < hi``: hi/lo when both positive, lo/hi when both negative."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        pos = np.where((lo > 0) & (hi > 0), hi / np.where(lo > 0, lo, 1.0), np.inf)
        neg = np.where((lo < 0) & (hi < 0), lo / np.where(hi < 0, hi, 1.0), pos)
    return float(np.min(neg)) if neg.size else math.inf


def _unwrap(node):
    while isinstance(node, ast.Call) and len(node.args) == 1 and not node.keywords:
        if ast.unparse(node.func) not in _WRAPPERS:
            break
        node = node.args[0]
    return node


def _find_frame(path: str, lineno: int):
    f = sys._getframe(1)
    while f is not None:
        if f.f_code.co_filename == path and f.f_lineno >= lineno:
            return f
        f = f.f_back
    return None


def _eval(node, frame):
    return eval(compile(ast.Expression(node), "<margin>", "eval"), frame.f_globals, dict(frame.f_locals))  # noqa: S307


def _observe(orig: str, frame):
    """(observed, threshold, margin, kind) of one assertion, or None if it is not numeric."""
    try:
        tree = ast.parse(orig.strip(), mode="eval").body
    except SyntaxError:
        return None
    node = _unwrap(tree)
    if not isinstance(node, ast.Compare) or len(node.ops) != 1:
        return None
    op, left, right = node.ops[0], node.left, node.comparators[0]
    try:
        a, b = _eval(left, frame), _eval(right, frame)
    except Exception:  # noqa: BLE001 - an expression we cannot re-evaluate is just not logged
        return None
    if isinstance(op, ast.Eq) and type(b).__name__ == "ApproxScalar":
        tol = float(b.tolerance)
        dev = abs(float(a) - float(b.expected))
        return dev, tol, (tol / dev if dev > 0 else math.inf), "approx"
    if type(op) not in _OPS:
        return None
    try:
        a64, b64 = np.asarray(a, np.float64), np.asarray(b, np.float64)
    except (TypeError, ValueError):
        return None
    if a64.dtype.kind not in "fiu" or b64.dtype.kind not in "fiu":
        return None
    lo, hi = (a64, b64) if isinstance(op, (ast.Lt, ast.LtE)) else (b64, a64)
    obs = float(np.max(a64)) if a64.size else math.nan
    thr = float(np.min(b64)) if b64.size else math.nan
    if isinstance(op, (ast.Gt, ast.GtE)) and b64.size == 1 and 0.5 <= thr < 1 and np.all(a64 <= 1):
        # A fraction that must stay above thr (< 1): its shortfall from 1 may grow (1 - thr) / (1 - a) times.
        return obs, thr, _ratio(1 - a64, 1 - b64), _OPS[type(op)] + " (fraction)"
    return obs, thr, _ratio(lo, hi), _OPS[type(op)]


class MarginRecorder:
    """pytest plugin object: appends one JSON line per numeric assertion to ``path``."""

    def __init__(self, path: str):
        self.path = path
        self._orig_allclose = np.testing.assert_allclose
        self.current = None
        self.seen: dict[tuple, int] = {}

    def _write(self, rec):
        # The k-th evaluation of a line within one test (loops, hypothesis examples) is its own row.
        key = (rec["test"], rec["line"])
        rec["k"] = self.seen.get(key, 0)
        self.seen[key] = rec["k"] + 1
        with open(self.path, "a") as fh:
            fh.write(json.dumps(rec) + "\n")

    def pytest_runtest_setup(self, item):
        self.current = item

    def pytest_assertion_pass(self, item, lineno, orig, expl):
        frame = _find_frame(str(item.path), lineno)
        if frame is None:
            return
        got = _observe(orig, frame)
        if got is None:
            return
        obs, thr, margin, kind = got
        self._write(dict(test=item.nodeid, line=lineno, expr=orig.strip()[:160], kind=kind,
                         observed=obs, threshold=thr, margin=margin))

    def allclose(self, actual, desired, rtol=1e-7, atol=0, *args, **kwargs):
        self._orig_allclose(actual, desired, rtol, atol, *args, **kwargs)
        a = np.asarray(actual, np.float64)
        d = np.asarray(desired, np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.abs(a - d) / (atol + rtol * np.abs(d))
        rel = rel[np.isfinite(rel)]
        worst = float(np.max(rel)) if rel.size else 0.0
        f = sys._getframe(1)
        line, name = f.f_lineno, ""
        item = self.current
        if item is not None:
            frame = f
            while frame is not None and frame.f_code.co_filename != str(item.path):
                frame = frame.f_back
            line = frame.f_lineno if frame is not None else line
            name = item.nodeid
        self._write(dict(test=name, line=line, expr=f"assert_allclose(rtol={rtol:g}, atol={atol:g})",
                         kind="allclose", observed=float(np.max(np.abs(a - d))) if a.size else 0.0,
                         threshold=float(atol + rtol * np.max(np.abs(d))) if d.size else float(atol),
                         margin=(1.0 / worst) if worst > 0 else math.inf))


def install(config) -> None:
    """Register the recorder when JAXCAL_MARGIN_LOG is set (called from conftest)."""
    path = os.environ.get("JAXCAL_MARGIN_LOG")
    if not path:
        return
    rec = MarginRecorder(path)
    np.testing.assert_allclose = rec.allclose
    config.pluginmanager.register(rec, "jaxcal-margins")


def report(paths: list[str], threshold: float = 3.0) -> str:
    """Markdown table of every assertion whose smallest margin over the runs is under ``threshold``.

    Per row (one assertion line of one test): the smallest ratio margin over runs and evaluations,
    and the stability: the observed value's distance to the threshold divided by its largest
    change between runs for the same evaluation (``inf`` when every run gave the same value).
    """
    rows: dict[tuple, dict] = {}
    for p in paths:
        for line in Path(p).read_text().splitlines():
            r = json.loads(line)
            rows.setdefault((r["test"], r["line"], r["expr"]), {}).setdefault(r.get("k", 0), []).append(r)
    out = [f"{len(rows)} numeric assertions over {len(paths)} runs.",
           "margin: how many times the observed value may grow before the assertion fails (smallest over runs and",
           "evaluations); change: largest difference of one evaluation's observed value between runs, relative;",
           "stability: distance of the observed value to its threshold / that change (inf: identical in every run).", "",
           "| test | line | assertion | observed | threshold | min margin | change | stability | runs |",
           "|---|---|---|---|---|---|---|---|---|"]
    low = 0
    stats = []
    for (test, line, expr), by_k in rows.items():
        margin = min(r["margin"] for rs in by_k.values() for r in rs)
        change, stability = 0.0, math.inf
        for rs in by_k.values():
            obs = np.array([r["observed"] for r in rs], np.float64)
            d = float(np.nanmax(obs) - np.nanmin(obs)) if len(obs) > 1 else 0.0
            if d > 0:
                scale = float(np.nanmax(np.abs(obs))) or 1.0
                change = max(change, d / scale)
                dist = float(np.nanmin(np.abs(obs - rs[0]["threshold"])))
                stability = min(stability, dist / d)
        first = next(iter(by_k.values()))
        runs = max(len(rs) for rs in by_k.values())
        stats.append((margin, test, line, expr, first[0]["observed"], first[0]["threshold"], change, stability, runs))
    for margin, test, line, expr, obs, thr, change, stability, runs in sorted(stats, key=lambda r: r[0]):
        if margin >= threshold:
            continue
        low += 1
        out.append(f"| {test} | {line} | `{expr[:90]}` | {obs:.4g} | {thr:.4g} | {margin:.3g} | {change:.2g} "
                   f"| {stability:.3g} | {runs} |")
    out.insert(4, f"{low} with a margin under {threshold:g}x.")
    return "\n".join(out)


if __name__ == "__main__":
    print(report(sys.argv[1:]))
