"""What the numba ``accelerations`` entry (``integrators.accelerations``) buys the methods that
evaluate accelerations outside the fixed-step kernels: implicit Euler (finite-difference
Jacobians and Newton), the adaptive DOP853, and the dense finite-difference Jacobian. Each row
runs the same call with ``backend="numpy"`` (the NumPy reference, what these methods used
before) and ``backend="auto"`` (numba) in the same process, alternating, best of 5 repeats
(process time), and prints the ratio.

    python scripts/refactor/accelerations_bench.py

The results agree to round-off (the last column: max relative difference of the outputs)."""
import time

import numpy as np

import tensegrity_gym as tg
from tensegrity_gym.core.model import State, initial_state
from tensegrity_gym.physics.evaluate import accelerations, project
from tensegrity_gym.physics.jacobian import acceleration_jacobians


def _state(model, B, seed=0):
    rng = np.random.default_rng(seed)
    st = initial_state(model, B)
    q, qd = project(model, st.q, st.qd + 0.05 * rng.standard_normal(st.qd.shape))
    return State(q=q, qd=qd)


def _time(fn, repeats=5):
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.process_time()
        n = 0
        while True:
            out = fn()
            n += 1
            el = time.process_time() - t0
            if el > 0.2:
                break
        best = min(best, el / n)
    return best, out


def _rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(a).max(), 1e-300))


def main():
    rows = []
    for name in ("prism3", "icosahedron", "tower3"):
        model = tg.compile_model(tg.load_structure(name))
        for B in (1, 16):
            st = _state(model, B)
            cases = {
                "accelerations": lambda be: accelerations(model, st.q, st.qd, backend=be),
                "jacobian (dense FD)": lambda be: acceleration_jacobians(model, st.q, st.qd, backend=be)[1],
                "implicit_euler x 10 steps": lambda be: tg.step(model, st, 1e-3, "implicit_euler", n_steps=10,
                                                                backend=be).q,
            }
            if B == 1:
                cases["dop853 over 10 ms"] = lambda be: tg.step(model, st, 1e-2, "dop853", backend=be).q
            for case, fn in cases.items():
                fn("auto")   # compile / warm
                t_np, o_np = _time(lambda: fn("numpy"))
                t_nb, o_nb = _time(lambda: fn("auto"))
                rows.append((name, B, case, t_np * 1e6, t_nb * 1e6, t_np / t_nb, _rel(o_np, o_nb)))
    print("| structure | B | call | NumPy, us | numba, us | speed-up | max rel. difference |")
    print("|---|---:|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.1f} | {r[4]:.1f} | {r[5]:.1f}x | {r[6]:.1e} |")


if __name__ == "__main__":
    main()
