#!/usr/bin/env python
"""Outputs of two versions of the package on the committed scenes (a refactor keeps
every output equal to 1e-12 relative).

    PYTHONPATH=/path/to/old/checkout python -m scripts.tools.compare_outputs dump old.npz
    PYTHONPATH=/path/to/new/checkout python -m scripts.tools.compare_outputs dump new.npz
    (dump-terrain / dump-tasks: the terrain scenes / every task's envs, below)
    python -m scripts.tools.compare_outputs compare old.npz new.npz      # table; exit 1 above 1e-12

``dump`` runs, with whatever ``tensegrity_gym`` is importable: every built-in structure
(released off equilibrium by a fixed, seeded velocity perturbation) for 200 steps of semi-implicit
Euler and RK4 with the numba kernels and 20 steps with the NumPy path, dop853 and implicit Euler
(B = 3 copies); and 100 control steps of TensegrityShape-v0 (both action modes) and
TensegrityRoll-v0 (single env and a vector env of 4) under a fixed seeded action sequence
(observations, rewards); vector envs of 20 and 64 copies, nominal and randomised, and of 900
(the roll env's contact loop on all threads). Only public API is used, so any version can be dumped.

``dump-terrain`` runs the terrain scenes instead: the terrain contact kernel (forces, contact state
and per-slot info) of a level plane, a slope, a slope with boxes, a heightfield and per-copy
terrains; the torch backend's terrain step on them; 60 control steps of TensegrityRoll-v0 on each
terrain generator and TensegrityNavigate-v0 (single env and a vector env of 16, the loop driver's
lanes); the MuJoCo twin on steps; and the MJCF text of each terrain. ``dump-tasks`` runs 40 control
steps of every task (TensegrityRoll-v0 with and without a drawn goal and robot sensors and on the
steps and slope generators, TensegrityClimb-v0 with drawn slopes and robot sensors,
TensegrityNavigate-v0 with a height scan, TensegrityShape-v0) as a single env, a NumPy vector env of
3 and the torch device env of 3 with host resets (and device resets where the task has them):
observations, rewards and every numeric info. ``dump-terrain-single`` leaves
out what compiles the batched (SIMD) terrain kernel: the kernel at B = 19 and the vector envs.
"""
from __future__ import annotations

import sys

import numpy as np

SCENES = ("prism3", "prism4", "pinned_rod", "constrained_prism", "icosahedron", "tower3")
RUNS = (("semi_implicit_euler", "numba", 200), ("rk4", "numba", 200), ("dop853", "auto", 20),
        ("implicit_euler", "auto", 20))


def _rollout(env, rng, steps: int = 100):
    """(observations (steps + 1, ...), rewards (steps, ...)) under seeded random actions."""
    o, _ = env.reset(seed=3)
    obs, rew = [o], []
    for _ in range(steps):
        o, r, *_ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        obs.append(o)
        rew.append(r)
    return np.array(obs), np.array(rew)


def _released(model, B: int, seed: int):
    """B copies of the model's initial state released by a seeded velocity perturbation (projected)."""
    from tensegrity_gym.physics.evaluate import project
    from tensegrity_gym.core.model import State
    import tensegrity_gym as tg
    st = tg.initial_state(model, B)
    rng = np.random.default_rng(seed)
    q, qd = project(model, st.q, st.qd + 0.05 * rng.standard_normal(st.qd.shape))
    return State(q=q, qd=qd), rng


