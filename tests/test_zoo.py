"""rl-baselines3-zoo end to end: train without --conf-file (the project's tuned hyperparameters),
a clear error where the project has none, enjoy, record_video and -optimize (tiny step counts).

Each command runs in a temporary directory (not the repository), as a user's would.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

rl_zoo3 = pytest.importorskip("rl_zoo3")
yaml = pytest.importorskip("yaml")

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""), "MPLBACKEND": "Agg"}
TINY = ["-n", "128", "--eval-freq", "-1", "--save-freq", "-1", "--num-threads", "1", "--seed", "0",
        "-params", "n_envs:2", "n_steps:32", "batch_size:32", "n_epochs:1"]


def _run(args, cwd, timeout=300):
    p = subprocess.run([sys.executable, *args], cwd=cwd, env=ENV, capture_output=True, text=True, timeout=timeout)
    return p.returncode, p.stdout + p.stderr


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """rl_zoo3.train --algo ppo --env TensegrityRoll-v0 --gym-packages tensegrity_gym.integrations.zoo, no --conf-file."""
    cwd = tmp_path_factory.mktemp("zoo")
    rc, out = _run(["-m", "rl_zoo3.train", "--algo", "ppo", "--env", "TensegrityRoll-v0", "--gym-packages",
                    "tensegrity_gym.integrations.zoo", "-f", "logs", *TINY], cwd)
    assert rc == 0, out[-4000:]
    return cwd, out


def test_zoo_train_uses_the_project_hyperparameters_without_conf_file(trained):
    cwd, out = trained
    from tensegrity_gym.integrations.zoo import hyperparams_file
    assert f"Loading hyperparameters from: {hyperparams_file('ppo')}" in out
    class Loader(yaml.SafeLoader):  # the zoo saves an OrderedDict: read it as its list of pairs, no objects
        pass
    Loader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict",
                           lambda loader, node: loader.construct_sequence(node.value[0], deep=True))
    cfg = yaml.load(next((cwd / "logs").rglob("config.yml")).read_text(), Loader=Loader)  # the zoo's record
    used = dict((k, v) for k, v in cfg)
    ours = yaml.safe_load(hyperparams_file("ppo").read_text())["TensegrityRoll-v0"]
    for k in ("gamma", "gae_lambda", "policy_kwargs", "normalize", "clip_range"):
        assert used[k] == ours[k], k                  # tuned values, not the zoo's generic default
    assert used["n_steps"] == 32                      # -params still override them
    assert list(cwd.rglob("TensegrityRoll-v0.zip"))


def test_zoo_without_project_hyperparameters_fails_with_a_message_saying_how(tmp_path):
    rc, out = _run(["-m", "rl_zoo3.train", "--algo", "a2c", "--env", "TensegrityRoll-v0", "--gym-packages",
                    "tensegrity_gym.integrations.zoo", "-f", "logs", "-n", "64"], tmp_path)
    assert rc != 0
    assert "no tuned a2c hyperparameters for TensegrityRoll-v0" in out and "--conf-file" in out


def test_zoo_explicit_conf_file_and_other_envs_are_left_to_the_zoo():
    import argparse
    from rl_zoo3.exp_manager import ExperimentManager
    from tensegrity_gym.integrations import zoo
    assert zoo.install() and zoo.install()                      # idempotent
    zoo_file = str(Path(rl_zoo3.__file__).parent / "hyperparams" / "ppo.yml")
    ns = argparse.Namespace()
    assert ExperimentManager(ns, "ppo", "TensegrityRoll-v0", "logs", config=zoo_file).config == zoo_file
    assert ExperimentManager(ns, "ppo", "TensegrityRoll-v0", "logs").config == str(zoo.hyperparams_file("ppo"))
    assert Path(ExperimentManager(ns, "ppo", "Pendulum-v1", "logs").config).resolve() == Path(zoo_file).resolve()


def test_importing_the_package_leaves_rl_zoo3_alone():
    """``import tensegrity_gym`` (even after the zoo) patches nothing; the registration is the
    module named in --gym-packages."""
    code = ("import rl_zoo3.exp_manager as m; init = m.ExperimentManager.__init__; import tensegrity_gym; "
            "assert m.ExperimentManager.__init__ is init; import tensegrity_gym.integrations.zoo; "
            "assert m.ExperimentManager.__init__ is not init; print('ok')")
    rc, out = _run(["-c", code], ROOT)
    assert rc == 0 and out.strip().endswith("ok"), out[-2000:]


def test_zoo_enjoy(trained):
    cwd, _ = trained
    rc, out = _run(["-m", "rl_zoo3.enjoy", "--algo", "ppo", "--env", "TensegrityRoll-v0", "--gym-packages",
                    "tensegrity_gym.integrations.zoo", "-f", "logs", "-n", "30", "--no-render", "--num-threads", "1"], cwd)
    assert rc == 0, out[-3000:]
    assert "Loading running average" in out  # the saved VecNormalize statistics were used


def test_zoo_record_video(trained):
    pytest.importorskip("moviepy")
    cwd, _ = trained
    rc, out = _run(["-m", "agents.zoo", "record_video", "--algo", "ppo", "--env", "TensegrityRoll-v0", "-f", "logs",
                    "-n", "20", "-o", "videos"], cwd)
    assert rc == 0, out[-3000:]
    videos = list((cwd / "videos").glob("*.mp4"))
    assert videos and videos[0].stat().st_size > 1000


@pytest.mark.slow
def test_zoo_optimize_writes_its_report(tmp_path):
    pytest.importorskip("optuna")
    pytest.importorskip("pandas")
    # --seed 2 with the random sampler draws n_steps 32, batch 32, 1 epoch: one small trial
    rc, out = _run(["-m", "rl_zoo3.train", "--algo", "ppo", "--env", "TensegrityShape-v0", "--gym-packages",
                    "tensegrity_gym.integrations.zoo", "-f", "logs", "-n", "128", "-optimize", "--n-trials", "1", "--n-jobs", "1",
                    "--sampler", "random", "--pruner", "none", "--n-evaluations", "1", "--eval-episodes", "1",
                    "--seed", "2", "--num-threads", "1", "--no-optim-plots", "-params", "n_envs:2"], tmp_path)
    assert rc == 0, out[-4000:]
    assert "Number of finished trials:  1" in out
    assert list(tmp_path.rglob("report_TensegrityShape-v0_*.csv"))
