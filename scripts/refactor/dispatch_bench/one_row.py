import timeit, numpy as np
from tensegrity_gym.core import builders
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.physics.evaluate import project
from tensegrity_gym.physics.integrate import step
model = compile_model(builders.prism(3))
rng = np.random.default_rng(0)
st = initial_state(model, 1)
q, qd = project(model, st.q, st.qd + 0.01 * rng.normal(size=st.qd.shape))
st = State(q=np.ascontiguousarray(q), qd=np.ascontiguousarray(qd), t=0.0)
f = lambda: step(model, st, 1e-4, "semi_implicit_euler", n_steps=20)
f()
print("%.3f" % (min(timeit.repeat(f, number=5000, repeat=7)) / 5000 * 1e6))