def dump(path: str) -> None:
    import gymnasium as gym
    import tensegrity_gym as tg
    out = {}
    for name in SCENES:
        model = tg.compile_model(tg.build(name))
        st, _ = _released(model, 3, 0)
        for integ, backend, n in RUNS:
            r = tg.step(model, st, 1e-3, integ, n_steps=n, backend=backend)
            out[f"{name}/{integ}/{backend}/q"] = r.q
            out[f"{name}/{integ}/{backend}/qd"] = r.qd
    # the kernels' batch paths: one copy at a time (B < 16), SIMD blocks (B = 19, 40, pad lanes),
    # the parallel kernel (B = 600), each with shared and per-copy Params
    from tensegrity_gym.core.params import default_params
    for name in ("prism3", "constrained_prism", "icosahedron", "tower3"):
        model = tg.compile_model(tg.build(name))
        for B in (1, 3, 19, 40, 600):
            st, rng = _released(model, B, B)
            p0 = default_params(model, batch_size=B)
            per_copy = p0.replace(stiffness=p0.stiffness * rng.uniform(0.8, 1.2, p0.stiffness.shape),
                                  mass=p0.mass * rng.uniform(0.8, 1.2, p0.mass.shape))
            for integ in ("semi_implicit_euler", "rk4"):
                for tag, params in (("shared", None), ("per_copy", per_copy)):
                    r = tg.step(model, st, 1e-3, integ, n_steps=50, backend="numba", params=params)
                    out[f"batch/{name}/B={B}/{integ}/{tag}/q"] = r.q
                    out[f"batch/{name}/B={B}/{integ}/{tag}/qd"] = r.qd
    envs = (("TensegrityShape-v0", {}), ("TensegrityShape-v0", {"action_mode": "force_density"}),
            ("TensegrityRoll-v0", {}))
    for env_id, kw in envs:
        tag = env_id + "/" + "/".join(f"{k}={v}" for k, v in kw.items())
        rng = np.random.default_rng(1)
        for kind, env in (("single", gym.make(env_id, **kw)),
                          ("vector", gym.make_vec(env_id, num_envs=4, vectorization_mode="vector_entry_point", **kw))):
            out[f"{tag}/{kind}/obs"], out[f"{tag}/{kind}/rew"] = _rollout(env, rng)
    # the roll env's contact sub-steps on all threads (enough work for the parallel kernel)
    env = gym.make_vec("TensegrityRoll-v0", num_envs=900, vectorization_mode="vector_entry_point")
    out["TensegrityRoll-v0/vector/N=900/obs"], out["TensegrityRoll-v0/vector/N=900/rew"] = _rollout(
        env, np.random.default_rng(4), steps=30)
    for env_id, N, rnd in (("TensegrityRoll-v0", 20, {"rod_mass": 0.1, "friction": 0.2, "stiffness": 0.1}),
                           ("TensegrityRoll-v0", 64, {"rod_mass": 0.1, "friction": 0.2, "stiffness": 0.1}),
                           ("TensegrityShape-v0", 20,
                            {"rod_mass": 0.1, "stiffness": 0.1, "rest_length_offset": 0.002})):
        env = gym.make_vec(env_id, num_envs=N, vectorization_mode="vector_entry_point", randomize=rnd)
        out[f"{env_id}/randomized/N={N}/obs"], out[f"{env_id}/randomized/N={N}/rew"] = _rollout(
            env, np.random.default_rng(2), steps=30)
    # the robot observation (sensors, noise from each env's generator, history) and the MuJoCo twin
    robot = {"observation_mode": "robot", "history": 2,
             "sensor_noise": {"imu_accel": 0.05, "imu_gyro": 0.01, "cable_length": 1e-3}}
    for env_id, kw in (("TensegrityRoll-v0", dict(robot, sensor_noise=dict(robot["sensor_noise"], contact=0.1))),
                       ("TensegrityShape-v0", robot)):
        for kind, env in (("single", gym.make(env_id, **kw)),
                          ("vector", gym.make_vec(env_id, num_envs=4, vectorization_mode="vector_entry_point", **kw))):
            out[f"{env_id}/robot/{kind}/obs"], out[f"{env_id}/robot/{kind}/rew"] = _rollout(
                env, np.random.default_rng(5), steps=30)
    for kw in ({}, robot):
        env = gym.make("TensegrityRollMuJoCo-v0", **kw)
        tag = "robot" if kw else "state"
        out[f"TensegrityRoll-v0/mujoco/{tag}/obs"], out[f"TensegrityRoll-v0/mujoco/{tag}/rew"] = _rollout(
            env, np.random.default_rng(6), steps=30)
    np.savez(path, **out)


