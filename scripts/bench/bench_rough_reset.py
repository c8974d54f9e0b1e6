#!/usr/bin/env python
"""What a reset on rough ground costs per copy, part by part: drawing the heights
(``tasks.terrain.drawn_values``), the whole drawn terrain (``tasks.terrain.generate``), its contact
arrays (``physics.terrain.TerrainContact``, with the heightfield's slope bound ``hf_bound``), and
with ``--envs N`` the ``reset_idx`` of all N copies of the NumPy vector env of
``TensegrityRoll-v0`` on that generator, per copy. Each figure is the least over ``--repeats``
calls, in ms.

    TENSEGRITY_GYM_QUIET=1 python -m scripts.bench.bench_rough_reset [--amplitude 0.02] [--repeats 25]
        [--envs 16] [--json FILE]

``--envs`` compiles the terrain kernel of the vector env on a new install (minutes).
"""
from __future__ import annotations

import argparse
import json
import os
import platform

import numpy as np

from tensegrity_gym.backends.numba.terrain_kinds import hf_bound
from tensegrity_gym.physics.terrain import TerrainContact
from tensegrity_gym.tasks.terrain import TerrainGenerator, drawn_values, generate, terrain_draws

from scripts._bench import best_of


def least_ms(fn, repeats: int) -> float:
    """The least time of ``repeats`` calls of ``fn()``, ms (after one call to warm up)."""
    return best_of(fn, repeats) * 1e3


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--amplitude", type=float, default=0.02, help="bump height of the rough generator, m")
    ap.add_argument("--repeats", type=int, default=25)
    ap.add_argument("--envs", type=int, default=0, help="also time reset_idx of a vector env of this many copies")
    ap.add_argument("--json", default=None, help="write the figures here")
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error(f"--repeats: must be at least 1, got {a.repeats}")
    if a.envs < 0:
        ap.error(f"--envs: must be 0 (no env) or a number of copies, got {a.envs}")
    if a.json and os.path.exists(a.json):
        ap.error(f"--json {a.json}: exists; give a new file")
    cfg = {"generator": "rough", "amplitude": a.amplitude, "pad": 0.0}
    try:
        gen = TerrainGenerator.from_dict(cfg)
    except ValueError as e:
        ap.error(f"--amplitude: {e}")
    rng = np.random.default_rng(0)
    u = rng.random((1, terrain_draws(gen)))
    terrain = generate(gen, rng)
    hf = terrain.heightfield
    out = {"heights (drawn_values)": least_ms(lambda: drawn_values(gen, u), a.repeats),
           "terrain (generate)": least_ms(lambda: generate(gen, rng), a.repeats),
           "contact arrays (TerrainContact)": least_ms(lambda: TerrainContact(terrain), a.repeats),
           "  of which the slope bound (hf_bound)": least_ms(lambda: hf_bound(hf.heights, hf.cell), a.repeats)}
    if a.envs:
        import gymnasium as gym
        import tensegrity_gym  # noqa: F401  (registers the envs)
        env = gym.make_vec("TensegrityRoll-v0", num_envs=a.envs, vectorization_mode="vector_entry_point",
                           terrain=cfg)
        env.reset(seed=0)
        idx = np.arange(a.envs)
        out[f"reset_idx of {a.envs} copies, per copy"] = least_ms(
            lambda: env.task.reset_idx(idx, [np.random.default_rng(i) for i in idx]), max(1, a.repeats // 5)) / a.envs
        env.close()
    print(f"rough ground, {hf.heights.shape[0]} x {hf.heights.shape[1]} grid, least of {a.repeats} calls")
    print("| part | ms per copy |\n|---|---:|")
    for k, v in out.items():
        print(f"| {k} | {v:.3f} |")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                       "generator": cfg, "repeats": a.repeats, "ms_per_copy": out}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
