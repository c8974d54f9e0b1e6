"""Wall-clock time per vector step of TensegrityRoll-v0 (20 contact sub-steps per step), for
results/refactor/contact_loop.md: N = 1, 16, 64, 256, 1024 copies, nominal, and N = 256 with
per-copy robots (randomize). Best of 5 windows of 0.5 s (time.perf_counter: the parallel kernel's
threads count once, as a user waits for them).

    PYTHONPATH=<checkout> python scripts/refactor/contact_loop_bench.py [case numbers]

Prints one line per case: 'index N=.. variant .. us/step  .. env-steps/s'. Run with two
checkouts, alternating, and compare the lines."""
import sys
import time

import numpy as np

from tensegrity_gym.envs.roll import TensegrityRollEnv, TensegrityRollVectorEnv

CASES = [(1, {}), (16, {}), (64, {}), (256, {}), (1024, {}),
         (256, {"randomize": {"rod_mass": 0.1, "friction": 0.2, "stiffness": 0.1}})]


def main(sel):
    for i, (N, kw) in enumerate(CASES):
        if sel and str(i) not in sel:
            continue
        e = TensegrityRollEnv(**kw) if N == 1 else TensegrityRollVectorEnv(num_envs=N, max_episode_steps=None, **kw)
        e.reset(seed=0)
        rng = np.random.default_rng(0)
        acts = [rng.uniform(-1, 1, e.action_space.shape).astype(np.float32) for _ in range(50)]
        for a in acts[:10]:
            e.step(a)
        best = []
        for _ in range(5):
            n = 0
            t0 = time.perf_counter()
            while time.perf_counter() - t0 < 0.5:
                e.step(acts[n % 50])
                n += 1
            best.append((time.perf_counter() - t0) / n)
        t = min(best)
        print(f"{i} N={N} {'+'.join(kw) or 'nominal'} {t * 1e6:.1f} us/step {N / t:.0f} env-steps/s", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