def dump_terrain(path: str, batched: bool = True) -> None:
    import gymnasium as gym
    import tensegrity_gym as tg
    from tensegrity_gym.core.terrain import Box, Heightfield, Plane, Terrain
    from tensegrity_gym.io.mjcf import to_mjcf
    from tensegrity_gym.physics import terrain as T
    out = {}
    rng = np.random.default_rng(7)
    hf = Heightfield(0.03 * rng.standard_normal((12, 14)), 0.1, (-0.7, -0.6))
    boxes = [Box([0.2, 0.0, 0.04], [0.2, 1.0, 0.1]), Box([-0.25, 0.15, 0.08], [0.2, 0.2, 0.2], 30.0, friction=0.5)]
    terrains = {"level": Terrain(), "slope": Terrain(plane=Plane(15.0, 30.0)),
                "slope_boxes": Terrain(plane=Plane(5.0), boxes=boxes),
                "hfield": Terrain(plane=None, heightfield=hf, damping=5.0),
                "all": Terrain(plane=Plane(-3.0), boxes=boxes[:1], heightfield=hf)}
    structure = tg.build("prism3")
    model = tg.compile_model(structure)
    for name, ter in terrains.items():
        out[f"mjcf/{name}"] = np.frombuffer(to_mjcf(structure, terrain=ter).encode(), np.uint8)
        for B in ((1, 3, 19) if batched else (1, 3)):
            st, _ = _released(model, B, B)
            st = type(st)(q=st.q - np.array([0, 0, 0.03, 0, 0, 0]) * (np.arange(B)[:, None, None] % 3),
                          qd=st.qd)
            tc = T.TerrainContact(ter)
            ts = T.init_terrain_state(tc, model, B)
            r, ts = T.step(model, st, 1e-3, tc, ts, n_steps=150)
            out[f"kernel/{name}/B={B}/q"], out[f"kernel/{name}/B={B}/qd"] = r.q, r.qd
            for k in ("anchor", "eta0", "active"):
                out[f"kernel/{name}/B={B}/{k}"] = getattr(ts, k)
            res = T.contact_forces(tc, model, r.q, r.qd, ts, info=True)
            for i, x in enumerate(res if isinstance(res, tuple) else (res,)):
                for k, v in (vars(x).items() if hasattr(x, "__dict__") else (("", x),)):
                    if isinstance(v, np.ndarray):
                        out[f"kernel/{name}/B={B}/forces/{i}{k}"] = v
    # per-copy terrains (one geometry and heights per copy)
    B = 3
    st, _ = _released(model, B, 5)
    tc = T.TerrainContact(terrains["all"])
    geom = np.repeat(tc.geom, B, axis=0)
    geom[1, 0, 1:5] = T.TerrainContact(terrains["slope"]).geom.reshape(-1, 10)[0, 1:5]
    ts = T.init_terrain_state(tc, model, B)
    r, ts = T.step(model, st, 1e-3, tc, ts, n_steps=100, geom=geom, prm=tc.per_copy(B) * [1, 1, 1, 1, 0.5, 1, 1, 1])
    out["kernel/per_copy/q"], out["kernel/per_copy/qd"], out["kernel/per_copy/anchor"] = r.q, r.qd, ts.anchor
    try:
        import torch
        from tensegrity_gym.backends.torch import terrain as TT
        for name, ter in terrains.items():
            st, _ = _released(model, 3, 11)
            q, qd = torch.as_tensor(np.array(st.q)), torch.as_tensor(np.array(st.qd))
            tc = T.TerrainContact(ter)
            ts = TT.init_terrain_state(model, tc.n_features, 3, dtype=torch.float64)
            res = TT.terrain_step(model, tc.geom, tc.prm, q, qd, *ts, 1e-3, n_steps=60, hf=tc.hf)
            for i, x in enumerate(res if isinstance(res, tuple) else (res,)):
                if hasattr(x, "numpy"):
                    out[f"torch/{name}/{i}"] = x.detach().numpy()
    except ImportError:
        pass
    scenes = {"slope": ("TensegrityRoll-v0", {"terrain": {"plane": {"slope_deg": 20.0}}}),
              "steps": ("TensegrityRoll-v0", {"terrain": {"generator": "steps"}}),
              "steps_under": ("TensegrityRoll-v0", {"terrain": {"generator": "steps", "pad": 0.05, "tread": 0.2}}),
              "rough": ("TensegrityRoll-v0", {"terrain": {"generator": "rough", "amplitude": 0.02, "pad": 0.0}}),
              "navigate": ("TensegrityNavigate-v0", {})}
    for tag, (env_id, kw) in scenes.items():
        envs = [("single", gym.make(env_id, **kw))]
        if batched:
            envs.append(("vector", gym.make_vec(env_id, num_envs=16, vectorization_mode="vector_entry_point", **kw)))
        for kind, env in envs:
            out[f"env/{tag}/{kind}/obs"], out[f"env/{tag}/{kind}/rew"] = _rollout(env, np.random.default_rng(8),
                                                                                steps=60)
    env = gym.make("TensegrityRollMuJoCo-v0", terrain={"generator": "steps"})
    out["env/steps/mujoco/obs"], out["env/steps/mujoco/rew"] = _rollout(env, np.random.default_rng(9), steps=30)
    np.savez(path, **out)


