"""Inputs that were accepted and failed later (inside a step, hours into a training) or silently:
robot parameters against the physics' limits, observation noise in float32, agents'
hyperparameters. Each must be a clear ValueError at construction naming the argument."""
from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import tensegrity_gym  # noqa: F401  (registers the envs)

SHAPE, ROLL = "TensegrityShape-v0", "TensegrityRoll-v0"


def _shortest(env_id):
    env = gym.make(env_id)
    t = env.unwrapped.task
    out = float(np.min(np.where(t.model.active, np.inf, t.model.rest_length)))
    act = t.actuation
    out = min(out, float(act.low.min())) if act.mode == "rest_length" else out
    env.close()
    return out


# ---------------------------------------------------------------- rest lengths stay positive
@pytest.mark.parametrize("env_id", [SHAPE, ROLL])
def test_rest_length_offset_spread_at_the_shortest_rest_length_is_refused(env_id):
    s = _shortest(env_id)
    with pytest.raises(ValueError, match=r"rest_length_offset.*string \d+ .*rest lengths must stay > 0"):
        gym.make(env_id, randomize={"rest_length_offset": s})
    with pytest.raises(ValueError, match=r"rest_length_offset.*rest lengths must stay > 0"):
        gym.make(env_id, params={"rest_length_offset": -0.6 * s}, randomize={"rest_length_offset": 0.5 * s})
    env = gym.make(env_id, randomize={"rest_length_offset": 0.5 * s})   # below it: fine, and runs
    env.reset(seed=0)
    for _ in range(3):
        obs, *_ = env.step(env.action_space.sample())
    assert np.all(np.isfinite(obs))
    env.close()


def test_rest_length_offset_refused_for_the_device_reset_too():
    pytest.importorskip("torch")
    s = _shortest(ROLL)
    with pytest.raises(ValueError, match=r"rest_length_offset.*rest lengths must stay > 0"):
        gym.make_vec(ROLL, num_envs=2, vectorization_mode="vector_entry_point", backend="torch", device="cpu",
                     reset_sampling="device", randomize={"rest_length_offset": s})


# ---------------------------------------------------------------- params vs the stable step
@pytest.mark.parametrize("env_id, kw, name", [
    (SHAPE, dict(params={"stiffness": 1e6}), "stiffness"),
    (ROLL, dict(params={"rod_mass": 1e-12}), "rod_mass"),
    (ROLL, dict(params={"ground_stiffness": 1e15}), "ground_stiffness"),
    (ROLL, dict(randomize={"stiffness": 0.5}, params={"stiffness": 2e5}), "stiffness"),
])
def test_params_below_the_stable_step_are_refused(env_id, kw, name):
    with pytest.raises(ValueError, match=rf"\['{name}'\] \(worst draw .*stability limit .* below dt = 0.001 s"
                                         r".*allow_unstable_dt=True"):
        gym.make(env_id, **kw)
    # the override builds it (and warns or not, as the dt override does)
    env = gym.make(env_id, allow_unstable_dt=True, **kw)
    env.close()


def test_nominal_params_and_mild_randomisation_still_build():
    env = gym.make(ROLL, params={"stiffness": 1000.0}, randomize={"rod_mass": 0.2, "stiffness": 0.2})
    env.reset(seed=1)
    env.step(env.action_space.sample())
    env.close()


# ---------------------------------------------------------------- noise in float32, numbers not text
def test_sensor_noise_checked_in_float32():
    with pytest.raises(ValueError, match=r"sensor_noise\['cable_length'\]: .*observation is float32.*1e\+39"):
        gym.make(ROLL, observation_mode="robot", sensor_noise={"cable_length": 1e39})
    with pytest.raises(ValueError, match=r"sensor_noise\['cable_length'\]: .*got '0.01'"):
        gym.make(ROLL, observation_mode="robot", sensor_noise={"cable_length": "0.01"})


def test_randomize_string_number_refused():
    with pytest.raises(ValueError, match=r"randomize\['stiffness'\]: expected a number \(spread\), got '0.1'"):
        gym.make(SHAPE, randomize={"stiffness": "0.1"})


def test_noise_sigma_unit():
    from tensegrity_gym.envs import limits as hc
    assert hc.check_noise_sigma("x", 0.5, False) == 0.5
    assert hc.check_noise_sigma("x", hc.MAX_FLOAT32_NOISE, False) == hc.MAX_FLOAT32_NOISE
    for bad in (1e39, -1.0, math.nan, True, "1", None):
        with pytest.raises(ValueError, match=r"sensor_noise\['x'\]"):
            hc.check_noise_sigma("x", bad, False)
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        hc.check_noise_sigma("contact", 1.5, True)
