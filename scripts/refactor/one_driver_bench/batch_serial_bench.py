"""ns per env-step of one step_inplace call, B = 64, 1024, 4096 (run with NUMBA_NUM_THREADS=1 to take
thread scheduling out): best of 5 timeit repeats. Run with a checkout first on PYTHONPATH."""
import sys, timeit, numpy as np
from tensegrity_gym.core import builders
from tensegrity_gym.core.model import compile_model, initial_state
from tensegrity_gym.physics.evaluate import project
from tensegrity_gym.backends.numba.api import step_inplace
out = []
for name, s in {"prism3": builders.prism(3), "icosahedron": builders.icosahedron(), "tower30": builders.tower(30)}.items():
    model = compile_model(s)
    for B in (64, 1024, 4096):
        if name == "tower30" and B == 4096: continue
        rng = np.random.default_rng(0)
        st = initial_state(model, B)
        q, qd = project(model, st.q, st.qd + 0.01 * rng.normal(size=st.qd.shape))
        q = np.ascontiguousarray(q); qd = np.ascontiguousarray(qd)
        for integ in ("semi_implicit_euler", "rk4"):
            f = lambda: step_inplace(model, q, qd, 1e-4, integ)
            f()
            nn = max(1, int(2e5 / B / (1 if name != "tower30" else 10)))
            t = min(timeit.repeat(f, number=nn, repeat=5)) / nn / B
            out.append("%s %s %d %.1f" % (name, integ, B, t * 1e9))
print("\n".join(out))
