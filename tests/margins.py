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

Report: ``python -m tests.margins RUN1.jsonl RUN2.jsonl ... [--perturbed RUN6.jsonl]`` prints, per
assertion under a 3x margin, the smallest margin over the runs and how far the observed value moved
between runs, and against a run whose float sums were reassociated.
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


def _load(paths: list[str]) -> dict[tuple, dict[int, list]]:
    rows: dict[tuple, dict] = {}
    for p in paths:
        for line in Path(p).read_text().splitlines():
            r = json.loads(line)
            rows.setdefault((r["test"], r["line"], r["expr"]), {}).setdefault(r.get("k", 0), []).append(r)
    return rows


def _stability(values: list[float], threshold: float) -> tuple[float, float]:
    """(largest relative change between the values, distance of the nearest to threshold / that change)."""
    obs = np.array(values, np.float64)
    d = float(np.nanmax(obs) - np.nanmin(obs)) if len(obs) > 1 else 0.0
    if not d > 0:
        return 0.0, math.inf
    scale = float(np.nanmax(np.abs(obs))) or 1.0
    return d / scale, float(np.nanmin(np.abs(obs - threshold))) / d


def report(paths: list[str], threshold: float = 3.0, perturbed: str | None = None) -> str:
    """Markdown table of every assertion whose smallest margin over the runs is under ``threshold``.

    Per row (one assertion line of one test): the smallest ratio margin over runs and evaluations;
    the stability, the observed value's distance to the threshold divided by its largest change
    between runs for the same evaluation (``inf`` when every run gave the same value); with
    ``perturbed`` (a run with reassociated float sums) the same against that run's values.
    """
    rows = _load(paths)
    pert = _load([perturbed]) if perturbed else {}
    out = [f"{len(rows)} numeric assertions over {len(paths)} runs.",
           "margin: how many times the observed value may grow before the assertion fails (smallest over runs and",
           "evaluations); change: largest relative difference of one evaluation's observed value between runs;",
           "stability: distance of the observed value to its threshold / that change (inf: identical in every run);",
           "reordered: the same two figures against the run with XLA fast math (sums reassociated).", "",
           "| test | line | assertion | observed | threshold | min margin | change | stability | reordered change | reordered stability |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    low, stats = 0, []
    for key, by_k in rows.items():
        margin = min(r["margin"] for rs in by_k.values() for r in rs)
        change, stab, pchange, pstab = 0.0, math.inf, math.nan, math.nan
        for k, rs in by_k.items():
            thr = rs[0]["threshold"]
            c, st = _stability([r["observed"] for r in rs], thr)
            change, stab = max(change, c), min(stab, st)
            if perturbed:
                extra = [r["observed"] for r in pert.get(key, {}).get(k, [])]
                if extra:
                    c, st = _stability([r["observed"] for r in rs] + extra, thr)
                    pchange = c if math.isnan(pchange) else max(pchange, c)
                    pstab = st if math.isnan(pstab) else min(pstab, st)
        first = next(iter(by_k.values()))[0]
        stats.append((margin, *key, first["observed"], first["threshold"], change, stab, pchange, pstab))
    for margin, test, line, expr, obs, thr, change, stab, pchange, pstab in sorted(stats, key=lambda r: r[0]):
        if margin >= threshold:
            continue
        low += 1
        ptxt = "- | -" if math.isnan(pchange) else f"{pchange:.2g} | {pstab:.3g}"
        out.append(f"| {test} | {line} | `{expr[:90]}` | {obs:.4g} | {thr:.4g} | {margin:.3g} | {change:.2g} "
                   f"| {stab:.3g} | {ptxt} |")
    out.insert(5, f"{low} with a margin under {threshold:g}x.")
    if perturbed:
        missing = sorted({t for (t, _, _) in rows} - {t for (t, _, _) in pert})
        out += ["", f"Tests with no passing assertion logged in the reordered run (failed or skipped there): {len(missing)}", ""]
        out += [f"- {t}" for t in missing]
    return "\n".join(out)


if __name__ == "__main__":
    args = sys.argv[1:]
    pert = None
    if "--perturbed" in args:
        i = args.index("--perturbed")
        pert = args[i + 1]
        args = args[:i] + args[i + 2:]
    print(report(args, perturbed=pert))
