"""In one process, the roll vector env stepped with the contact loop forced serial (_contact_loop) or
with the first threshold (parallel when all n_steps sub-steps together reach PARALLEL_MIN_WORK,
8 or 2 chunks), alternating 0.3 s windows; microseconds per vector step, min and median of 6.
Run at 92f9097 (the first threshold): output in threshold_bench.txt."""
import time, numpy as np
from tensegrity_gym.backends.numba import compile as _kernels
from tensegrity_gym.envs.roll import TensegrityRollVectorEnv
orig = _kernels._parallel
modes = {"serial": lambda *a, **k: False, "auto": orig}
for B in (32, 48, 64, 128, 256):
    e = TensegrityRollVectorEnv(num_envs=B, max_episode_steps=None); e.reset(seed=0)
    rng = np.random.default_rng(0)
    acts = [rng.uniform(-1, 1, e.action_space.shape).astype(np.float32) for _ in range(50)]
    res = {m: [] for m in ("serial", "auto", "auto_nch2")}
    for rep in range(6):
        for m in res:
            _kernels._parallel = modes["serial" if m == "serial" else "auto"]
            _kernels._NCHUNK = 2 if m == "auto_nch2" else 8
            for a in acts[:3]: e.step(a)
            n = 0; t0 = time.perf_counter()
            while time.perf_counter() - t0 < 0.3:
                e.step(acts[n % 50]); n += 1
            res[m].append((time.perf_counter() - t0) / n * 1e6)
    print(B, {m: round(min(v)) for m, v in res.items()}, {m: round(float(np.median(v))) for m, v in res.items()}, flush=True)
