#!/usr/bin/env python
"""Free flight of MuJoCo models (MJCF) in MuJoCo against their import here, one line per file:
what the import mapped (largest site offset from a rod axis, largest shift along an axis, what it
dropped) and how far the nodes end up apart (:func:`tensegrity_gym.tools.mjcf_check.free_flight`:
RK4 at ``--dt`` on both sides, no gravity, no contact).

    python -m scripts.eval.mjcf_free_flight robot.xml [more.xml ...] [--duration 0.2] [--dt 1e-4]

A file that is refused (not class-1) or that this MuJoCo cannot load is listed with the reason.
Needs the ``mujoco`` package.
"""
from __future__ import annotations

import argparse

from tensegrity_gym.tools.mjcf_check import free_flight


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("models", nargs="+", help="MJCF files")
    ap.add_argument("--duration", type=float, default=0.2, help="simulated time, s")
    ap.add_argument("--dt", type=float, default=1e-4, help="RK4 step on both sides, s")
    a = ap.parse_args(argv)
    print("| model | rods / strings / actuated | largest axis offset (m) | largest axial shift (m) | dropped | "
          f"largest node motion in {a.duration:g} s (m) | largest ours - MuJoCo (m) |")
    print("|---|---|---|---|---|---|---|")
    for path in a.models:
        try:
            f = free_flight(path, a.duration, a.dt)
        except ValueError as e:
            print(f"| {path} | refused or not loadable: {' '.join(str(e).split())} | | | | | |")
            continue
        s, r = f["structure"], f["report"]
        print(f"| {path} | {s.n_bars} / {s.n_strings} / {len(r.actuated)} | {r.max_axis_offset:.3g} | "
              f"{r.max_axial_shift:.3g} | {len(r.dropped)} | {f['moved']:.3g} | {f['error']:.3g} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
