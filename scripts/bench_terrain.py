#!/usr/bin/env python
"""Cost of a physics step with terrain contact against flat ground (numba, the prism robot).

    PYTHONPATH=. TENSEGRITY_GYM_QUIET=1 python scripts/bench_terrain.py [--batch 1 64] [--steps 2000]

Prints microseconds per physics step (all copies) for: the flat-ground GroundContact (the fused
compiled loop), a level terrain plane, a 20-degree plane, and a 20-degree plane with two boxes
(terrain steps: the compiled forces kernel and one compiled integrator step per physics step).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from tensegrity_gym import builders, contact as C, dynamics as dyn
from tensegrity_gym.core.terrain import Box, Plane, Terrain
from tensegrity_gym.physics import terrain as T

DT = 1e-3


def prism():
    s = builders.prism(3, radius=0.15, height=0.25, bar_mass=0.2, stiffness=1000.0, prestress=20.0, damping=2.0,
                       gravity=(0.0, 0.0, -9.81))
    nodes = s.nodes.copy()
    nodes[:, 2] += 0.02
    return dyn.compile_model(s.replace(nodes=nodes))


def timed(fn, steps):
    fn(10)                                     # compile / warm up
    t0 = time.perf_counter()
    fn(steps)
    return (time.perf_counter() - t0) / steps * 1e6


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 64])
    ap.add_argument("--steps", type=int, default=2000)
    a = ap.parse_args()
    m = prism()
    scenes = {"level plane": Terrain(), "20 deg plane": Terrain(plane=Plane(20.0)),
              "20 deg plane + 2 boxes": Terrain(plane=Plane(20.0), boxes=[Box([0.3, 0, 0.05], [0.2, 1, 0.1]),
                                                                          Box([-0.3, 0.2, 0.1], [0.2, 0.2, 0.2], 30.0)])}
    print(f"{'scene':<26}" + "".join(f"{'B=' + str(B) + ' us/step':>16}" for B in a.batch))
    rows = {"flat GroundContact": [], **{k: [] for k in scenes}}
    for B in a.batch:
        st = dyn.initial_state(m, B)
        g = C.GroundContact()
        cs = C.init_contact_state(m, B)
        rows["flat GroundContact"].append(timed(lambda n: C.step(m, g, st, cs, DT, n_steps=n), a.steps))
        for name, ter in scenes.items():
            tc = T.TerrainContact(ter)
            ts = T.init_terrain_state(tc, m, B)
            rows[name].append(timed(lambda n: T.step(m, st, DT, tc, ts, n_steps=n), a.steps))
    for name, vals in rows.items():
        print(f"{name:<26}" + "".join(f"{v:16.2f}" for v in vals))


if __name__ == "__main__":
    main()
