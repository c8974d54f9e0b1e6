"""B = 1 cost of one `_kernels.step_inplace` call (us), per scene, integrator and steps per call: the
fixed cost the one-driver change had to keep. Run with each checkout first on PYTHONPATH:
`PYTHONPATH=<checkout> python scripts/refactor/kernel_call_bench.py`."""
import sys, timeit, numpy as np
import tensegrity_gym as tg
from tensegrity_gym.core import builders
from tensegrity_gym.core.model import compile_model, initial_state
from tensegrity_gym.physics.evaluate import project
from tensegrity_gym.backends.numba.api import step_inplace
print(tg.__file__, file=sys.stderr)
rows = []
for name, s in {"prism3": builders.prism(3), "icosahedron": builders.icosahedron(), "tower30": builders.tower(30)}.items():
    model = compile_model(s)
    rng = np.random.default_rng(0)
    st = initial_state(model, 1)
    q, qd = project(model, st.q, st.qd + 0.01 * rng.normal(size=st.qd.shape))
    q = np.ascontiguousarray(q); qd = np.ascontiguousarray(qd)
    for integ in ("semi_implicit_euler", "rk4"):
        for ns in (1, 20):
            f = lambda: step_inplace(model, q, qd, 1e-4, integ, n_steps=ns)
            f()
            nn = 20000 if name != "tower30" else 2000
            t = min(timeit.repeat(f, number=nn, repeat=7)) / nn
            rows.append((name, integ, ns, t * 1e6))
for r in rows:
    print("%-12s %-20s n=%2d %8.3f us" % r)
