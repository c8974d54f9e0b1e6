"""us per step of _kernels.step_inplace (the same entry in both versions) on a few scenes, best of 7."""
import sys, timeit
import numpy as np
from tensegrity_gym.core import builders
from tensegrity_gym.core.model import compile_model, initial_state
from tensegrity_gym.backends.numba.api import step_inplace
rows = []
for name in ("prism3", "icosahedron", "tower30"):
    model = compile_model(builders.build(name))
    for integ in ("semi_implicit_euler", "rk4"):
        for B in (1, 64):
            st = initial_state(model, batch_size=B)
            q, qd = st.q.copy(), st.qd.copy()
            rng = np.random.default_rng(0)
            qd[..., :3] += 1e-3 * rng.standard_normal(qd[..., :3].shape)
            f = lambda: step_inplace(model, q, qd, 1e-3, integ, n_steps=10)
            for _ in range(200): f()
            n = max(20, int(2000 / B))
            t = min(timeit.repeat(f, number=n, repeat=7)) / n / 10 / B * 1e6 * B   # us per (batched) step
            rows.append((name, integ, B, t))
for r in rows:
    print("%-12s %-20s B=%-3d %8.3f us/step" % r)
