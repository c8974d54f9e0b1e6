"""Short env-step timing of results/refactor/pipeline.md: process time per vector step, best of 5
windows of 0.3 s, for the roll and shape envs at N = 1, 16, 256, the randomised roll env at
N = 256 and the shape single env with a rest-length offset.

    PYTHONPATH=<checkout> python scripts/refactor/pipeline_bench.py [case numbers]

Prints one line per case: 'index env N=.. variant .. us/step'. Run with two checkouts,
alternating, and compare the lines (the machine's load moves single runs by 5-10 %)."""
import sys, time
import numpy as np
import gymnasium as gym
import tensegrity_gym  # noqa
from tensegrity_gym.envs.roll import TensegrityRollEnv, TensegrityRollVectorEnv
from tensegrity_gym.envs.shape import TensegrityShapeEnv, TensegrityShapeVectorEnv

def make(env, N, **kw):
    if env == "roll":
        return TensegrityRollEnv(**kw) if N == 1 else TensegrityRollVectorEnv(num_envs=N, max_episode_steps=None, **kw)
    return TensegrityShapeEnv(**kw) if N == 1 else TensegrityShapeVectorEnv(num_envs=N, max_episode_steps=None, **kw)

cases = [("roll", 1, {}), ("roll", 16, {}), ("roll", 256, {}), ("shape", 1, {}), ("shape", 16, {}), ("shape", 256, {}),
         ("roll", 256, {"randomize": {"rod_mass": 0.1, "friction": 0.2}}), ("shape", 1, {"params": {"rest_length_offset": 0.001}})]
sel = sys.argv[1:] 
for i, (env, N, kw) in enumerate(cases):
    if sel and str(i) not in sel:
        continue
    e = make(env, N, **kw)
    e.reset(seed=0)
    rng = np.random.default_rng(0)
    shape = e.action_space.shape
    acts = [rng.uniform(-1, 1, shape) for _ in range(50)]
    for a in acts[:10]:
        e.step(a)
    best = []
    target = 0.3
    for rep in range(5):
        n = 0
        t0 = time.process_time()
        while time.process_time() - t0 < target:
            e.step(acts[n % 50]); n += 1
        best.append((time.process_time() - t0) / n)
    print(f"{i} {env} N={N} {'+'.join(kw) or 'nominal'} {min(best) * 1e6:.1f} us/step", flush=True)
