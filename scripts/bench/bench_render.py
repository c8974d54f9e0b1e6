"""Frames/s of the renderers on the prism (and other scenes), measured in one run.

    python -m scripts.bench.bench_render [--frames 100] [--size 480] [--scenes prism3,icosahedron]

Prints a table: renderer, scene, frames/s from the median wall-clock frame time, frames/s of
the best frame, and frames per CPU-second (frames / process CPU time, all threads included: what
one otherwise idle core delivers, independent of other processes competing for the CPU), plus
the OpenGL backend MuJoCo used. On a shared machine the wall-clock figures fall with the load;
the CPU-time figure and the ratio to matplotlib measured in the same run do not. The structure moves between frames (a real simulated trajectory), so no
frame is a cached copy of the previous one.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import tensegrity_gym as tg
from tensegrity_gym.core.model import initial_state
from tensegrity_gym.physics.geometry import node_positions
from tensegrity_gym.physics.evaluate import force_densities
from tensegrity_gym.tools.rendering import MujocoRenderer, Renderer, RendererUnavailable


def trajectory(name: str, frames: int):
    s = tg.load_structure(name)
    m = tg.compile_model(s)
    rng = np.random.default_rng(0)
    st = initial_state(m, nodes=s.nodes + 0.01 * rng.standard_normal(s.nodes.shape))
    _, q, qd = tg.simulate(m, st, 1e-3, 10 * frames, "rk4", record_every=10)
    q, qd = q[1:, 0], qd[1:, 0]
    nodes = node_positions(m, q)
    gamma, _, L = force_densities(m, q, qd)
    return s, nodes, gamma * L


def bench(renderer, s, nodes, tensions, ground_z):
    renderer.render(nodes[0], s.bars, s.strings, tensions[0], ground_z=ground_z, caption="warm-up")
    ts = np.empty(len(nodes))
    c0 = time.process_time()
    for i in range(len(nodes)):
        t0 = time.perf_counter()
        renderer.render(nodes[i], s.bars, s.strings, tensions[i], ground_z=ground_z, caption=f"frame {i}")
        ts[i] = time.perf_counter() - t0
    cpu = time.process_time() - c0
    return 1.0 / np.median(ts), 1.0 / ts.min(), len(nodes) / cpu


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--size", type=int, default=480)
    ap.add_argument("--scenes", default="prism3")
    ap.add_argument("--shadows", action="store_true", help="MuJoCo renderer with shadows")
    a = ap.parse_args(argv)
    rows = []
    backend = "-"
    for name in a.scenes.split(","):
        s, nodes, T = trajectory(name, a.frames)
        gz = float(nodes[..., 2].min()) - 0.05
        try:
            r = MujocoRenderer(a.size, a.size, title=name, shadows=a.shadows)
            backend = r.backend
            rows.append(("mujoco", name) + bench(r, s, nodes, T, gz))
            r.close()
        except RendererUnavailable as exc:
            print(f"mujoco renderer unavailable: {exc}")
        r = Renderer(a.size, a.size, title=name)
        rows.append(("matplotlib", name) + bench(r, s, nodes[: max(10, a.frames // 5)], T, gz))
    print(f"OpenGL backend: {backend}; {a.size} x {a.size} px, ground plane on, {a.frames} frames")
    print(f"{'renderer':<12}{'scene':<14}{'frames/s (median)':>19}{'frames/s (best frame)':>23}"
          f"{'frames per CPU-s':>18}")
    for name, scene, med, best, cpu in rows:
        print(f"{name:<12}{scene:<14}{med:>19.1f}{best:>23.1f}{cpu:>18.1f}")
    try:
        import os
        print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    except OSError:  # pragma: no cover
        pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
