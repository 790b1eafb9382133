"""The README's tour runs as written (issue 29, point 4).

The ```bash block under "### Tour" is executed command by command in a temporary folder that holds
the repository's ``data/`` and ``docs/`` (links): every command must exit 0 without a Python warning on stderr, no two commands may
write the same output, and nothing may be written outside ``tour/`` (the tour's own folder). A
placeholder (a file the tour never made and the repository does not hold) fails the command, so
the test also proves that the tour has none.

The first ``jaxcal`` command, and every command that is not ``jaxcal``, runs through ``bash`` with a
``jaxcal`` executable on the PATH, as a user types it (a fresh interpreter: import-time warnings
show there). The other ``jaxcal`` commands run in this process through ``jaxcal.cli.main`` with the
same arguments (``shlex`` splits them as bash does): the same code from argument parsing on, without
an interpreter start and a re-import per command, and with the compiled code of one command there
for the next (``diagnose`` then ``align`` on one recording). Timed as whole ``pytest`` processes on
the 2-core machine, this test alone against the previous all-subprocess version, three runs each in
turn, warm compilation cache, the other core busy: wall 291 -> 191 s (medians; ratio 0.66, range
0.63-0.66), at the cost of peak memory 0.83 -> 3.0 GiB (one process holds every command's compiled
code). It also checks that no command depends on a fresh
process: state one command leaves behind would show up in the next. Warnings are shown as a fresh
interpreter shows them (Python's default filters) and fail the command alike.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SKIP = ("source .venv/bin/activate",)
OUT_FLAGS = ("--out", "--model-out")  # the CLI's flags that name a file it writes


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
    return [words[i + 1] for i, w in enumerate(words[:-1]) if w in OUT_FLAGS]


def test_the_tour_block_is_parsed():
    cmds = tour_commands((ROOT / "README.md").read_text())
    assert len(cmds) >= 10 and all(c.split()[0] in ("jaxcal", "mkdir", "ls", "rm") for c in cmds), cmds


def test_no_two_tour_commands_write_the_same_output():
    outs = [o for c in tour_commands((ROOT / "README.md").read_text()) for o in _outputs(c)]
    assert len(outs) == len(set(outs)), sorted(o for o in outs if outs.count(o) > 1)
    assert all(o.startswith("tour/") for o in outs), [o for o in outs if not o.startswith("tour/")]


def _tour_path_words(words: list[str]) -> list[str]:
    """The words of a command that name files: under ``data/``, ``docs/`` or ``tour/``."""
    return [w for w in words if w.split("/", 1)[0] in ("data", "docs", "tour") and "/" in w]


def test_every_tour_command_parses_and_reads_only_what_exists():
    """Each tour command's arguments parse with ``jaxcal``'s own parser (no flag the CLI lacks),
    every ``data/`` or ``docs/`` file it reads is in the repository, and every ``tour/`` file it
    reads was written by an earlier command (its ``--out``, or inside an earlier ``--out`` folder).
    This is the tour's fast check: the commands themselves run in :func:`test_the_tour_runs_as_written`
    (slow tier), and each subcommand runs in the fast tier's own CLI tests."""
    from jaxcal.cli import build_parser

    parser, written, n = build_parser(), [], 0
    for cmd in tour_commands((ROOT / "README.md").read_text()):
        words = shlex.split(cmd)
        if words[0] != "jaxcal":
            continue
        if "--help" not in words:
            parser.parse_args(words[1:])  # SystemExit(2) on a flag or value the CLI does not take
            n += 1
        outs = _outputs(cmd)
        for w in _tour_path_words(words):
            if w in outs:
                continue
            if w.startswith("tour/"):
                assert any(w == o or (o.endswith("/") and w.startswith(o)) for o in written), f"{cmd}: reads {w} before any command writes it"
            else:
                assert (ROOT / w).exists(), f"{cmd}: {w} is not in the repository"
        written += outs
    assert n >= 20, n


@pytest.mark.slow
def test_the_tour_runs_as_written(tmp_path, monkeypatch):
    """Every tour command, in order, as a user types it (170 s on the 2-core CI machine).

    Fast cover: tests/test_readme_tour.py::test_every_tour_command_parses_and_reads_only_what_exists
    (every command parses and reads only files that exist or an earlier command wrote),
    tests/test_readme_tour.py::test_no_two_tour_commands_write_the_same_output,
    tests/test_cli.py::test_multipos_cli_turns_on_imucal_session (calibrate multipos with --turns),
    tests/test_cli.py::test_online_without_labels_beats_spec (calibrate online),
    tests/test_noise_cli.py::test_imu_yaml_recovers_known_noise (noise),
    tests/test_cli_apply_output.py::test_noise_and_diagnose_read_the_applied_output (apply, diagnose)
    """
    (tmp_path / "data").symlink_to(ROOT / "data")
    (tmp_path / "docs").symlink_to(ROOT / "docs")
    bindir = tmp_path / "bin"
    bindir.mkdir()
    exe = bindir / "jaxcal"
    exe.write_text(f"#!/bin/sh\nexec {shlex.quote(sys.executable)} -m jaxcal.cli \"$@\"\n")
    exe.chmod(0o755)
    env = dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}", PYTHONPATH=str(ROOT))
    before = {p.name for p in tmp_path.iterdir()}
    shell_done = False
    for cmd in tour_commands((ROOT / "README.md").read_text()):
        words = shlex.split(cmd)
        if words[0] == "jaxcal" and shell_done:
            rc, stdout, stderr = _in_process(words[1:], tmp_path, monkeypatch)
        else:
            r = subprocess.run(["bash", "-c", cmd], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
            rc, stdout, stderr = r.returncode, r.stdout, r.stderr
            shell_done = shell_done or words[0] == "jaxcal"
        if rc != 0:
            pytest.fail(f"tour command failed (exit {rc}): {cmd}\n{stdout[-2000:]}\n{stderr[-2000:]}")
        warned = [ln for ln in stderr.splitlines() if "Warning:" in ln]
        assert not warned, f"{cmd}: a Python warning reached the user: {warned[:3]}"
    assert shell_done, "no jaxcal command ran through the shell"
    left = {p.name for p in tmp_path.iterdir()} - before
    assert left <= {"tour"}, f"the tour wrote outside tour/: {sorted(left - {'tour'})}"


def _fresh_interpreter_filters() -> None:
    """Python's own warning filters in a fresh interpreter (what a user's shell shows)."""
    warnings.resetwarnings()
    for category in (ResourceWarning, ImportWarning, PendingDeprecationWarning, DeprecationWarning):
        warnings.filterwarnings("ignore", category=category)
    warnings.filterwarnings("default", category=DeprecationWarning, module="__main__")


def _in_process(argv: list[str], cwd: Path, monkeypatch) -> tuple[int, str, str]:
    """``jaxcal.cli.main(argv)`` from ``cwd``: exit status, stdout, and stderr with every warning a
    fresh interpreter would show appended as its ``Category: message`` line."""
    from jaxcal.cli import main

    out, err = io.StringIO(), io.StringIO()
    with monkeypatch.context() as m, warnings.catch_warnings(record=True) as caught:
        m.chdir(cwd)
        _fresh_interpreter_filters()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main(argv)
    shown = [f"{w.category.__name__}: {w.message}" for w in caught]
    return rc, out.getvalue(), err.getvalue() + "".join(f"\n{ln}" for ln in shown)
