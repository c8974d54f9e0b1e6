"""Batched random search over RollingGait-style travelling-wave patterns on TensegrityRoll-v0.

    python scripts/gait_search.py 1 4096        # seed 1, 4096 patterns, 10 s each (~35 s on 2 cores)

Every pattern runs in one env of one batched vector env (the same physics as the env): the
rest-length targets of the wave in ``tensegrity_gym.baselines.RollingGait`` with per-env
parameters, the cable-speed action that tracks them, and, per control step, the best-fit rigid
rotation of the nodes (Kabsch) accumulated as a rotation vector. Prints the patterns that
progressed most along +x and those that rotated most about a horizontal axis (rolling), and
saves everything to /tmp/gs/res_SEED.npz. A pattern rolls when its displacement is along
(net turns) x z. Findings: ``results/gait_search/README.md``.
"""
import sys, time, numpy as np
from scipy.spatial.transform import Rotation
import gymnasium as gym, tensegrity_gym
from tensegrity_gym import dynamics as dyn
from tensegrity_gym.envs.roll import TensegrityRollVectorEnv

def run(P, T=10.0, seed=0):
    B = len(P["period"])
    env = TensegrityRollVectorEnv(num_envs=B, max_episode_steps=None)
    obs, _ = env.reset(seed=seed)
    task = env.task
    sl = {n: s for n, s, _ in task.observation_layout()}["control"]
    nominal = task.actuation.nominal; low, high = task.actuation.low, task.actuation.high
    step = task.actuation.max_rate * task.control_dt
    sym = np.tile(np.arange(3), 3); kind = np.repeat(np.arange(3), 3)
    amp = P["amplitude"][:, kind]; ph = P["phase"][:, kind]
    N0 = dyn.node_positions(task.model, task.q); prev = N0 - N0.mean(1, keepdims=True)
    rot = np.zeros((B, 3)); start = dyn.center_of_mass(task.model, task.q)
    n = int(round(T / task.control_dt))
    for k in range(n):
        t = k * task.control_dt
        x = t / P["period"][:, None] - P["direction"][:, None] * sym[None] / 3.0 - ph
        p = ((1 - np.cos(2 * np.pi * x)) / 2) ** P["sharpness"][:, None]
        tgt = np.clip(nominal[None] * (1 - amp * p), low, high)
        a = np.clip((tgt - obs[:, sl]) / step, -1, 1).astype(np.float32)
        obs, r, term, trunc, info = env.step(a)
        N = dyn.node_positions(task.model, task.q); cur = N - N.mean(1, keepdims=True)
        H = np.einsum("bni,bnj->bij", prev, cur)
        U, S, Vt = np.linalg.svd(H)
        V = np.swapaxes(Vt, 1, 2); Ut = np.swapaxes(U, 1, 2)
        d = np.sign(np.linalg.det(V @ Ut))
        D = np.tile(np.eye(3), (B, 1, 1)); D[:, 2, 2] = d
        R = V @ D @ Ut
        rot += Rotation.from_matrix(R).as_rotvec()
        prev = cur
    com = dyn.center_of_mass(task.model, task.q)
    return com - start, rot / (2 * np.pi)

def sample(rng, B):
    return {"amplitude": rng.uniform(0.0, 0.5, (B, 3)), "phase": rng.uniform(0, 1, (B, 3)),
            "period": rng.uniform(0.5, 4.0, B), "direction": rng.choice([-1, 1], B).astype(float),
            "sharpness": rng.choice([1.0, 2.0, 4.0], B)}

if __name__ == "__main__":
    import os
    os.makedirs("/tmp/gs", exist_ok=True)
    rng = np.random.default_rng(int(sys.argv[1]) if len(sys.argv) > 1 else 0)
    B = int(sys.argv[2]) if len(sys.argv) > 2 else 256
    t0 = time.time()
    P = sample(rng, B)
    disp, turns = run(P, T=10.0)
    print("wall", time.time() - t0)
    # rolling about any horizontal axis: displacement consistent with rotation w x z
    roll_dir = np.cross(turns, [0, 0, 1.0])   # direction of travel a roll with these turns gives
    score = disp[:, 0]
    order = np.argsort(-score)
    for i in order[:12]:
        print(f"dx {disp[i,0]:+.3f} dy {disp[i,1]:+.3f} turns {turns[i].round(2)} "
              f"amp {P['amplitude'][i].round(2)} ph {P['phase'][i].round(2)} per {P['period'][i]:.2f} dir {P['direction'][i]:+.0f} sh {P['sharpness'][i]}")
    big = np.argsort(-np.abs(turns[:, :2]).sum(1))[:8]
    print("-- most horizontal rotation")
    for i in big:
        print(f"dx {disp[i,0]:+.3f} dy {disp[i,1]:+.3f} turns {turns[i].round(2)} amp {P['amplitude'][i].round(2)} ph {P['phase'][i].round(2)} per {P['period'][i]:.2f} dir {P['direction'][i]:+.0f} sh {P['sharpness'][i]}")
    np.savez("/tmp/gs/res_%s.npz" % (sys.argv[1] if len(sys.argv) > 1 else 0), disp=disp, turns=turns, **P)

def big(seed, B, T=10.0):
    rng = np.random.default_rng(seed)
    P = sample(rng, B)
    disp, turns = run(P, T=T)
    return P, disp, turns