def compare(a: str, b: str) -> int:
    A, B = np.load(a), np.load(b)
    worst = 0.0
    print("| output | max abs difference | max relative difference |\n|---|---:|---:|")
    for k in sorted(set(A.files) | set(B.files)):
        if k not in A.files or k not in B.files:
            print(f"| {k} | missing in {'the first' if k not in A.files else 'the second'} | |")
            worst = np.inf
            continue
        x, y = A[k].astype(float), B[k].astype(float)
        # equal values (infinities and NaNs included) differ by 0; a NaN against a number by inf
        same = (x == y) | (np.isnan(x) & np.isnan(y))
        with np.errstate(invalid="ignore"):
            d = np.where(same, 0.0, np.nan_to_num(np.abs(x - y), nan=np.inf))
        rel = float((d / np.maximum(np.abs(x), 1.0)).max()) if d.size else 0.0
        worst = max(worst, rel)
        print(f"| {k} | {float(d.max()) if d.size else 0.0:.3g} | {rel:.3g} |")
    print(f"\nlargest relative difference: {worst:.3g} ({'within' if worst <= 1e-12 else 'ABOVE'} 1e-12)")
    return 0 if worst <= 1e-12 else 1


TASK_CASES = (("TensegrityRoll-v0", {}), ("TensegrityClimb-v0", {"slope_range": (5.0, 25.0)}),
              ("TensegrityClimb-v0", {"slope_range": (5.0, 25.0), "observation_mode": "robot"}),
              ("TensegrityNavigate-v0", {"height_scan": (3, 0.2)}), ("TensegrityShape-v0", {}),
              ("TensegrityRoll-v0", {"observation_mode": "robot", "randomize_goal": True}),
              ("TensegrityRoll-v0", {"terrain": {"generator": "steps"}, "randomize_goal": True}),
              ("TensegrityRoll-v0", {"terrain": {"generator": "slope"}}))


def _task_rollout(out: dict, name: str, env, steps: int = 40, as_tensor=None) -> None:
    """Observations, rewards and numeric infos of ``steps`` seeded random-action steps into ``out``."""
    rng = np.random.default_rng(1)
    o, _ = env.reset(seed=5)
    obs, rew, infos = [np.asarray(o, float)], [], {}
    for _ in range(steps):
        a = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        o, r, _, _, info = env.step(a if as_tensor is None else as_tensor(a))
        obs.append(np.asarray(o, float))
        rew.append(np.asarray(r, float))
        for k, v in info.items():
            if not isinstance(v, dict):
                try:
                    infos.setdefault(k, []).append(np.asarray(v, dtype=float))
                except (TypeError, ValueError):
                    pass
    out[name + "/obs"], out[name + "/rew"] = np.array(obs), np.array(rew)
    for k, v in infos.items():
        try:
            out[name + "/info/" + k] = np.array(v)
        except ValueError:       # ragged: not compared
            pass


def dump_tasks(path: str) -> None:
    import gymnasium as gym
    import tensegrity_gym  # noqa: F401  (registers the ids)
    import torch
    out = {}
    f64 = (lambda a: torch.as_tensor(a, dtype=torch.float64))
    vec = dict(num_envs=3, vectorization_mode="vector_entry_point")
    for i, (eid, kw) in enumerate(TASK_CASES):
        _task_rollout(out, f"{i}/single", gym.make(eid, **kw))
        _task_rollout(out, f"{i}/vector", gym.make_vec(eid, **vec, **kw))
        _task_rollout(out, f"{i}/torch", gym.make_vec(eid, **vec, backend="torch", **kw), as_tensor=f64)
        if eid in ("TensegrityRoll-v0", "TensegrityClimb-v0"):
            _task_rollout(out, f"{i}/torch_device_reset",
                          gym.make_vec(eid, **vec, backend="torch", reset_sampling="device", **kw), as_tensor=f64)
    np.savez(path, **out)
    print(f"{len(out)} arrays -> {path}")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "dump":
        dump(sys.argv[2])
        raise SystemExit(0)
    if len(sys.argv) == 3 and sys.argv[1] in ("dump-terrain", "dump-terrain-single"):
        dump_terrain(sys.argv[2], batched=sys.argv[1] == "dump-terrain")
        raise SystemExit(0)
    if len(sys.argv) == 3 and sys.argv[1] == "dump-tasks":
        dump_tasks(sys.argv[2])
        raise SystemExit(0)
    if len(sys.argv) == 4 and sys.argv[1] == "compare":
        raise SystemExit(compare(sys.argv[2], sys.argv[3]))
    print(__doc__, file=sys.stderr)
    raise SystemExit(2)
