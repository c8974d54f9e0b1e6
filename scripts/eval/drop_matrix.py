#!/usr/bin/env python
"""The drop matrix: the prism robot dropped at rest from 0.1-20 m onto each terrain of
``tests/test_drops.py`` with each fixed-step integrator, with the contact the envs and the
command line run (damping capped, ``physics.contact.impact_damping_cap``) and without the cap
(the command line's contact before the cap).

    python -m scripts.eval.drop_matrix [--out results/drops] [--dt 0.001]

Writes ``drop_matrix.csv`` (one row per case: largest energy over the start's, energy left 0.5 s
after the impact, lowest node height m), ``drop_matrix.md`` (the largest ratio per terrain and
integrator, capped and uncapped) and ``drop_energy.png`` (energy against time, 5 m drops onto the
plane). Numba kernels, one process.
"""
from __future__ import annotations

import argparse
import csv
import io
import math
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from tensegrity_gym.core.builders import load_structure
from tensegrity_gym.io.atomic import write_atomic
from tensegrity_gym.tools.drops import drop, drop_terrains

HEIGHTS = (0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0)
INTEGRATORS = ("semi_implicit_euler", "rk4", "implicit_euler")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="results/drops")
    ap.add_argument("--dt", type=float, default=1e-3)
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    robot = load_structure("prism_robot")
    rows, curves = [], {}
    for tname, ter in drop_terrains().items():
        for integ in INTEGRATORS:
            for capped in (True, False):
                for h in HEIGHTS:
                    r = drop(robot, ter, h, integ, dt=a.dt, after=0.5, max_damping=None if capped else math.inf)
                    ok = np.isfinite(r.energy)
                    ratio = float(np.max(r.energy[ok]) / r.energy[0])
                    rows.append(dict(terrain=tname, integrator=integ, damping_cap="yes" if capped else "no",
                                     height_m=h, impact_speed_m_s=round(r.impact_speed, 3),
                                     energy_max_over_start=f"{ratio:.6g}",
                                     energy_end_over_start=f"{float(r.energy[ok][-1] / r.energy[0]):.4g}",
                                     lowest_node_m=f"{float(np.min(r.lowest[ok])):.4g}"))
                    if tname == "plane" and h == 5.0 and integ != "implicit_euler":
                        curves[(integ, capped)] = (r.t, r.energy / r.energy[0])
                print(f"{tname:12s} {integ:20s} cap={'yes' if capped else 'no '} largest ratio "
                      f"{max(float(x['energy_max_over_start']) for x in rows[-len(HEIGHTS):]):.4g}", flush=True)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    write_atomic(out / "drop_matrix.csv", lambda f: f.write(buf.getvalue().encode()))
    lines = ["| terrain | integrator | largest energy / start, capped | uncapped | lowest node, capped (m) |",
             "|---|---|---|---|---|"]
    for tname in drop_terrains():
        for integ in INTEGRATORS:
            sel = [r for r in rows if r["terrain"] == tname and r["integrator"] == integ]
            cap = max(float(r["energy_max_over_start"]) for r in sel if r["damping_cap"] == "yes")
            unc = max(float(r["energy_max_over_start"]) for r in sel if r["damping_cap"] == "no")
            low = min(float(r["lowest_node_m"]) for r in sel if r["damping_cap"] == "yes")
            lines.append(f"| {tname} | {integ} | {cap:.6g} | {unc:.4g} | {low:.3g} |")
    table = "\n".join(lines) + "\n"
    text = (f"Drops of the prism robot from {HEIGHTS[0]}-{HEIGHTS[-1]} m, dt = {a.dt:g} s "
            f"(`python -m scripts.eval.drop_matrix`).\n\n" + table)
    write_atomic(out / "drop_matrix.md", lambda f: f.write(text.encode()))
    print(table)
    plt.switch_backend("Agg")
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for (integ, capped), (t, e) in curves.items():
        ax.plot(t, e, label=f"{integ}, {'capped' if capped else 'no cap'}", ls="-" if capped else "--")
    ax.set(xlabel="t [s]", ylabel="energy / start", yscale="log", title="prism robot dropped 5 m onto a plane")
    ax.legend(fontsize=8)
    fig.tight_layout()
    write_atomic(out / "drop_energy.png", lambda f: fig.savefig(f, format="png", dpi=110))


if __name__ == "__main__":
    main()
