import timeit, numpy as np
from tensegrity_gym import builders, dynamics, integrators
model = dynamics.compile_model(builders.prism(3))
rng = np.random.default_rng(0)
st = dynamics.initial_state(model, 1)
q, qd = dynamics.project(model, st.q, st.qd + 0.01 * rng.normal(size=st.qd.shape))
st = dynamics.State(q=np.ascontiguousarray(q), qd=np.ascontiguousarray(qd), t=0.0)
f = lambda: integrators.step(model, st, 1e-4, "semi_implicit_euler", n_steps=20)
f()
print("%.3f" % (min(timeit.repeat(f, number=5000, repeat=7)) / 5000 * 1e6))
