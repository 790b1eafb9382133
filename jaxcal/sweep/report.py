"""The sweep's report: ``sweep.json``, ``sweep.md`` (seed means, the best configurations) and the heatmap."""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from jaxcal.recording import atomic_output
from jaxcal.sweep.run import SweepResult, write_json
from jaxcal.sweep.spec import spec_to_dict
from jaxcal.sweep.targets import TARGETS

__all__ = ["failed_runs", "write_sweep"]


def failed_runs(result: SweepResult) -> int:
    """Runs whose every metric is non-finite (diverged, or a configuration that cannot run)."""
    keys = [k for k, _ in TARGETS[result.spec.target].metrics]

    def bad(r: dict) -> bool:
        vals = [r.get(k) for k in keys if isinstance(r.get(k), (int, float))]
        return bool(vals) and not any(math.isfinite(v) for v in vals)

    return sum(bad(r) for r in result.rows)


def _seed_means(result: SweepResult) -> list[dict[str, Any]]:
    """Rows averaged over seeds (one per configuration), in first-appearance order."""
    by: dict[tuple, list[dict]] = {}
    for r in result.rows:
        by.setdefault(tuple(r[k] for k in result.names), []).append(r)
    out = []
    for key, rs in by.items():
        m = dict(zip(result.names, key, strict=True))
        for col, _ in TARGETS[result.spec.target].metrics:
            m[col] = float(np.mean([r[col] for r in rs]))
        m["n_seeds"] = len(rs)
        out.append(m)
    return out


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _markdown(result: SweepResult) -> str:
    spec = result.spec
    target = TARGETS[spec.target]
    means = _seed_means(result)
    cols = [*result.names, *(c for c, _ in target.metrics)]
    heads = [*result.names, *(h for _, h in target.metrics)]
    lines = [
        f"# Sweep: {spec.target}",
        "",
        f"Written by `jaxcal sweep` ({len(result.rows)} runs: {len(means)} configurations x {len(spec.seeds)} seeds "
        f"{list(spec.seeds)}; {target.describe(spec)}). Errors are test-set means "
        f"(eq. 3.8) averaged over the seeds; {result.timing.get('total_s', 0):.1f} s on "
        f"{result.timing.get('devices', 1)} device(s).",
        "",
    ]
    if means:
        show = lambda m: ", ".join(f"{k} = {_fmt(m[k])}" for k in result.names) or "the only configuration"  # noqa: E731
        words = []
        for col, phrase, unit in target.best:
            b = min(means, key=lambda m: m[col])
            others = "; ".join(f"{p} {b[c]:.4g}{' ' + u if u else ''}" for c, p, u in (*target.best, *target.best_context) if c != col)
            words.append(f"Lowest {phrase}: {b[col]:.2f} {unit} ({show(b)}{'; ' + others if others else ''}).")
        lines += [" ".join(words), ""]
    lines += ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    lines += ["| " + " | ".join(_fmt(m[c]) for c in cols) + " |" for m in means]
    lines += ["", "Per seed: `sweep.json` (`rows`).", ""]
    return "\n".join(lines)


def _heatmap_axes(result: SweepResult) -> tuple[str, str] | None:
    if result.spec.heatmap:
        return tuple(result.spec.heatmap)
    return tuple(result.names[:2]) if len(result.names) >= 2 else None


def _tick(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def _write_heatmap(path: Path, result: SweepResult, axes: tuple[str, str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    target = TARGETS[result.spec.target]
    heads = dict(target.metrics)
    xa, ya = axes
    xs = sorted({r[xa] for r in result.rows})
    ys = sorted({r[ya] for r in result.rows})
    fig, panes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, col in zip(panes, target.heatmap_metrics, strict=True):
        grid = np.full((len(ys), len(xs)), np.nan)
        for j, y in enumerate(ys):
            for i, x in enumerate(xs):
                v = [r[col] for r in result.rows if r[xa] == x and r[ya] == y]
                grid[j, i] = np.mean(v) if v else np.nan
        fin = grid[np.isfinite(grid)]
        # a log colour scale when the cells span more than a decade (e.g. converged vs unconverged fits)
        norm = LogNorm() if fin.size and fin.min() > 0 and fin.max() > 10 * fin.min() else None
        im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis", norm=norm)
        ax.set_xticks(range(len(xs)), [_tick(x) for x in xs], rotation=45)
        ax.set_yticks(range(len(ys)), [_tick(y) for y in ys])
        ax.set_xlabel(xa)
        ax.set_ylabel(ya)
        ax.set_title(f"{heads[col]}, mean over seeds and other axes")
        for j in range(len(ys)):
            for i in range(len(xs)):
                if np.isfinite(grid[j, i]):
                    ax.text(i, j, f"{grid[j, i]:.3g}", ha="center", va="center", color="w", fontsize=8)
        fig.colorbar(im, ax=ax)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def write_sweep(out_dir: str | os.PathLike, result: SweepResult) -> list[Path]:
    """Write ``sweep.json``, ``sweep.md`` and (two swept names or more) ``sweep_heatmap.png``: all three
    finished in a temporary folder inside ``out_dir`` first, then moved into place (an earlier heatmap
    removed when this sweep has none), so an interruption leaves the earlier results whole.

    Args:
        out_dir: the directory (created if needed).
        result: from :func:`run_sweep`.

    Returns:
        The paths written.
    """
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".sweep.", suffix=".partial", dir=d))
    try:  # every file finished beside the folder first: an interruption leaves the earlier results whole
        names = ["sweep.md", "sweep.json"]
        write_json(tmp / "sweep.json", {"spec": spec_to_dict(result.spec), "names": list(result.names),
                                         "rows": result.rows, "timing": result.timing})
        (tmp / "sweep.md").write_text(_markdown(result))
        axes = _heatmap_axes(result)
        if axes is not None:
            _write_heatmap(tmp / "sweep_heatmap.png", result, axes)
            names.insert(0, "sweep_heatmap.png")
        else:  # an earlier sweep's heatmap would not describe these results
            (d / "sweep_heatmap.png").unlink(missing_ok=True)
        for n in names:  # sweep.json, the record, last
            os.replace(tmp / n, d / n)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return [d / n for n in ("sweep.json", "sweep.md", "sweep_heatmap.png") if n in names]
