"""Packaging: a NON-editable install works from any directory.

The repository's files (as git lists them) are copied to a temporary folder and installed with
``pip install --no-deps --no-build-isolation`` into a fresh virtual environment that sees the
test interpreter's site-packages through a ``.pth`` line (so the dependencies are there and the
install takes seconds). Then, from another temporary directory and without PYTHONPATH:
``python -m agents.train`` (64 steps), ``python -m agents.evaluate``, the rl_zoo3 hyperparameter
lookup and the packaged files are checked. Pendulum-v1 is trained there so that no numba kernel
has to compile in the fresh install (~70 s on 2 cores); the tensegrity envs are trained by the
other tests.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
pytest.importorskip("stable_baselines3")
pytest.importorskip("yaml")


def _tracked_files() -> list[str]:
    p = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip("not a git checkout")
    return [f for f in p.stdout.splitlines() if f and not f.startswith("results/") and (ROOT / f).is_file()]


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    base = tmp_path_factory.mktemp("pkg")
    src = base / "src"
    for f in _tracked_files():
        (src / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / f, src / f)
    vdir = base / "venv"
    venv.EnvBuilder(with_pip=False).create(vdir)
    py = vdir / ("Scripts/python.exe" if os.name == "nt" else "bin/python")
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    Path(site, "_shared_site.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["MPLBACKEND"] = "Agg"
    p = subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", str(src)],
                       cwd=str(base), env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    shutil.rmtree(src)  # nothing may come from the source tree any more
    work = base / "work"
    work.mkdir()
    return py, Path(site), work, env


def _run(installed, args, timeout=300):
    py, _, work, env = installed
    p = subprocess.run([str(py), *args], cwd=str(work), env=env, capture_output=True, text=True, timeout=timeout)
    return p.returncode, p.stdout + p.stderr


@pytest.mark.slow
def test_installed_package_ships_agents_hyperparams_adapter_and_license(installed):
    py, site, work, env = installed
    rc, out = _run(installed, ["-c", "import json, tensegrity_gym, agents, tensegrity_gym.sb3 as s, "
                                     "tensegrity_gym.zoo as z; print(json.dumps([tensegrity_gym.__file__, "
                                     "agents.__file__, s.__file__, str(z.hyperparams_file('ppo'))]))"])
    assert rc == 0, out
    paths = json.loads(out.strip().splitlines()[-1])
    for p in paths:
        assert Path(p).resolve().is_relative_to(site.resolve()), p   # from the install, not the repository
    for name in ("ppo.yml", "sac.yml", "td3.yml"):
        assert (site / "agents" / "hyperparams" / name).exists()
    for name in ("smoke.yml", "sweep1.yml"):
        assert (site / "agents" / "sweeps" / name).exists()
    lic = list(site.glob("tensegrity_gym-*.dist-info/**/LICENSE*"))
    assert lic and "MIT License" in lic[0].read_text()


@pytest.mark.slow
def test_installed_train_and_evaluate_from_any_directory(installed):
    rc, out = _run(installed, ["-m", "agents.train", "--algo", "ppo", "--env", "Pendulum-v1", "--n-timesteps", "64",
                               "--n-envs", "2", "--eval-freq", "32", "--eval-episodes", "1", "--save-freq", "32",
                               "--no-progress-bar", "--log-dir", "run",
                               "--hyperparams", "n_steps=32", "batch_size=32", "n_epochs=1"])
    assert rc == 0, out[-3000:]
    run = installed[2] / "run"
    cfg = (run / "config.yaml").read_text()
    assert "agents/hyperparams/ppo.yml:Pendulum-v1" in cfg          # the packaged file was found
    assert json.loads((run / "state.json").read_text())["status"] == "finished"
    rc, out = _run(installed, ["-m", "agents.evaluate", "run", "--model", "final", "--n-episodes", "1",
                               "--out", "ev"])
    assert rc == 0, out[-3000:]
    assert (installed[2] / "ev" / "metrics.json").exists()


@pytest.mark.slow
def test_installed_zoo_reads_the_packaged_hyperparameters(installed):
    pytest.importorskip("rl_zoo3")
    code = ("import argparse, rl_zoo3.exp_manager, tensegrity_gym\n"
            "from rl_zoo3.exp_manager import ExperimentManager\n"
            "m = ExperimentManager(argparse.Namespace(), 'ppo', 'TensegrityRoll-v0', 'logs')\n"
            "print('CONF', m.config)\n"
            "hp, _ = m.read_hyperparameters()\n"
            "print('GAMMA', hp['gamma'])\n")
    rc, out = _run(installed, ["-c", code])
    assert rc == 0, out[-3000:]
    conf = next(l.split(" ", 1)[1] for l in out.splitlines() if l.startswith("CONF"))
    assert Path(conf).resolve() == (installed[1] / "agents" / "hyperparams" / "ppo.yml").resolve()
    assert "GAMMA 0.99" in out
