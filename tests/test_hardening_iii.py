"""Hardening III: inputs of a hostile pass that gave a wrong result, a silent no-op or a traceback,
each now a clear error naming the argument (one line from the CLI) or a correct result. The
curriculum hooks (a climb's slope range, the vector env's ``set_attr``, ``env_idx``), terrain
numbers out of any physical range, a navigation grid or scan too large for memory, and system
identification's verdict, initial values and help."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from tensegrity_gym.envs.vector_rules import reset_mask_option     # (importing the package registers the envs)

CLIMB, ROLL, SHAPE = "TensegrityClimb-v0", "TensegrityRoll-v0", "TensegrityShape-v0"
VEC = dict(vectorization_mode="vector_entry_point")


# ---------------------------------------------------------------- curriculum hooks
@pytest.fixture(scope="module")
def climb_vec():
    v = gym.make_vec(CLIMB, num_envs=3, slope_range=(5.0, 10.0), **VEC)
    yield v
    v.close()


@pytest.mark.parametrize("value, match", [
    ((89.0, 300.0), r"slope_range\[0\]: must be in \[0, 60\] degrees, got 89"),
    ((float("nan"), float("nan")), r"slope_range\[0\]: must be in \[0, 60\] degrees, got nan"),
    ("ab", r"slope_range: expected \(low, high\) degrees, got 'ab'"),
    ((1e400, 1e400), r"slope_range\[0\]: must be in"),
    ((30.0, 10.0), r"slope_range: low 30 is above high 10"),
])
def test_slope_range_is_validated_when_set(climb_vec, value, match):
    task = climb_vec.unwrapped.task
    with pytest.raises(ValueError, match=match):
        task.slope_range = value
    assert task.slope_range == (5.0, 10.0)


def test_slope_range_set_between_episodes_draws_from_it(climb_vec):
    task = climb_vec.unwrapped.task
    try:
        task.slope_range = (20.0, 30.0)
        _, info = climb_vec.reset(seed=1)
        assert np.all((info["slope_deg"] >= 20.0) & (info["slope_deg"] <= 30.0))
        climb_vec.set_attr("slope_range", (40.0, 40.0))       # through set_attr: one (low, high) pair
        assert climb_vec.get_attr("slope_range") == ((40.0, 40.0),) * 3
        _, info = climb_vec.reset(seed=1)
        np.testing.assert_array_equal(info["slope_deg"], 40.0)
        with pytest.raises(ValueError, match=r"slope_range\[1\]"):
            climb_vec.set_attr("slope_range", (0.0, 61.0))
    finally:
        task.slope_range = (5.0, 10.0)


def test_slope_range_on_a_fixed_slope_env_is_refused_not_ignored():
    env = gym.make(CLIMB, slope_deg=10.0)
    task = env.unwrapped.task
    with pytest.raises(ValueError, match=r"slope_range: this env was built with the fixed slope_deg=10 degrees"):
        task.slope_range = (5.0, 20.0)
    with pytest.raises(ValueError, match=r"slope_range: .*fixed slope_deg=10"):
        task.slope_range = (20.0, 20.0)
    task.slope_range = (10.0, 10.0)                      # its own slope: nothing changes
    _, info = env.reset(seed=0)
    assert info["slope_deg"] == 10.0
    env.close()


def test_vector_set_attr_forwards_terrain_difficulty_to_the_task():
    v = gym.make_vec(ROLL, num_envs=2, **VEC)
    v.set_attr("terrain_difficulty", 0.0)
    assert v.unwrapped.task.terrain_difficulty == 0.0
    assert "terrain_difficulty" not in vars(v)           # not a new attribute on the shell
    assert v.get_attr("terrain_difficulty") == (0.0, 0.0)
    with pytest.raises(ValueError, match=r"terrain_difficulty: must be in \[0, 1\], got 2"):
        v.set_attr("terrain_difficulty", 2)
    v.close()


@pytest.mark.parametrize("name, value, match", [
    ("num_envs", 7, r"set_attr\('num_envs'\): is read-only on TensegrityRollVectorEnv; settable: \["),
    ("courses", None, r"set_attr\('courses'\): is not an attribute of TensegrityRollVectorEnv"),
    ("task", None, r"set_attr\('task'\): is read-only"),
    ("np_random", [1, 2], r"set_attr\('np_random'\): env 0: expected a numpy.random.Generator, got 1"),
    ("max_episode_steps", 0, r"max_episode_steps"),
    ("autoreset_mode", "sometimes", r"autoreset_mode: expected one of"),
])
def test_vector_set_attr_refuses_read_only_unknown_and_bad_values(name, value, match):
    v = gym.make_vec(ROLL, num_envs=2, **VEC)
    with pytest.raises(ValueError, match=match):
        v.set_attr(name, value)
    assert v.num_envs == 2 and len(v.np_random_list) == 2
    v.reset(seed=0)
    v.step(np.zeros((2, v.single_action_space.shape[0])))     # nothing broken
    v.close()


def test_terrain_difficulty_is_not_a_hook_of_the_climb_env(climb_vec):
    with pytest.raises(ValueError, match=r"set_attr\('terrain_difficulty'\): .*settable: .*'slope_range'"):
        climb_vec.set_attr("terrain_difficulty", 0.0)


@pytest.mark.parametrize("idx", [[-1], [0, -3], [3]])
def test_env_idx_refuses_negative_indices_as_out_of_range(idx):
    with pytest.raises(ValueError, match=r"options\['env_idx'\]: indices must lie in \[0, 3\)"):
        reset_mask_option({"env_idx": idx}, 3)
    mask, _ = reset_mask_option({"env_idx": [2, 0]}, 3)
    np.testing.assert_array_equal(mask, [True, False, True])
