"""B = 1 cost of one `integrators.step` call (us; best of 7 timeit repeats), the public entry whose
dispatch changed when the NumPy path became the test oracle (commit 3acede3): per scene,
integrator and steps per call, plus `integrators.accelerations` of one state. Run with a checkout
first on PYTHONPATH and NUMBA_NUM_THREADS=1."""
import sys, timeit, numpy as np
import tensegrity_gym as tg
from tensegrity_gym.core import builders
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.physics.evaluate import accelerations, project
from tensegrity_gym.physics.integrate import step
print(tg.__file__, file=sys.stderr)
rows = []
for name, s in {"prism3": builders.prism(3), "icosahedron": builders.icosahedron(),
                "constrained_prism": builders.constrained_prism(damping=0.5)}.items():
    model = compile_model(s)
    rng = np.random.default_rng(0)
    st = initial_state(model, 1)
    q, qd = project(model, st.q, st.qd + 0.01 * rng.normal(size=st.qd.shape))
    st = State(q=np.ascontiguousarray(q), qd=np.ascontiguousarray(qd), t=0.0)
    for integ in ("semi_implicit_euler", "rk4"):
        for ns in (1, 20):
            f = lambda: step(model, st, 1e-4, integ, n_steps=ns)
            f()
            t = min(timeit.repeat(f, number=5000, repeat=7)) / 5000
            rows.append(("%s %s n=%d" % (name, integ, ns), t * 1e6))
    f = lambda: accelerations(model, st.q, st.qd)
    f()
    t = min(timeit.repeat(f, number=5000, repeat=7)) / 5000
    rows.append(("%s accelerations" % name, t * 1e6))
for r in rows:
    print("%-45s %9.3f us" % r)
