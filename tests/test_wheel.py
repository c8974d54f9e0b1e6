"""The built wheel holds every file of the package folders that git tracks.

``pip wheel --no-deps --no-build-isolation`` builds the wheel from a copy of the tracked files
(offline, a few seconds); its file list must hold each tracked file under ``tensegrity_gym/`` and
``agents/`` (installed as ``tensegrity_gym_agents/``): Python modules, the hyperparameter and
sweep files of every subfolder, the JSON schemas, the README. A data file the package-data globs
miss would be absent from an installed package only (a checkout has it).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: source folder -> its import name in the installed package
PACKAGE_DIRS = {"tensegrity_gym": "tensegrity_gym", "agents": "tensegrity_gym_agents"}


def _tracked() -> list[str]:
    p = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip("not a git checkout")
    return [f for f in p.stdout.splitlines() if f and (ROOT / f).is_file()]


@pytest.fixture(scope="module")
def wheel_files(tmp_path_factory) -> set[str]:
    pytest.importorskip("setuptools")
    pytest.importorskip("wheel")
    base = tmp_path_factory.mktemp("wheel")
    src = base / "src"
    for f in _tracked():
        if f.startswith("results/"):
            continue
        (src / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / f, src / f)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    p = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
                        "-w", str(base / "dist"), str(src)], cwd=str(base), env=env, capture_output=True,
                       text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    (whl,) = (base / "dist").glob("tensegrity_gym-*.whl")
    with zipfile.ZipFile(whl) as z:
        return set(z.namelist())


def _expected() -> list[str]:
    out = []
    for f in _tracked():
        top, _, rest = f.partition("/")
        if top in PACKAGE_DIRS and rest:
            out.append(f"{PACKAGE_DIRS[top]}/{rest}")
    return out


def test_wheel_holds_every_tracked_package_file(wheel_files):
    expected = _expected()
    assert any(f.startswith("tensegrity_gym_agents/hyperparams/") and f.count("/") >= 3 for f in expected)
    missing = sorted(f for f in expected if f not in wheel_files)
    assert not missing, f"tracked but not in the wheel (pyproject.toml [tool.setuptools.package-data]): {missing}"


def test_wheel_ships_the_hyperparameter_and_sweep_files_and_schemas(wheel_files):
    for name in ("hyperparams/ppo.yml", "hyperparams/navigate/ppo.yml", "hyperparams/time_to_policy/ppo.yml",
                 "hyperparams/climb/ppo.yml", "sweeps/smoke.yml", "README.md"):
        assert f"tensegrity_gym_agents/{name}" in wheel_files, name
    for name in ("structure.schema.json", "terrain.schema.json"):
        assert f"tensegrity_gym/{name}" in wheel_files, name
    assert not any(f.startswith("agents/") for f in wheel_files)   # installed under its own name only
