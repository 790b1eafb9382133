"""Where the ``online`` filter's time went: its real-time factor, one engine change at a time.

    python benchmarks/online_engine.py [--reps 7] [--json results/online_engine.json]

Each rung below adds one change to the one before; the first is the engine as it was at a0722c9
(rebuilt here by putting its functions back, so every rung runs in this one process, alternating, on
the same data). For each rung and kind (``diag``, ``affine``) this times ``online_scan`` on Dataset 2
(500 sequences x 101 samples at 100 Hz, float64; one fresh ``jit`` each, the persistent cache off):
the median of ``--reps`` runs, the compile time, and the largest difference of the final parameters
from the first rung (the claim: unchanged to float64 rounding). The load average is recorded.

1. ``a0722c9``: JAX's own derivative of the propagation loop (every tangent carried through all
   ``N`` steps), ``jacfwd`` of the whole residual (all columns through the propagation), LAPACK's
   ``solve`` for ``K_a^{-1}`` and ``@`` for the 3x3 products.
2. ``+ closed-form tangent``: ``rotation.propagate_specific_force``'s ``custom_jvp``.
3. ``+ structured Jacobian``: the accelerometer's columns skip the propagation
   (``online.filter._residuals_and_jacobian``).
4. ``+ elementwise 3x3 algebra``: ``mat3.inv3`` / ``matvec3`` in the reading model and the calibrations.
5. ``+ elementwise loop``: the propagation's steps as multiply-adds (``PROPAGATE_ELEMENTWISE``): the
   library's default.

The rungs are rebuilt by putting the filter's earlier kernels back in place of its module globals
(``online.filter._residuals_and_jacobian``, ``_readings_of``, ``_calibrate_acc``, ``_calibrate_gyr``,
``propagate_specific_force``, ``PROPAGATE_ELEMENTWISE``), which its ``jit`` reads at trace time. This
ablation is about the filter's internals by purpose, so it is the one script that uses private names.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from contextlib import contextmanager
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxcal.online.filter as F  # noqa: E402  (module globals are read when the filter is traced)
from benchmarks.online_unroll import filter_inputs  # noqa: E402
from jaxcal import rotation  # noqa: E402
from jaxcal.online import make_filter, online_scan  # noqa: E402

RUNGS = ("a0722c9", "+ closed-form tangent", "+ structured Jacobian", "+ elementwise 3x3 algebra", "+ elementwise loop")


def _loop_propagation(f0, w, dt, unroll=1, elementwise=False):
    """a0722c9's propagation: the plain loop, differentiated by JAX's own rules."""
    def step(f, r):
        f_next = r.T @ f
        return f_next, f_next

    _, fs = jax.lax.scan(step, f0, rotation.rotation_from_rate(w, dt), unroll=unroll)
    return jnp.concatenate([f0[None], fs], axis=0)


def _jacfwd_all(lay, z, f0_ref, u_acc, u_gyr, mask, dt, weight=None, weight_t=None):
    """a0722c9's Jacobian: ``jacfwd`` of the whole residual, the residual evaluated on its own."""
    p = lay.n

    def res(z_):
        return F._sequence_residuals(lay, z_[:p], z_[p:], f0_ref, u_acc, u_gyr, mask, dt, weight, weight_t)

    return res(z), jax.jacfwd(res)(z)


def _readings_solve(lay, theta, f):
    c = F._unpack(lay, theta)
    return jnp.linalg.solve(c.K_a, (f + c.e_a).T).T


def _cal_acc_dot(lay, theta, u):
    c = F._unpack(lay, theta)
    return u @ c.K_a.T - c.e_a


def _cal_gyr_dot(lay, theta, u):
    c = F._unpack(lay, theta)
    return u @ c.K_g.T - c.e_g


@contextmanager
def _rung(i: int):
    """Put back the functions of the rungs above ``i`` (module globals, read at trace time)."""
    saved = {k: getattr(F, k) for k in ("propagate_specific_force", "_residuals_and_jacobian", "_readings_of",
                                        "_calibrate_acc", "_calibrate_gyr", "PROPAGATE_ELEMENTWISE")}
    try:
        if i < 1:
            F.propagate_specific_force = _loop_propagation
        if i < 2:
            F._residuals_and_jacobian = _jacfwd_all
        if i < 3:
            F._readings_of, F._calibrate_acc, F._calibrate_gyr = _readings_solve, _cal_acc_dot, _cal_gyr_dot
        if i < 4:
            F.PROPAGATE_ELEMENTWISE = False
        yield
    finally:
        for k, v in saved.items():
            setattr(F, k, v)


def measure(reps: int) -> dict:
    with jax.enable_x64(True):
        info, batch, dt, hp = filter_inputs()
        data_s = info["data_s"]
        out: dict = {**info, "reps": reps, "rungs": list(RUNGS), "rows": []}
        fns = {}
        for i, name in enumerate(RUNGS):
            with _rung(i):
                for kind in ("diag", "affine"):
                    st0 = make_filter(kind).init(hp, jnp.float64)
                    t0 = time.perf_counter()
                    fn = jax.jit(partial(online_scan, kind=kind)).lower(st0, batch, dt, hp).compile()
                    fns[(name, kind)] = (fn, st0, time.perf_counter() - t0)
        times: dict = {k: [] for k in fns}
        theta = {k: np.asarray(jax.block_until_ready(fn(st0, batch, dt, hp))[0].theta) for k, (fn, st0, _) in fns.items()}
        for _ in range(reps):  # alternating, so a change of load falls on every rung alike
            for k, (fn, st0, _) in fns.items():
                t0 = time.perf_counter()
                jax.block_until_ready(fn(st0, batch, dt, hp))
                times[k].append(time.perf_counter() - t0)
        for (name, kind), (_, _, c) in fns.items():
            run = statistics.median(times[(name, kind)])
            row = {"rung": name, "kind": kind, "compile_s": c, "run_s": run, "run_s_all": times[(name, kind)],
                   "realtime_factor": data_s / run,
                   "max_abs_diff_vs_first": float(np.max(np.abs(theta[(name, kind)] - theta[(RUNGS[0], kind)])))}
            out["rows"].append(row)
            print(f"{name:28s} {kind:6s} run {run * 1e3:7.1f} ms  RTF {data_s / run:6.0f}  compile {c:4.1f} s  "
                  f"theta diff {row['max_abs_diff_vs_first']:.1e}", flush=True)
        for kind in ("diag", "affine"):
            first = next(r for r in out["rows"] if r["rung"] == RUNGS[0] and r["kind"] == kind)
            last = next(r for r in out["rows"] if r["rung"] == RUNGS[-1] and r["kind"] == kind)
            out[f"speedup_{kind}"] = first["run_s"] / last["run_s"]
            print(f"{kind}: {out[f'speedup_{kind}']:.2f}x ({first['realtime_factor']:.0f} -> {last['realtime_factor']:.0f})")
        out["max_abs_theta"] = float(max(np.max(np.abs(t)) for t in theta.values()))
    out["load_average_at_end"] = list(os.getloadavg())
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    jax.config.update("jax_enable_compilation_cache", False)
    res = measure(a.reps)
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
