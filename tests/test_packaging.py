"""Packaging: a NON-editable install works from any directory.

The repository's files (as git lists them) are copied to a temporary folder and installed with
``pip install --no-deps --no-build-isolation`` into a fresh virtual environment that sees the
test interpreter's site-packages through a ``.pth`` line (so the dependencies are there and the
install takes seconds). Then, from another temporary directory and without PYTHONPATH:
``python -m tensegrity_gym_agents.train`` (64 steps), ``python -m tensegrity_gym_agents.evaluate``,
the rl_zoo3 hyperparameter lookup and the packaged files are checked. The repository's ``agents/``
folder installs as ``tensegrity_gym_agents`` (``agents`` is another distribution's import name). Pendulum-v1 is trained there so that no numba kernel
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
    rc, out = _run(installed, ["-c", "import json, tensegrity_gym, tensegrity_gym_agents as a, "
                                     "tensegrity_gym.integrations.sb3 as s, tensegrity_gym.integrations.zoo as z; print(json.dumps("
                                     "[tensegrity_gym.__file__, a.__file__, s.__file__, "
                                     "str(z.hyperparams_file('ppo'))]))"])
    assert rc == 0, out
    paths = json.loads(out.strip().splitlines()[-1])
    for p in paths:
        assert Path(p).resolve().is_relative_to(site.resolve()), p   # from the install, not the repository
    for name in ("ppo.yml", "sac.yml", "td3.yml", "time_to_policy/ppo.yml"):
        assert (site / "tensegrity_gym_agents" / "hyperparams" / name).exists()
    for name in ("smoke.yml", "sweep1.yml"):
        assert (site / "tensegrity_gym_agents" / "sweeps" / name).exists()
    # the top-level name `agents` is not installed (it would collide with openai-agents)
    assert not (site / "agents").exists()
    top = list(site.glob("tensegrity_gym-*.dist-info/top_level.txt"))
    if top:
        assert "agents" not in top[0].read_text().split()
    lic = list(site.glob("tensegrity_gym-*.dist-info/**/LICENSE*"))
    assert lic and "MIT License" in lic[0].read_text()


@pytest.mark.slow
def test_installed_train_and_evaluate_from_any_directory(installed):
    rc, out = _run(installed, ["-m", "tensegrity_gym_agents.train", "--algo", "ppo", "--env", "Pendulum-v1", "--n-timesteps", "64",
                               "--n-envs", "2", "--eval-freq", "32", "--eval-episodes", "1", "--save-freq", "32",
                               "--no-progress-bar", "--log-dir", "run",
                               "--hyperparams", "n_steps=32", "batch_size=32", "n_epochs=1"])
    assert rc == 0, out[-3000:]
    run = installed[2] / "run"
    cfg = (run / "config.yaml").read_text()
    assert "tensegrity_gym_agents/hyperparams/ppo.yml:Pendulum-v1" in cfg   # the packaged file was found
    assert "python -m tensegrity_gym_agents.train" in (run / "command.txt").read_text()  # replayable as installed
    assert json.loads((run / "state.json").read_text())["status"] == "finished"
    rc, out = _run(installed, ["-m", "tensegrity_gym_agents.evaluate", "run", "--model", "final", "--n-episodes", "1",
                               "--out", "ev"])
    assert rc == 0, out[-3000:]
    assert (installed[2] / "ev" / "metrics.json").exists()


@pytest.mark.slow
def test_installed_loads_a_model_trained_from_a_checkout(installed):
    """A committed model trained with ``python -m agents.train`` pickled its ``lin_`` schedule as
    ``agents.common._LinearSchedule``: the installed package (no ``agents``) loads it all the same,
    and a model trained now pickles the package's own class."""
    run = ROOT / "results" / "climb" / "seed_0"
    if not (run / "model.zip").exists():
        pytest.skip("no committed climbing model")
    rc, out = _run(installed, ["-c", "import sys; from stable_baselines3 import PPO; "
                                     "from tensegrity_gym_agents import common; "
                                     f"m = common.load_model_file(PPO, {str(run / 'model.zip')!r}); "
                                     "print(type(m.learning_rate).__module__, m.learning_rate(0.5), "
                                     "'agents' in sys.modules)"])
    assert rc == 0, out[-3000:]
    assert out.split()[-3:] == ["tensegrity_gym.integrations.sb3", "0.00056", "False"], out[-500:]


