"""Residual Jacobian of the sys-ID fit (tensegrity_gym.tools.sysid): batched forward differences
(``jacobian="fd"``, numba) against autograd through the torch backend (``jacobian="torch"``),
time per Jacobian and their agreement, on the recovery case of ``scripts/figures/sysid_results.py``
(constrained prism, 9 stiffnesses + 9 dampings + 3 rod masses with the total mass given,
RK4 at 2 ms, 0.15 s windows). SI units.

    PYTHONPATH=. python -m scripts.bench.bench_sysid_jacobian [--threads 1] [--repeat 3]

Prints the case size, the median seconds per Jacobian of each method, and the relative
difference of the two (max-abs / max and Frobenius) for the projected parameter block and the
window-state block. The difference is the forward differences' truncation error (~1e-6),
not the autograd's (``tests/test_torch_env.py`` checks autograd against central differences).
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    ap.add_argument("--repeat", type=int, default=3, help="Jacobians timed per method (median)")
    a = ap.parse_args(argv)
    import torch
    import tensegrity_gym as tg
    from tensegrity_gym.tools import sysid
    from tensegrity_gym.core.model import State
    from tensegrity_gym.physics.geometry import node_positions
    from tensegrity_gym.physics.evaluate import project
    from tensegrity_gym.core.params import default_params
    torch.set_num_threads(a.threads)
    s = tg.constrained_prism(damping=2.0)
    model = tg.compile_model(s)
    rng = np.random.default_rng(1)
    true = {f: getattr(model, f) * rng.uniform(0.8, 1.2, getattr(model, f).shape)
            for f in ("stiffness", "damping", "mass")}
    st = tg.initial_state(model, nodes=s.nodes + 0.03 * np.random.default_rng(0).standard_normal(s.nodes.shape))
    st = State(*project(model, st.q, st.qd))
    t, q, _ = tg.simulate(model, st, 5e-4, 1240, "rk4", params=default_params(model).replace(**true))
    nodes = node_positions(model, q[:, 0])
    names, items, init, base = sysid._parse_fit(model, ("stiffness", "damping", "mass"), "per_member", None)
    t_, rec, mask, rl, h = sysid._check_record(model, t, nodes, None, None)
    pb = sysid._Problem(model, t_, rec, mask, rl, h, names, items, init, base, "per_member", 0.15, "rk4", None, 4,
                        float(true["mass"].sum()))
    q0, qd0 = pb.guess()
    theta = np.random.default_rng(3).uniform(-0.1, 0.1, pb.p)
    sim = pb.simulate(q0, qd0, pb.physics(theta), np.arange(pb.W))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, torch "
          f"{torch.__version__} ({a.threads} threads); load average {os.getloadavg()[0]:.1f}")
    print(f"case: W = {pb.W} windows x K = {pb.K} samples, p = {pb.p} parameters, ns = {pb.ns} state coordinates, "
          f"{pb.n_sub} RK4 step(s) of {pb.dt:g} s per sample")
    out = {}
    for method in ("fd", "torch"):
        pb.jacobian = method
        times = []
        for _ in range(a.repeat):
            t0 = time.perf_counter()
            out[method] = pb.full_jacobian(theta, q0, qd0, sim)
            times.append(time.perf_counter() - t0)
        print(f"jacobian={method!r}: {np.median(times):.3f} s per Jacobian (median of {a.repeat})")
    for i, name in enumerate(("parameters (projected)", "window states")):
        f, g = out["fd"][i], out["torch"][i]
        print(f"{name}: max |fd - torch| / max |torch| = {np.abs(f - g).max() / np.abs(g).max():.2e}, "
              f"Frobenius {np.linalg.norm(f - g) / np.linalg.norm(g):.2e}")


if __name__ == "__main__":
    main()
