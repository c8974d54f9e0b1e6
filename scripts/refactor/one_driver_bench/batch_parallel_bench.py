"""ns per env-step of one step_inplace call on B = 1024 and 4096 copies (the parallel kernel at the
machine's thread count): best of 7 timeit repeats. Run with a checkout first on PYTHONPATH."""
import sys, timeit, numpy as np
from tensegrity_gym.core import builders
from tensegrity_gym.core.model import compile_model, initial_state
from tensegrity_gym.physics.evaluate import project
from tensegrity_gym.backends.numba.api import step_inplace
for name, s in {"prism3": builders.prism(3), "icosahedron": builders.icosahedron()}.items():
    model = compile_model(s)
    for B in (1024, 4096):
        st = initial_state(model, B)
        rng = np.random.default_rng(0)
        q, qd = project(model, st.q, st.qd + 0.01 * rng.normal(size=st.qd.shape))
        q = np.ascontiguousarray(q); qd = np.ascontiguousarray(qd)
        for integ in ("semi_implicit_euler", "rk4"):
            f = lambda: step_inplace(model, q, qd, 1e-4, integ)
            f()
            nn = int(4e5 / B)
            t = min(timeit.repeat(f, number=nn, repeat=7)) / nn / B
            print(name, integ, B, "%.1f" % (t * 1e9))
