"""The README's tour runs as written (issue 29, point 4).

The ```bash block under "### Tour" is executed command by command in a temporary folder that holds
the repository's ``data/`` and ``docs/`` (links): every command must exit 0 without a Python warning on stderr, no two commands may
write the same output, and nothing may be written outside ``tour/`` (the tour's own folder). A
placeholder (a file the tour never made and the repository does not hold) fails the command, so
the test also proves that the tour has none.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SKIP = ("source .venv/bin/activate",)


def tour_commands(readme: str) -> list[str]:
    """The shell commands of the README's tour block: continuations joined, comments and blank
    lines dropped, the venv activation left out (the test runs this interpreter)."""
    m = re.search(r"^### Tour\n.*?```bash\n(.*?)```", readme, re.S | re.M)
    assert m, "README.md has no ```bash block under '### Tour'"
    cmds, cur = [], ""
    for line in m.group(1).splitlines():
        code = line.split(" #", 1)[0].rstrip() if not line.lstrip().startswith("#") else ""
        cur += code.rstrip("\\").rstrip() + " " if code.endswith("\\") else code
        if not code.endswith("\\"):
            if cur.strip() and cur.strip() not in SKIP:
                cmds.append(cur.strip())
            cur = ""
    return cmds


def _outputs(cmd: str) -> list[str]:
    words = shlex.split(cmd)
    return [words[i + 1] for i, w in enumerate(words[:-1]) if w == "--out"]


def test_the_tour_block_is_parsed():
    cmds = tour_commands((ROOT / "README.md").read_text())
    assert len(cmds) >= 10 and all(c.split()[0] in ("jaxcal", "mkdir", "ls", "rm") for c in cmds), cmds


def test_no_two_tour_commands_write_the_same_output():
    outs = [o for c in tour_commands((ROOT / "README.md").read_text()) for o in _outputs(c)]
    assert len(outs) == len(set(outs)), sorted(o for o in outs if outs.count(o) > 1)
    assert all(o.startswith("tour/") for o in outs), [o for o in outs if not o.startswith("tour/")]


def test_the_tour_runs_as_written(tmp_path):
    (tmp_path / "data").symlink_to(ROOT / "data")
    (tmp_path / "docs").symlink_to(ROOT / "docs")
    bindir = tmp_path / "bin"
    bindir.mkdir()
    exe = bindir / "jaxcal"
    exe.write_text(f"#!/bin/sh\nexec {shlex.quote(sys.executable)} -m jaxcal.cli \"$@\"\n")
    exe.chmod(0o755)
    env = dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}", PYTHONPATH=str(ROOT))
    before = {p.name for p in tmp_path.iterdir()}
    for cmd in tour_commands((ROOT / "README.md").read_text()):
        r = subprocess.run(["bash", "-c", cmd], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
        if r.returncode != 0:
            pytest.fail(f"tour command failed (exit {r.returncode}): {cmd}\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}")
        warned = [ln for ln in r.stderr.splitlines() if "Warning:" in ln]
        assert not warned, f"{cmd}: a Python warning reached the user: {warned[:3]}"
    left = {p.name for p in tmp_path.iterdir()} - before
    assert left <= {"tour"}, f"the tour wrote outside tour/: {sorted(left - {'tour'})}"
