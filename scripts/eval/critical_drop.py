#!/usr/bin/env python
"""Critical drop height of the prism robot for a rod tube of each material: the lowest release
height (onto a level plane, at rest, default contact) whose impact loads a rod past its capacity
(Euler buckling with pinned ends, or yield: ``physics.loads.RodSection``), found by bisection on
the peak rod compression of ``tools.drops.drop(..., loads=True)`` (every physics step recorded).

    python -m scripts.eval.critical_drop [--tube 0.006 0.0005] [--out results/drops]

Writes ``critical_drop.json`` and ``critical_drop.md`` (peak compression against height, and the
critical height per material). The loads depend on the contact law (a compliant end cap of
``stiffness`` 1e4 N/m, the damping capped for the step): a stiffer cap raises them.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path


from tensegrity_gym.core.builders import load_structure
from tensegrity_gym.core.terrain import Terrain
from tensegrity_gym.io.atomic import write_atomic
from tensegrity_gym.physics.loads import MATERIALS, RodSection
from tensegrity_gym.tools.drops import drop

GRID = (0.1, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 20.0)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tube", nargs=2, type=float, default=(0.006, 0.0005), metavar=("OUTER_DIAMETER", "WALL"),
                    help="rod tube, m (default: 6 mm, 0.5 mm wall)")
    ap.add_argument("--materials", nargs="+", default=["aluminium_6061_t6", "titanium_ti6al4v"],
                    choices=sorted(MATERIALS))
    ap.add_argument("--out", default="results/drops")
    a = ap.parse_args(argv)
    robot = load_structure("prism_robot")
    length = float(robot.bar_lengths.min())
    cache: dict = {}

    def peak(h: float) -> float:
        if h not in cache:
            cache[h] = float(drop(robot, Terrain(), h, after=0.5, record_every=1, loads=True).rod_compression.max())
        return cache[h]

    curve = [(h, peak(h)) for h in GRID]
    out = {"robot": "prism_robot", "rod_length_m": length, "tube_m": list(a.tube), "heights": {}, "curve": curve}
    for mat in a.materials:
        cap = float(RodSection.of(mat, *a.tube).capacity(length))
        lo = max([h for h, p in curve if p < cap], default=None)
        hi = min([h for h, p in curve if p >= cap], default=None)
        if lo is not None and hi is not None:
            for _ in range(12):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if peak(mid) < cap else (lo, mid)
        out["heights"][mat] = {"capacity_N": cap, "critical_height_m": hi, "source": MATERIALS[mat][3]}
        print(f"{mat}: capacity {cap:.1f} N; critical drop height "
              + ("above 20 m" if hi is None else f"{hi:.2f} m"))
    d = Path(a.out)
    write_atomic(d / "critical_drop.json", lambda f: f.write(json.dumps(out, indent=1).encode()))
    lines = [f"Prism robot (rods {length:.3f} m, 0.2 kg), tube {a.tube[0] * 1e3:g} mm x {a.tube[1] * 1e3:g} mm wall, "
             "dropped at rest onto a level plane (`python -m scripts.eval.critical_drop`).", "",
             "| height (m) | peak rod compression (N) |", "|---|---|"]
    lines += [f"| {h:g} | {p:.1f} |" for h, p in curve]
    lines += ["", "| material | rod capacity (N) | critical drop height (m) |", "|---|---|---|"]
    for mat, v in out["heights"].items():
        h = v["critical_height_m"]
        lines.append(f"| {mat} | {v['capacity_N']:.1f} | {'> 20' if h is None else f'{h:.2f}'} |")
    text = "\n".join(lines) + "\n"
    write_atomic(d / "critical_drop.md", lambda f: f.write(text.encode()))
    print(text)


if __name__ == "__main__":
    main()
