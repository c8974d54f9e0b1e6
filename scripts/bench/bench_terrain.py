#!/usr/bin/env python
"""Cost of a physics step with terrain contact against flat ground (numba, the prism robot).

    PYTHONPATH=. TENSEGRITY_GYM_QUIET=1 python -m scripts.bench.bench_terrain [--batch 1 64] [--steps 2000] \
        [--envs 1 16 128] [--env-steps 200] [--episode] [--repeats 1] [--scenes "steps under the robot" ...] \
        [--torch] [--torch-envs 4 16] [--torch-env-steps 10] \
        [--torch-compile] [--torch-cuda-graph] [--torch-no-eager] [--torch-device cuda] [--torch-dtype float32] \
        [--torch-scenes flat ...] [--json out.json]

Physics table: microseconds per physics step (all copies) for the flat-ground GroundContact (the
fused compiled loop), a level terrain plane, a 20-degree plane, and a 20-degree plane with two
boxes (terrain steps: the forces kernel and one integrator step per physics step, all in one
compiled call below the multi-threaded batch size).

Torch table (``--torch``): the same scenes on the torch backend (CPU, float64; the physics step
alone, as for numba).

Env table (``--envs``): env-steps/s of ``TensegrityRoll-v0`` (NumPy vector env, random actions)
on flat ground and on each terrain kind, and the cost ratio terrain / flat measured in the same
run on the same machine, over ``--env-steps`` steps after a reset (the physics only) or, with
``--episode``, over one whole episode of each scene's registered time limit, so that every copy
resets once within the timed steps (what training pays: a drawn terrain is made at each reset);
``--repeats R`` times every scene in each of R rounds and gives the median rate per scene (one
episode at 16 copies takes about 0.1 s: single runs scatter by about 10 %); ``--scenes`` times
only the scenes named (flat ground always, for the ratio).
Scenes: a 20-degree slope (a plane), steps (the ``steps`` generator: 4 boxes; the robot starts
on its level pad), steps whose first edge is under the robot (``pad`` 0.05 m, ``tread`` 0.2 m:
the boxes next to the rods from the start), rough ground (the ``rough`` generator with no level
pad: a 12 m heightfield of 2 cm bumps over the whole floor, the robot on bumps from the start)
and ``TensegrityNavigate-v0`` (5 walls, 2 rough patches, the planner).

Torch env table (``--torch-envs``): the same scenes on the torch device
vector env (``backend="torch"``; CPU, float64, one torch thread unless ``--torch-device`` /
``--torch-dtype`` say otherwise); env-steps/s, milliseconds per control step, the cost against flat ground
(flat's rate over the scene's, in the same table) and the warm-up of two steps (s). With
``--torch-compile`` the same with ``compile=True`` (``torch.compile`` of the terrain's physics
step; the warm-up is its compile, shorter in a second run from inductor's cache on disk), with
``--torch-cuda-graph`` with ``compile=True, cuda_graph=True`` (the physics of a control step
replayed as one CUDA graph); ``--torch-no-eager`` leaves the eager table out.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from tensegrity_gym.core import builders
from tensegrity_gym.core.model import compile_model, initial_state
from tensegrity_gym.physics import contact as physics_contact, pipeline
from tensegrity_gym.core.terrain import Box, Plane, Terrain
from tensegrity_gym.physics import terrain as T
from tensegrity_gym_agents.common import cpu_model

from scripts._bench import sync

DT = 1e-3


def prism():
    s = builders.prism(3, radius=0.15, height=0.25, bar_mass=0.2, stiffness=1000.0, prestress=20.0, damping=2.0,
                       gravity=(0.0, 0.0, -9.81))
    nodes = s.nodes.copy()
    nodes[:, 2] += 0.02
    return compile_model(s.replace(nodes=nodes))


def timed(fn, steps):
    fn(10)                                     # compile / warm up
    t0 = time.perf_counter()
    fn(steps)
    return (time.perf_counter() - t0) / steps * 1e6


ENV_SCENES = {"flat": ("TensegrityRoll-v0", {}),
              "slope 20 deg": ("TensegrityRoll-v0", {"terrain": {"plane": {"slope_deg": 20.0}}}),
              "steps (4 boxes)": ("TensegrityRoll-v0", {"terrain": {"generator": "steps"}}),
              "steps under the robot": ("TensegrityRoll-v0",
                                        {"terrain": {"generator": "steps", "pad": 0.05, "tread": 0.2}}),
              "rough 2 cm (heightfield)": ("TensegrityRoll-v0", {"terrain": {"generator": "rough", "amplitude": 0.02,
                                                                                 "pad": 0.0}}),
              "navigate (5 walls, 2 patches)": ("TensegrityNavigate-v0", {})}


def env_rate(env_id: str, kwargs: dict, n: int, steps: int) -> float:
    """env-steps/s of the NumPy vector env of ``n`` copies over ``steps`` steps of random actions."""
    import gymnasium as gym
    env = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (steps + 5, n) + env.single_action_space.shape).astype(np.float32)
    for a in acts[:5]:
        env.step(a)
    t0 = time.perf_counter()
    for a in acts[5:]:
        env.step(a)
    rate = n * steps / (time.perf_counter() - t0)
    env.close()
    return rate


def torch_env_rate(env_id: str, kwargs: dict, n: int, steps: int, compile: bool = False, device: str = "cpu",
                   dtype: str = "float64", cuda_graph: bool = False) -> tuple:
    """``(env-steps/s, warm-up s)`` of the torch device env of ``n`` copies on ``device`` in
    ``dtype`` over ``steps`` steps after two warm-up steps (with ``compile``: the compile; with
    ``cuda_graph``: the captures)."""
    import gymnasium as gym
    import torch
    env = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", backend="torch",
                       device=device, dtype=dtype, compile=compile, cuda_graph=cuda_graph, **kwargs)
    env.reset(seed=0)
    acts = torch.as_tensor(np.random.default_rng(0).uniform(-1, 1, (steps + 2, n) + env.single_action_space.shape),
                           dtype=getattr(torch, dtype), device=device)
    t0 = time.perf_counter()
    for a in acts[:2]:
        env.step(a)
    sync(device)
    t1 = time.perf_counter()
    for a in acts[2:]:
        env.step(a)
    sync(device)
    rate = n * steps / (time.perf_counter() - t1)
    env.close()
    return rate, t1 - t0


def torch_env_table(ns, steps: int, compile: bool = False, device: str = "cpu", dtype: str = "float64",
                    scenes=None, eager: bool = True, cuda_graph: bool = False) -> dict:
    """env-steps/s per scene and N on ``device`` in ``dtype``: eager (unless not ``eager``), with
    ``compile`` also ``compile=True`` and its warm-up, with ``cuda_graph`` also ``compile=True,
    cuda_graph=True``; each table with the scene's cost against flat ground's (``cost/flat``:
    flat's rate over the scene's, when flat is measured); ``scenes`` a subset of
    ``ENV_SCENES``'s names (default all). Returns the eager rates alone when that is all
    that ran, else ``{mode: rates, mode + "_warmup_s": ...}`` (``compile_warmup_s`` for
    ``compiled``)."""
    import torch
    if torch.device(device).type == "cpu":
        torch.set_num_threads(1)
    chosen = {k: ENV_SCENES[k] for k in (scenes or ENV_SCENES)}
    modes = ([("eager", {})] if eager else []) + ([("compiled", {"compile": True})] if compile else []) + (
        [("cuda_graph", {"compile": True, "cuda_graph": True})] if cuda_graph else [])
    out = {}
    for mode, kw_mode in modes:
        # each row printed as soon as it is measured (a run cut short keeps its rows in the log)
        title = {"eager": "torch env scene", "compiled": "torch env, compile=True",
                 "cuda_graph": "torch env, cuda_graph=True"}[mode]
        print(f"\n{title:<30}" + "".join(f"{'N=' + str(n) + ' steps/s':>16}{'ms/step':>10}{'cost/flat':>10}"
                                        f"{'warm s':>8}" for n in ns), flush=True)
        rates, warm = {}, {}
        for name, (eid, kw) in chosen.items():
            vals = [torch_env_rate(eid, kw, n, steps, device=device, dtype=dtype, **kw_mode) for n in ns]
            rates[name], warm[name] = [v[0] for v in vals], [v[1] for v in vals]
            flat = rates.get("flat")
            print(f"{name:<30}" + "".join(
                f"{v:16,.1f}{ns[i] / v * 1e3:10.1f}" + (f"{flat[i] / v:10.2f}" if flat else f"{'-':>10}")
                + f"{w:8.1f}" for i, (v, w) in enumerate(vals)), flush=True)
        out[mode] = rates
        if mode != "eager":
            out["compile_warmup_s" if mode == "compiled" else mode + "_warmup_s"] = warm
    return out["eager"] if list(out) == ["eager"] else out


def env_table(ns, steps: int, episode: bool = False, repeats: int = 1, scenes=None) -> tuple:
    """env-steps/s per scene and N over ``steps`` steps, or (``episode``) over each scene's
    registered episode length, its time limit: every copy resets once within the timed steps.
    ``repeats`` rounds, each timing every scene once in turn (so that a slower spell of a shared
    machine falls on all scenes of a round); the table gives each scene's median rate, the cost
    against flat ground as the ratio of the medians and, with more than one round, the range of
    the rounds' own ratios. ``scenes``: only these of ``ENV_SCENES`` besides flat ground (default
    all). Returns (median rates, every round's rates)."""
    import gymnasium as gym
    chosen = {k: ENV_SCENES[k] for k in ENV_SCENES if scenes is None or k == "flat" or k in scenes}
    rounds = [{name: [env_rate(eid, kw, n, gym.spec(eid).max_episode_steps if episode else steps) for n in ns]
               for name, (eid, kw) in chosen.items()} for _ in range(repeats)]
    med = {name: [float(np.median([r[name][i] for r in rounds])) for i in range(len(ns))] for name in chosen}
    what = "one episode each, resets included" if episode else f"{steps} steps after a reset"
    if repeats > 1:
        what += f"; median of {repeats} rounds"
    span = repeats > 1
    print(f"\n{'env scene (' + what + ')':<30}" + "".join(
        f"{'N=' + str(n) + ' steps/s':>16}{'cost/flat':>10}" + (f"{'rounds':>12}" if span else "") for n in ns))
    for name, vals in med.items():
        cells = []
        for i, v in enumerate(vals):
            cell = f"{v:16,.0f}{med['flat'][i] / v:10.2f}"
            if span:
                ratios = [r["flat"][i] / r[name][i] for r in rounds]
                cell += f"{min(ratios):7.2f}-{max(ratios):4.2f}"
            cells.append(cell)
        print(f"{name:<30}" + "".join(cells))
    return med, rounds


def torch_table(m, scenes: dict, batch, steps: int) -> dict:
    """microseconds per physics step of the torch backend (CPU, float64): flat ground contact
    (``backends.torch.contact.contact_step``) against each terrain (``backends.torch.terrain.terrain_step``)."""
    import torch
    from tensegrity_gym.backends.torch import contact as torch_contact
    from tensegrity_gym.backends.torch import terrain as TT
    rows = {"torch flat GroundContact": [], **{f"torch {k}": [] for k in scenes}}
    g = physics_contact.GroundContact()
    for B in batch:
        st = initial_state(m, B)
        q, qd = torch.as_tensor(np.array(st.q)), torch.as_tensor(np.array(st.qd))
        an, ac = torch_contact.init_contact_state(m, B, dtype=torch.float64)
        rows["torch flat GroundContact"].append(timed(lambda n: torch_contact.contact_step(m, g, q, qd, an, ac, DT, n_steps=n),
                                                      steps))
        for name, ter in scenes.items():
            tc = T.TerrainContact(ter)
            ts = TT.init_terrain_state(m, tc.n_features, B, dtype=torch.float64)
            rows[f"torch {name}"].append(timed(lambda n: TT.terrain_step(m, tc.geom, tc.prm, q, qd, *ts, DT, n_steps=n,
                                                                         hf=tc.hf), steps))
    for name, vals in rows.items():
        print(f"{name:<32}" + "".join(f"{v:16.2f}" for v in vals))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, nargs="*", default=[1, 64], help="physics table B (none: no physics table)")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--envs", type=int, nargs="*", default=[], help="env table for these numbers of copies")
    ap.add_argument("--env-steps", type=int, default=200)
    ap.add_argument("--episode", action="store_true",
                    help="time one whole episode per scene (every copy resets once) instead of --env-steps steps")
    ap.add_argument("--repeats", type=int, default=1,
                    help="rounds of the env table (every scene once per round); the median rate per scene")
    ap.add_argument("--scenes", nargs="+", default=None, choices=list(ENV_SCENES),
                    help="only these scenes in the env table, besides flat ground (default all)")
    ap.add_argument("--json", type=str, default=None, help="write the tables here")
    ap.add_argument("--torch", action="store_true", help="also the torch backend's physics table (CPU)")
    ap.add_argument("--torch-envs", type=int, nargs="*", default=[],
                    help="torch device env table for these numbers of copies (on --torch-device)")
    ap.add_argument("--torch-device", default="cpu", help="device of the torch env table (default cpu; cuda)")
    ap.add_argument("--torch-dtype", default="float64", choices=["float32", "float64"],
                    help="dtype of the torch env table (default float64)")
    ap.add_argument("--torch-scenes", nargs="+", default=None, choices=list(ENV_SCENES),
                    help="only these scenes in the torch env table (default all)")
    ap.add_argument("--torch-env-steps", type=int, default=10)
    ap.add_argument("--torch-compile", action="store_true",
                    help="the torch env table also with compile=True (after its compile, timed apart)")
    ap.add_argument("--torch-cuda-graph", action="store_true",
                    help="the torch env table also with compile=True, cuda_graph=True (a CUDA device)")
    ap.add_argument("--torch-no-eager", action="store_true", help="leave out the torch env's eager table")
    a = ap.parse_args()
    if a.repeats < 1:
        ap.error(f"--repeats must be at least 1, got {a.repeats}")
    m = prism()
    scenes = {"level plane": Terrain(), "20 deg plane": Terrain(plane=Plane(20.0)),
              "20 deg plane + 2 boxes": Terrain(plane=Plane(20.0), boxes=[Box([0.3, 0, 0.05], [0.2, 1, 0.1]),
                                                                          Box([-0.3, 0.2, 0.1], [0.2, 0.2, 0.2], 30.0)])}
    if a.batch:
        print(f"{'scene':<26}" + "".join(f"{'B=' + str(B) + ' us/step':>16}" for B in a.batch))
    rows = {"flat GroundContact": [], **{k: [] for k in scenes}}
    for B in a.batch:
        st = initial_state(m, B)
        g = physics_contact.GroundContact()
        cs = physics_contact.init_contact_state(m, B)
        rows["flat GroundContact"].append(timed(lambda n: pipeline.contact_step(m, g, st, cs, DT, n_steps=n), a.steps))
        for name, ter in scenes.items():
            tc = T.TerrainContact(ter)
            ts = T.init_terrain_state(tc, m, B)
            rows[name].append(timed(lambda n: T.step(m, st, DT, tc, ts, n_steps=n), a.steps))
    for name, vals in rows.items() if a.batch else ():
        print(f"{name:<26}" + "".join(f"{v:16.2f}" for v in vals))
    torch_rows = torch_table(m, scenes, a.batch, max(a.steps // 10, 20)) if a.torch else {}
    envs, env_rounds = env_table(a.envs, a.env_steps, a.episode, a.repeats, a.scenes) if a.envs else ({}, [])
    torch_envs = (torch_env_table(a.torch_envs, a.torch_env_steps, a.torch_compile, a.torch_device, a.torch_dtype,
                                   a.torch_scenes, not a.torch_no_eager, a.torch_cuda_graph) if a.torch_envs else {})
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"cpu": cpu_model(), "load_before": os.getloadavg(), "batch": a.batch, "physics_us_per_step": rows, "torch_us_per_step": torch_rows,
                       "envs": a.envs, "env_steps_per_s": envs, "env_rounds": env_rounds, "repeats": a.repeats,
                       "env_steps": a.env_steps, "episode": a.episode,
                       "torch_envs": a.torch_envs, "torch_env_steps_per_s": torch_envs,
                       "torch_device": a.torch_device, "torch_device_name": _device_name(a.torch_device),
                       "torch_dtype": a.torch_dtype, "command": "python -m scripts.bench.bench_terrain " +
                       " ".join(sys.argv[1:])}, f, indent=1)


def _device_name(device: str) -> str:
    import torch
    d = torch.device(device)
    return torch.cuda.get_device_name(d) if d.type == "cuda" else cpu_model()


if __name__ == "__main__":
    main()
