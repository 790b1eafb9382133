"""``jaxcal sweep``: hyperparameter sweeps from a JSON spec."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

from jaxcal.cli.core import PROG, Command, UsageError, _progress, register_command

__all__ = ["sweep_lock", "sweep_lock_path"]


def _add_sweep(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", metavar="CONFIG", help="sweep spec (JSON; see docs/sweep_example.json)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output directory: sweep.json, sweep.md, sweep_heatmap.png; checkpoint.json while running")
    p.add_argument("--resume", action="store_true", help="skip the batches already in DIR/checkpoint.json")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def _run_sweep(args: argparse.Namespace) -> int:
    from jaxcal import sweep as sw  # imported on use

    try:
        spec = sw.read_sweep_spec(args.config)  # checked here, once: the run takes it as checked
    except ValueError as e:  # documented: bad input
        raise UsageError(str(e)) from None
    d = Path(args.out)
    if d.exists() and not d.is_dir():
        raise UsageError(f"--out {args.out}: exists and is not a directory")
    base = next(a for a in d.absolute().parents if a.exists()) if not d.exists() else d
    if not base.is_dir():
        raise UsageError(f"--out {args.out}: cannot create directory ({base} is not a directory)")
    if not os.access(base, os.W_OK | os.X_OK):
        raise UsageError(f"--out {args.out}: {base} is not writable")
    if not args.resume and (d / sw.CHECKPOINT).exists():
        raise UsageError(f"--out {args.out}: holds a checkpoint; add --resume to continue it, or choose another DIR")
    n = sw.n_runs(spec.spec)
    log = _progress(args)
    if log is not None:
        log(f"sweep {args.config}: {n} runs in {len(sw.plan(spec))} batch(es) -> {args.out}")
    t0 = time.perf_counter()
    made = not d.exists()
    with sweep_lock(d):
        return _sweep_locked(args, sw, spec, d, made, log, t0)


def sweep_lock(d: Path) -> contextlib.AbstractContextManager[None]:
    """A lock on ``--out DIR`` for the whole run (a file in the system's temporary folder named after
    DIR's absolute path, holding the writer's process id, so nothing is added beside DIR): a second
    sweep into the same folder is refused while the first runs; a lock whose process is gone (a
    killed sweep) is taken over, so ``--resume`` works after a kill."""
    lock = sweep_lock_path(d)

    @contextlib.contextmanager
    def held() -> Iterator[None]:
        for _ in range(2):
            try:
                fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                try:
                    pid = int(lock.read_text().strip() or "0")
                except (OSError, ValueError):
                    pid = 0
                if pid > 0 and pid != os.getpid() and _alive(pid):
                    raise UsageError(f"--out {d}: another sweep (process {pid}) is writing this folder; wait for it "
                                     f"or choose another DIR (its lock: {lock})") from None
                lock.unlink(missing_ok=True)  # stale: its process is gone
                continue
            except OSError as e:
                raise UsageError(f"--out {d}: cannot create its lock {lock} ({e.strerror or e})") from None
            with os.fdopen(fd, "w") as fh:
                fh.write(str(os.getpid()))
            break
        try:
            yield
        finally:
            lock.unlink(missing_ok=True)

    return held()


def sweep_lock_path(d: Path) -> Path:
    """The lock file of ``--out d``: in the system's temporary folder, named after d's absolute path."""
    import hashlib
    import tempfile

    return Path(tempfile.gettempdir()) / f"jaxcal-sweep-{hashlib.sha1(str(d.resolve()).encode()).hexdigest()[:16]}.lock"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _sweep_locked(args: argparse.Namespace, sw: ModuleType, spec: Any, d: Path, made: bool,
                  log: Callable[[str], None] | None, t0: float) -> int:
    try:
        res = sw.run_sweep(spec, out_dir=d, resume=args.resume, log=log)
        bad = sw.failed_runs(res)
        if bad == len(res.rows):
            _discard(d, sw.CHECKPOINT, made, args.resume)
            raise UsageError(f"{args.config}: every one of the {bad} runs gave non-finite results (diverged?); nothing "
                             "written: lower the learning rates or check the dataset settings")
        sw.write_sweep(d, res)
    except ValueError as e:  # a checkpoint of another spec, or a configuration that cannot run
        raise UsageError(f"{args.config}: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
    except OSError as e:
        raise UsageError(f"--out {args.out}: cannot write ({e.strerror or e})") from None
    if bad:
        print(f"{PROG}: warning: {bad} of {len(res.rows)} runs gave non-finite results (NaN in the table)", file=sys.stderr)
    print(f"{PROG}: wrote {d / 'sweep.json'} ({len(res.rows)} runs) in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


def _discard(d: Path, checkpoint: str, made: bool, resume: bool) -> None:
    """Remove what this run wrote before refusing its result: its checkpoint (not a resumed one) and
    the folder if this run created it and nothing else is in it."""
    if not resume:
        (d / checkpoint).unlink(missing_ok=True)
    if made and d.is_dir() and not any(d.iterdir()):
        d.rmdir()


register_command(
    "sweep",
    Command(
        "hyperparameter sweep (grid or random search), vmapped and sharded over the local devices",
        _add_sweep,
        _run_sweep,
        "Run the sweep of CONFIG (jaxcal.sweep: target, grid and/or random search, seeds, dataset) as one "
        "vmapped, jitted call per compile-compatible batch on all local devices, checkpointing DIR/checkpoint.json "
        "after each; write DIR/sweep.json, sweep.md and sweep_heatmap.png.",
    ),
)
