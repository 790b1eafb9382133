"""jaxcal installs as users install it: ``python -m build`` makes an sdist and a wheel, the wheel
holds every ``jaxcal`` module and the console script, and that script runs from the installed wheel
(not from this checkout). Also the path ``pip install .`` takes: the wheel is built from the sdist,
as pip builds a clone."""

from __future__ import annotations

import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _modules_in_checkout() -> set[str]:
    return {p.relative_to(ROOT).as_posix() for p in (ROOT / "jaxcal").rglob("*.py")}


@pytest.fixture(scope="module")
def dist(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    # `python -m build` builds the sdist, then the wheel *from the sdist* (so a file the sdist lacks
    # breaks the wheel too); isolated build env with setuptools from pyproject's [build-system].
    r = subprocess.run([sys.executable, "-m", "build", "--outdir", str(out), str(ROOT)],
                       capture_output=True, text=True, cwd=out, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return out


def test_sdist_and_wheel_hold_every_module_and_the_license(dist):
    (sdist,) = dist.glob("jaxcal-*.tar.gz")
    (wheel,) = dist.glob("jaxcal-*-py3-none-any.whl")
    with tarfile.open(sdist) as tf:
        in_sdist = {n.split("/", 1)[1] for n in tf.getnames() if "/" in n}
    with zipfile.ZipFile(wheel) as zf:
        in_wheel = set(zf.namelist())
        entry_points = next(zf.read(n).decode() for n in in_wheel if n.endswith("entry_points.txt"))
    expected = _modules_in_checkout()
    assert expected <= in_sdist, sorted(expected - in_sdist)
    assert expected <= in_wheel, sorted(expected - in_wheel)
    assert {"pyproject.toml", "README.md", "LICENSE"} <= in_sdist
    assert any(n.endswith("licenses/LICENSE") for n in in_wheel)
    assert "jaxcal = jaxcal.cli:main" in entry_points


def test_console_script_runs_from_the_installed_wheel(dist, tmp_path):
    (wheel,) = dist.glob("jaxcal-*-py3-none-any.whl")
    target = tmp_path / "site"
    # Install only jaxcal (its dependencies are this venv's); a target folder stands in for a fresh env.
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
                        "--target", str(target), str(wheel)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    script = target / "bin" / "jaxcal"
    assert script.exists()
    env = {"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin", "JAX_PLATFORMS": "cpu"}
    # cwd outside the checkout, so `import jaxcal` cannot find the source tree.
    where = subprocess.run([sys.executable, "-c", "import jaxcal; print(jaxcal.__file__)"],
                           capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120)
    assert where.returncode == 0, where.stderr[-2000:]
    assert Path(where.stdout.strip()).is_relative_to(target)
    version = subprocess.run([sys.executable, str(script), "--version"], capture_output=True, text=True,
                             cwd=tmp_path, env=env, timeout=120)
    assert version.returncode == 0, version.stderr[-2000:]
    assert version.stdout.split() == ["jaxcal", _version_in_pyproject()]
    listed = subprocess.run([sys.executable, str(script), "methods"], capture_output=True, text=True,
                            cwd=tmp_path, env=env, timeout=120)
    assert listed.returncode == 0, listed.stderr[-2000:]
    assert {"linear", "multipos", "online", "nn"} <= {line.split()[0] for line in listed.stdout.splitlines() if line}


def _version_in_pyproject() -> str:
    import tomllib

    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
