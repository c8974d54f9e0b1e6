"""The worked example "Adding a task" of docs/architecture.md, kept true.

A yaw-rate "turn" task is one module (this file's ``TurnTask`` and its two env shells) and one
registration call: its one piece of state (``heading``) is a ``StateField`` row, and its
reset and step are written once over the task's record, so the NumPy vector env and the torch
device env (host and device resets) run the same code and agree.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import gymnasium as gym

from tensegrity_gym.envs import register_task
from tensegrity_gym.envs.roll import RollTask
from tensegrity_gym.envs.shells import TaskEnv, TaskVectorEnv
from tensegrity_gym.tasks.state import StateField
from tensegrity_gym.tasks.xp import namespace

ENV_ID = "TensegrityTurnExample-v0"


def heading(q):
    """(B,) yaw of rod 0's axis about the vertical, rad (``q`` (B, k, 6): centres, then axes)."""
    return namespace(q).arctan2(q[:, 0, 4], q[:, 0, 3])


class TurnTask(RollTask):
    """The rolling robot rewarded for turning: ``reward_turn`` = ``turn_weight`` x the yaw rate
    (rad/s) of rod 0 about the vertical; info ``yaw_rate`` (rad/s)."""

    STATE = RollTask.STATE + (StateField("heading"),)

    def __init__(self, num_envs: int = 1, turn_weight: float = 1.0, **kwargs):
        self.turn_weight = float(turn_weight)
        super().__init__(num_envs, **kwargs)
        self.heading = heading(self.q)

    def reset_info(self, rec, rows) -> dict:
        rec.heading[rows] = heading(rec.q[rows])
        return super().reset_info(rec, rows)

    def task_step(self, rec, com0, com, action):
        terms, terminated, infos = super().task_step(rec, com0, com, action)
        xp = namespace(com)
        h = heading(rec.q)
        d = h - rec.heading
        rate = xp.arctan2(xp.sin(d), xp.cos(d)) / self.control_dt
        rec.heading = h
        terms["turn"] = self.turn_weight * rate
        infos["yaw_rate"] = rate
        return terms, terminated, infos


TensegrityTurnEnv = TaskEnv.for_task(TurnTask, ENV_ID, TurnTask.__doc__, __name__)
TensegrityTurnVectorEnv = TaskVectorEnv.for_task(TurnTask, ENV_ID, TurnTask.__doc__, __name__)
register_task(ENV_ID, f"{__name__}:TensegrityTurnEnv", f"{__name__}:TensegrityTurnVectorEnv", 1000)


def _run(env, steps, as_tensor=None):
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=4)
    out = [np.asarray(obs, float)]
    rewards, rates = [], []
    for _ in range(steps):
        a = rng.uniform(-1, 1, env.action_space.shape)
        obs, r, term, trunc, info = env.step(a if as_tensor is None else as_tensor(a))
        out.append(np.asarray(obs, float))
        rewards.append(np.asarray(r, float))
        rates.append(np.asarray(info["yaw_rate"], float))
    return np.array(out), np.array(rewards), np.array(rates)


def test_turn_task_single_and_vector_env():
    single = gym.make(ENV_ID)
    _, info = single.reset(seed=1)
    _, r, _, _, info = single.step(single.action_space.sample())
    assert {"reward_turn", "reward_forward", "reward_ctrl", "yaw_rate"} <= set(info)
    assert np.isclose(r, info["reward_turn"] + info["reward_forward"] + info["reward_ctrl"])
    vec = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode="vector_entry_point", turn_weight=2.0)
    assert isinstance(vec, TensegrityTurnVectorEnv) and vec.task.turn_weight == 2.0
    _, _, rates = _run(vec, 5)
    assert np.all(np.isfinite(rates)) and np.any(rates != 0)


def test_turn_task_torch_device_env_runs_the_same_task():
    torch = pytest.importorskip("torch")
    kw = dict(num_envs=3, vectorization_mode="vector_entry_point", max_episode_steps=12)
    ref = _run(gym.make_vec(ENV_ID, **kw), 30)
    dev = gym.make_vec(ENV_ID, backend="torch", dtype="float64", **kw)
    assert type(dev).TASK is TurnTask
    got = _run(dev, 30, lambda a: torch.as_tensor(a, dtype=torch.float64))
    # two autoresets in 30 steps: the heading's reset is the task's. The NumPy env's observation
    # is float32 (the torch env's float64 before that cast); rewards and yaw rates float64
    np.testing.assert_allclose(got[0].astype(np.float32), ref[0], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(got[1], ref[1], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got[2], ref[2], rtol=1e-9, atol=1e-9)
    # device resets: the same record function sets the heading of the reset rows
    dev = gym.make_vec(ENV_ID, backend="torch", dtype="float64", reset_sampling="device", **kw)
    dev.reset(seed=2)
    np.testing.assert_array_equal(dev.heading.numpy(), heading(dev.q).numpy())


def test_the_documented_example_is_this_module():
    doc = (Path(__file__).parents[1] / "docs" / "architecture.md").read_text()
    block = re.search(r"\*\*a task\*\*.*?```python\n(.*?)```", doc, re.S).group(1)
    own = {line.strip() for line in Path(__file__).read_text().splitlines()}
    missing = [line for line in block.splitlines() if line.strip() and line.strip() not in own]
    assert not missing, f"docs/architecture.md's task example differs from this module: {missing}"
