"""us per env step (best of 7 timeit repeats) of the roll and shape envs, single (B = 1) and vector
(B = 64), random actions in [-1, 1]: the control update, divergence check and observation around
the physics. Run with a checkout first on PYTHONPATH and NUMBA_NUM_THREADS=1."""
import sys, timeit, numpy as np
import gymnasium as gym
import tensegrity_gym as tg
from tensegrity_gym.envs.roll import TensegrityRollVectorEnv
from tensegrity_gym.envs.shape import TensegrityShapeVectorEnv
print(tg.__file__, file=sys.stderr)
rng = np.random.default_rng(0)
rows = []
for name, make, B in (("roll", lambda: gym.make("TensegrityRoll-v0").unwrapped, 1),
                      ("roll", lambda: TensegrityRollVectorEnv(num_envs=64, max_episode_steps=None), 64),
                      ("shape", lambda: gym.make("TensegrityShape-v0").unwrapped, 1),
                      ("shape", lambda: TensegrityShapeVectorEnv(num_envs=64, max_episode_steps=None), 64)):
    env = make()
    env.reset(seed=0)
    A = rng.uniform(-1, 1, (200,) + env.action_space.shape)
    it = iter(range(10**9))
    f = lambda: env.step(A[next(it) % 200])
    for _ in range(50):
        f()
    nn = 300
    t = min(timeit.repeat(f, number=nn, repeat=7)) / nn
    rows.append((name, B, t * 1e6))
for r in rows:
    print("%-6s B=%-3d %9.2f us per step" % r)
