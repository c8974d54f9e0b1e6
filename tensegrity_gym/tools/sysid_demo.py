"""Files for the system-identification recipe of docs/sysid.md (SI units), from any folder::

    python -m tensegrity_gym.tools.sysid_demo files DIR     # DIR/robot.json, DIR/robot_true.json, DIR/commands.csv
    python -m tensegrity_gym.tools.sysid_demo noise IN.npz OUT.npz [--sigma 0.001] [--seed 0]

``files`` writes your model of the robot (``robot.json``: the nominal 3-bar prism, no string
damping), a stand-in for the real robot (``robot_true.json``: strings 20 % stiffer, 0.5 N s/m of
damping each) and a cable-command log (``commands.csv``: ``t,l_0,...,l_8``, every string's rest
length, 50 Hz for 2 s, each string contracting by up to 4 % in a sine wave of its own phase).
``noise`` adds Gaussian noise of ``--sigma`` m to every recorded node coordinate of a
``simulate`` output, as a motion-capture system would see it, and keeps its times and commands.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from tensegrity_gym.core.builders import prism
from tensegrity_gym.core.checks import load_npz
from tensegrity_gym.core.structure import save_json


def write_files(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    s = prism(3).replace(damping=0.0)
    save_json(s, out / "robot.json")
    save_json(s.replace(stiffness=1.2 * s.stiffness, damping=np.full(s.n_strings, 0.5)), out / "robot_true.json")
    t = np.arange(0.0, 2.0, 0.02)
    phase = 2 * np.pi * np.arange(s.n_strings) / s.n_strings
    L = s.rest_length * (1.0 - 0.02 * (1.0 - np.cos(2 * np.pi * 1.5 * t[:, None] + phase)))
    rows = np.column_stack([t, L])
    header = "t," + ",".join(f"l_{i}" for i in range(s.n_strings))
    np.savetxt(out / "commands.csv", rows, delimiter=",", header=header, comments="", fmt="%.9g")
    print(f"wrote {out / 'robot.json'}, {out / 'robot_true.json'}, {out / 'commands.csv'}")


def add_noise(src: Path, dst: Path, sigma: float, seed: int) -> None:
    d = load_npz(src, "a simulate output with t and nodes")
    rng = np.random.default_rng(seed)
    d["nodes"] = d["nodes"] + rng.normal(0.0, sigma, d["nodes"].shape)
    np.savez(dst, **d)
    print(f"wrote {dst}: {d['nodes'].shape[0]} samples of {d['nodes'].shape[1]} nodes with {sigma * 1e3:g} mm noise")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tensegrity_gym.tools.sysid_demo", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("files")
    f.add_argument("out", type=Path)
    n = sub.add_parser("noise")
    n.add_argument("src", type=Path)
    n.add_argument("dst", type=Path)
    n.add_argument("--sigma", type=float, default=0.001, help="noise standard deviation, m")
    n.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.cmd == "files":
        write_files(args.out)
    else:
        add_noise(args.src, args.dst, args.sigma, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