def test_checkout_loads_a_model_trained_from_a_checkout_with_its_schedule():
    """From a checkout (``agents`` importable, as ``python -m agents.train --resume`` runs) the old
    pickled name resolves too: the schedule is restored, not replaced by SB3's default with a
    warning (a resumed run would then train at the default learning rate)."""
    run = ROOT / "results" / "climb" / "seed_0"
    if not (run / "model.zip").exists():
        pytest.skip("no committed climbing model")
    code = ("import warnings; warnings.simplefilter('error'); from stable_baselines3 import PPO; "
            f"from agents import common; m = common.load_model_file(PPO, {str(run / 'model.zip')!r}); "
            "print(type(m.learning_rate).__name__, m.learning_rate(0.5))")
    p = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    assert p.stdout.split()[-2:] == ["LinearSchedule", "0.00056"], p.stdout


def test_checkout_loads_a_committed_model_with_its_normalisation():
    """A committed model whose pickles name a module of this package
    (``tensegrity_gym.integrations.sb3``'s schedule) and its VecNormalize statistics load through
    the project's loaders, warnings as errors, and the policy acts on a normalised observation."""
    runs = [ROOT / "results" / "climb_randomized" / "seed_0"] + sorted(ROOT.glob("results/*/seed_0"))
    run = next((r for r in runs if (r / "model.zip").exists() and (r / "vecnormalize.pkl").exists()), None)
    if run is None:
        pytest.skip("no committed model with its normalisation")
    algo = next(line.split(":", 1)[1].strip() for line in (run / "config.yaml").read_text().splitlines()
                if line.startswith("algo:"))
    code = ("import warnings; warnings.simplefilter('error'); import numpy as np; "
            f"import stable_baselines3 as sb3; from agents import common; Algo = getattr(sb3, {algo.upper()!r}); "
            f"m = common.load_model_file(Algo, {str(run / 'model.zip')!r}, device='cpu'); "
            f"vn = common.load_vecnormalize_file({str(run / 'vecnormalize.pkl')!r}); "
            "obs = np.zeros((1,) + m.observation_space.shape, np.float32); "
            "a, _ = m.predict(vn.normalize_obs(obs), deterministic=True); "
            "print(type(vn).__name__, a.shape == (1,) + m.action_space.shape, bool(np.isfinite(a).all()))")
    p = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    assert p.stdout.split()[-3:] == ["VecNormalize", "True", "True"], p.stdout


@pytest.mark.slow
def test_installed_zoo_reads_the_packaged_hyperparameters(installed):
    pytest.importorskip("rl_zoo3")
    code = ("import argparse, rl_zoo3.exp_manager, tensegrity_gym.integrations.zoo\n"
            "from rl_zoo3.exp_manager import ExperimentManager\n"
            "m = ExperimentManager(argparse.Namespace(), 'ppo', 'TensegrityRoll-v0', 'logs')\n"
            "print('CONF', m.config)\n"
            "hp, _ = m.read_hyperparameters()\n"
            "print('GAMMA', hp['gamma'])\n")
    rc, out = _run(installed, ["-c", code])
    assert rc == 0, out[-3000:]
    conf = next(l.split(" ", 1)[1] for l in out.splitlines() if l.startswith("CONF"))
    assert Path(conf).resolve() == (installed[1] / "tensegrity_gym_agents" / "hyperparams" / "ppo.yml").resolve()
    assert "GAMMA 0.99" in out


# ---------------------------------------------------------------------- layout (fast)
def test_pyproject_lists_every_package():
    """pyproject.toml lists the packages by name (agents/ is mapped to tensegrity_gym_agents, which
    package discovery cannot do): a new sub-package must be added there, or it would not ship."""
    tomllib = pytest.importorskip("tomllib")   # Python 3.11+
    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(conf["packages"])
    found = {".".join(f.parent.relative_to(ROOT).parts) for f in (ROOT / "tensegrity_gym").rglob("__init__.py")}
    assert found <= listed, sorted(found - listed)
    assert conf["package-dir"] == {"tensegrity_gym_agents": "agents"}
    assert "tensegrity_gym_agents" in listed and not any(p == "agents" or p.startswith("agents.") for p in listed)
    assert not list((ROOT / "agents").rglob("*/__init__.py"))      # agents/ has no sub-packages to list


