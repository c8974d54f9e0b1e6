"""One loop that steps a ``TensegrityRollVectorEnv`` beside N single ``gymnasium.make`` envs
with the same actions and asserts that they agree (observations bit for bit, rewards by the
caller's check, terminated/truncated flags), autoreset included. Used by test_roll_env.py and
test_motor.py."""
import gymnasium as gym
import numpy as np

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.envs.roll import TensegrityRollVectorEnv

ENV_ID = "TensegrityRoll-v0"


def step_vector_beside_singles(T: int, N: int, seed: int, actions, check_reward, **env_kwargs) -> int:
    """``2 T + 3`` steps of episodes of ``T`` steps; ``actions(step) -> (N, na)`` float32;
    ``check_reward(vector_reward, single_reward)`` asserts their agreement. Returns the number of
    vector-env truncations seen."""
    venv = TensegrityRollVectorEnv(num_envs=N, max_episode_steps=T, **env_kwargs)
    singles = [gym.make(ENV_ID, max_episode_steps=T, **env_kwargs) for _ in range(N)]
    vobs, _ = venv.reset(seed=seed)
    sobs = [e.reset(seed=seed + i)[0] for i, e in enumerate(singles)]
    np.testing.assert_array_equal(vobs, np.array(sobs))
    done = [False] * N
    n_trunc = 0
    for step in range(2 * T + 3):
        a = actions(step)
        vobs, vr, vterm, vtrunc, _ = venv.step(a)
        for i, e in enumerate(singles):
            if done[i]:
                o, _ = e.reset()
                r, te, tr = 0.0, False, False
            else:
                o, r, te, tr, _ = e.step(a[i])
            done[i] = te or tr
            np.testing.assert_array_equal(vobs[i], o)
            check_reward(vr[i], r)
            assert (vterm[i], vtrunc[i]) == (te, tr)
        n_trunc += int(vtrunc.sum())
    return n_trunc