def test_agents_modules_import_each_other_relatively():
    """Inside agents/, ``from agents import ...`` would fail once installed as tensegrity_gym_agents."""
    offenders = [str(f.relative_to(ROOT)) for f in (ROOT / "agents").glob("*.py")
                 if "from agents" in f.read_text() or "import agents" in f.read_text()]
    assert not offenders, offenders


def test_no_sys_path_edits_in_scripts_agents_or_package():
    offenders = []
    for folder in ("scripts", "agents", "tensegrity_gym"):
        for f in (ROOT / folder).rglob("*.py"):
            if "sys.path.insert" in f.read_text() or "sys.path.append" in f.read_text():
                offenders.append(str(f.relative_to(ROOT)))
    assert not offenders, offenders


def _script_helpers():
    """scripts/_bench.py, which the scripts import as ``scripts._bench`` (it is not installed)."""
    import importlib
    return importlib.import_module("scripts._bench")


def test_benchmark_helpers_are_not_in_the_package():
    assert not (ROOT / "tensegrity_gym" / "_bench.py").exists()
    assert not list((ROOT / "results").rglob("*.py"))


def test_shared_script_helpers():
    import numpy as np
    from tensegrity_gym.core import builders
    from tensegrity_gym.core.model import compile_model
    _bench = _script_helpers()
    rng = np.random.default_rng(0)
    t = _bench.timeit(lambda: sum(range(100)), target=0.01, repeats=1)
    assert 0 < t < 1e-3
    out, wall = _bench.timed(lambda: 3, wall_min=0.0)
    assert out == 3 and wall >= 0
    m = compile_model(builders.prism(3))
    xml = _bench.mjcf(m)
    assert xml.count("<freejoint") == m.n_bars and xml.count("<spatial") == m.n_strings
    # a rigid rotation of a node set is recovered
    from scipy.spatial.transform import Rotation
    p = rng.normal(size=(1, 6, 3))
    p -= p.mean(axis=1, keepdims=True)
    rv = np.array([[0.1, -0.2, 0.3]])
    cur = p @ Rotation.from_rotvec(rv[0]).as_matrix().T
    np.testing.assert_allclose(_bench.rotation_vectors(p, cur), rv, atol=1e-12)


def test_script_mjcf_is_the_package_writer_and_takes_our_state():
    """scripts/_bench.mjcf is io.mjcf.to_mjcf; mj_set_state puts our state into it: MuJoCo's node
    sites land on our node positions."""
    mujoco = pytest.importorskip("mujoco")
    import numpy as np
    from tensegrity_gym.core import builders
    from tensegrity_gym.core.model import compile_model, initial_state
    from tensegrity_gym.physics.geometry import node_positions
    from tensegrity_gym.io.mjcf import to_mjcf
    _bench = _script_helpers()
    m = compile_model(builders.prism(3))
    assert _bench.mjcf(m, "RK4", dt=1e-4) == to_mjcf(m.structure, timestep=1e-4, integrator="RK4")
    mm = mujoco.MjModel.from_xml_string(_bench.mjcf(m))
    d = mujoco.MjData(mm)
    st = initial_state(m, nodes=m.structure.nodes + 0.01 * np.random.default_rng(1).standard_normal(
        m.structure.nodes.shape))
    _bench.mj_set_state(mujoco, mm, d, m, st.q[0], st.qd[0])
    np.testing.assert_allclose(_bench.mj_node_positions(mujoco, mm, d, m.n_nodes),
                               node_positions(m, st.q)[0], atol=1e-12)


def test_scripts_import_the_agents_package_by_its_installed_name():
    """After an install the agents package is importable only as tensegrity_gym_agents (the
    checkout's ``agents/`` is on sys.path only when a script runs from the repository root), so a
    script importing 'agents' would stop with ModuleNotFoundError."""
    import re
    bad = [f"{p.name}:{i}" for p in sorted((ROOT / "scripts").rglob("*.py"))
           for i, line in enumerate(p.read_text().splitlines(), 1)
           if re.match(r"\s*(from agents(\.|\s)|import agents\b)", line)]
    assert not bad, f"scripts import 'agents' (use tensegrity_gym_agents): {bad}"
