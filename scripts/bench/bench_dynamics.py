#!/usr/bin/env python
"""Dynamics step speed of tensegrity_gym next to the same scene in MuJoCo, plus accuracy checks.

What it measures (wall clock, best of a few repeats, everything timed in the same run):

* wall time per environment step and environment steps per second for the fixed-step
  integrators (``semi_implicit_euler``, ``rk4``), the numba kernels (the NumPy equations are the test oracle, not timed), on the free
  3-bar prism, the 6-bar icosahedron and a 30-stage prism tower (``tower(30)``), for
  B = 1, 64, 1024, 4096 copies, dt = 1 ms;
* the same scenes in MuJoCo (PyPI ``mujoco``), written by the package's MJCF writer
  (:func:`tensegrity_gym.io.mjcf.to_mjcf`): each rod a free body, each string a spatial tendon
  between sites at the rod ends with ``stiffness`` and ``springlength="0 l0"`` (a dead band:
  no force while shorter than l0), no gravity, no contact, integrator Euler (semi-implicit)
  or RK4, timestep 1 ms; our states enter MuJoCo through the same module's mapping. B = 1 is one ``mj_step`` call per step; batched MuJoCo is
  ``mujoco.rollout`` over B states with one MjData per core (its fastest batched path), and
  a Python loop of ``mj_step`` over B MjData where that is affordable;
* ratios ours / MuJoCo in steps per second (> 1: tensegrity_gym is faster);
* B = 1 per-call cost of each of our entry points (the public ``physics.step`` and
  ``physics.step_inplace``, the numba backend's ``step`` and ``step_inplace``), each with its
  ratio to the kernel's ``step_inplace`` measured in the same run;
* ``dop853`` (scipy, rtol = atol = 1e-10) wall seconds per simulated second, B = 1;
* checks: MuJoCo's tendon dead band (a stretched tendon pulls with k (L - l0), a short one
  carries no force), MuJoCo's prism at rest in its prestressed equilibrium and following the
  same trajectory as ours; RK4 at dt = 1e-4 over 2 s against DOP853 at rtol = atol = 1e-12
  (largest node error, m) and the relative energy drift of RK4 at dt = 1e-4 over 10 s, on a
  prism perturbed by a small random velocity so that no string goes slack.

Usage::

    .venv/bin/python -m scripts.bench.bench_dynamics                    # full run (a few minutes)
    .venv/bin/python -m scripts.bench.bench_dynamics --quick            # smoke run (~1 min)
    .venv/bin/python -m scripts.bench.bench_dynamics --out results/bench_dynamics.json

Targets (free 3-prism, dt = 1 ms, this 2-core machine): single-env step at least as
fast as ``mj_step`` (same integrator), B = 4096 >= 3M env-steps/s with semi-implicit Euler,
RK4 dt = 1e-4 within 1e-8 m of the reference over 2 s, energy drift < 1e-9 over 10 s.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

from tensegrity_gym.core import builders  # noqa: E402
from tensegrity_gym import physics  # noqa: E402
from tensegrity_gym.core.model import State, compile_model, initial_state  # noqa: E402
from tensegrity_gym.physics.evaluate import project  # noqa: E402
from tensegrity_gym.physics.integrate import step  # noqa: E402
from tensegrity_gym.physics.rollout import simulate  # noqa: E402
from tensegrity_gym.core.errors import StabilityWarning  # noqa: E402
from tensegrity_gym.physics.geometry import energy, node_positions, rod_length_drift, string_state  # noqa: E402
from tensegrity_gym.backends.numba import api as numba_api  # noqa: E402
from scripts._bench import mj_node_positions, mj_set_state, mjcf, mujoco_rollout_time, timeit

DT = 1e-3


# ---------------------------------------------------------------------------- scenes
def scenes(quick):
    out = {"prism3": builders.prism(3), "icosahedron": builders.icosahedron()}
    out["tower30"] = builders.tower(30)
    return out


def perturbed_state(model, B, scale, seed=0):
    """B copies of the structure with a small random velocity (m/s scale), projected so that
    rods keep their length."""
    rng = np.random.default_rng(seed)
    st = initial_state(model, B)
    q, qd = project(model, st.q, st.qd + scale * rng.normal(size=st.qd.shape))
    return State(np.ascontiguousarray(q), np.ascontiguousarray(qd), 0.0)


# ---------------------------------------------------------------------------- MuJoCo
def mujoco_slack_check(mujoco):
    """A point body tied to the world by one tendon (k = 1000 N/m, springlength [0, l0 = 1 m]):
    the passive force must be k (L - l0) towards the anchor when L > l0 and zero when L < l0."""
    k, l0 = 1000.0, 1.0
    xml = ('<mujoco><option gravity="0 0 0"/><worldbody><site name="a" pos="0 0 0"/>'
           '<body name="p" pos="1 0 0"><freejoint/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>'
           '<site name="b" pos="0 0 0"/></body></worldbody><tendon>'
           f'<spatial stiffness="{k}" springlength="0 {l0}"><site site="a"/><site site="b"/></spatial>'
           '</tendon></mujoco>')
    mm = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(mm)
    rows = []
    for L in (1.05, 0.95, 1.2, 0.5):
        d.qpos[:3] = (L, 0.0, 0.0)
        d.qpos[3:7] = (1, 0, 0, 0)
        d.qvel[:] = 0
        mujoco.mj_forward(mm, d)
        fx = float(d.qfrc_passive[0])
        expect = -k * max(L - l0, 0.0)
        rows.append(dict(length=L, rest_length=l0, mujoco_force_x=fx, expected_force_x=expect,
                         ok=abs(fx - expect) <= 1e-9 * k))
    return rows


# ---------------------------------------------------------------------------- benchmark
def bench_ours(model, B, integ, backend, target, repeats, numpy_limit):
    st = perturbed_state(model, B, 0.05)
    if backend == "numpy":
        return None, "not a backend (the NumPy path is the test oracle)"
    q, qd = st.q.copy(), st.qd.copy()

    def fn():
        numba_api.step_inplace(model, q, qd, DT, integ)
    t = timeit(fn, target, repeats)
    return (None, "skipped (one call > 2 s)") if t is None else (t / B, "")


def bench_mujoco(mujoco, rollout, model, B, integ, target, repeats, loop_limit):
    """(time per env-step via rollout or the single step, time per env-step via a loop)."""
    mm = mujoco.MjModel.from_xml_string(mjcf(model, "Euler" if integ == "semi_implicit_euler" else "RK4"))
    st = perturbed_state(model, 1, 0.05)
    d = mujoco.MjData(mm)
    mj_set_state(mujoco, mm, d, model, st.q[0], st.qd[0])
    if B == 1:
        t = timeit(lambda: mujoco.mj_step(mm, d), target, repeats)
        return t, t
    t_roll = mujoco_rollout_time(mujoco, rollout, mm, d, B, target, repeats)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    x0 = np.empty(mujoco.mj_stateSize(mm, spec))
    mujoco.mj_getState(mm, d, x0, spec)
    t_loop = None
    if B * mm.ntendon <= loop_limit:
        ds = [mujoco.MjData(mm) for _ in range(B)]
        for dd in ds:
            mujoco.mj_setState(mm, dd, x0, spec)

        def loop():
            for dd in ds:
                mujoco.mj_step(mm, dd)
        t_loop = timeit(loop, target, repeats)
        t_loop = None if t_loop is None else t_loop / B
    return t_roll, t_loop


def single_env_api(model, integ, target, repeats):
    """B = 1, one step per call, per entry point: seconds per call."""
    st = perturbed_state(model, 1, 0.05)
    q, qd = st.q.copy(), st.qd.copy()
    holder = [st, st]
    own = State(st.q.copy(), st.qd.copy(), st.t)

    def public():
        holder[0] = physics.step(model, holder[0], DT, integ)

    def kstep():
        holder[1] = numba_api.step(model, holder[1], DT, integ)

    def public_inplace():
        physics.step_inplace(model, own, DT, integ)

    def inplace():
        numba_api.step_inplace(model, q, qd, DT, integ)
    fns = {"physics.step": public, "physics.step_inplace": public_inplace, "numba step": kstep,
           "numba step_inplace": inplace}
    best = dict.fromkeys(fns)
    for _ in range(4 * repeats):     # interleaved rounds: a change of load hits every entry point alike
        for k, fn in fns.items():
            t = timeit(fn, target / 4, 1)
            best[k] = t if best[k] is None or (t is not None and t < best[k]) else best[k]
    return best


def dop853_cost(model, sim_time):
    st = perturbed_state(model, 1, 0.05)
    t0 = time.perf_counter()
    step(model, st, sim_time, "dop853", rtol=1e-10, atol=1e-10)
    return (time.perf_counter() - t0) / sim_time


# ---------------------------------------------------------------------------- accuracy
def accuracy_checks(quick):
    model = compile_model(builders.prism(3))
    st = perturbed_state(model, 1, 0.05, seed=1)
    T_acc = 0.2 if quick else 2.0
    T_en = 1.0 if quick else 10.0
    dt = 1e-4
    n_rec = 20
    steps = int(round(T_acc / dt))
    every = steps // n_rec
    t_r, q_r, _ = simulate(model, st, dt, steps, "rk4", record_every=every)
    t_d, q_d, _ = simulate(model, st, dt, steps, "dop853", record_every=every, rtol=1e-12, atol=1e-12)
    N_r = np.stack([node_positions(model, q) for q in q_r])
    N_d = np.stack([node_positions(model, q) for q in q_d])
    pos_err = float(np.abs(N_r - N_d).max())
    # energy drift over T_en, and the slack margin along the run
    steps_e = int(round(T_en / dt))
    every_e = steps_e // 200
    t_e, q_e, qd_e = simulate(model, st, dt, steps_e, "rk4", record_every=every_e)
    E = np.array([energy(model, q, qd)[0] for q, qd in zip(q_e, qd_e)])
    drift = float(np.abs(E - E[0]).max() / abs(E[0]))
    margin = min(float(np.min(string_state(model, q)[1] - model.rest_length)) for q in q_e)
    return dict(rk4_dt=dt, duration_s=T_acc, rk4_vs_dop853_max_node_error_m=pos_err,
                energy_duration_s=T_en, energy_relative_drift=drift, energy_J=float(E[0]),
                min_string_stretch_m=margin, all_strings_taut=margin > 0,
                rod_length_drift=float(max(rod_length_drift(model, q).max() for q in q_e)))


def mujoco_same_scene(mujoco, quick):
    """MuJoCo's prism: accelerations at the prestressed equilibrium, and node distance to our
    trajectory after a short run with RK4 at dt = 1e-4 in both."""
    model = compile_model(builders.prism(3))
    st0 = initial_state(model)
    mm = mujoco.MjModel.from_xml_string(mjcf(model, "RK4", dt=1e-4))
    d = mujoco.MjData(mm)
    mj_set_state(mujoco, mm, d, model, st0.q[0], st0.qd[0])
    qacc_eq = float(np.abs(d.qacc).max())
    st = perturbed_state(model, 1, 0.05, seed=2)
    mj_set_state(mujoco, mm, d, model, st.q[0], st.qd[0])
    T = 0.1 if quick else 0.5
    n = int(round(T / 1e-4))
    mujoco.mj_step(mm, d, nstep=n)
    mujoco.mj_kinematics(mm, d)
    ours = step(model, st, 1e-4, "rk4", n_steps=n)
    diff = float(np.abs(mj_node_positions(mujoco, mm, d, model.n_nodes) - node_positions(model, ours.q)[0]).max())
    moved = float(np.abs(node_positions(model, ours.q) - node_positions(model, st.q)).max())
    return dict(mujoco_max_qacc_at_equilibrium=qacc_eq, duration_s=T, max_node_difference_m=diff,
                max_node_displacement_m=moved)


# ---------------------------------------------------------------------------- main
def fmt_t(t):
    return "      -" if t is None else f"{t * 1e6:9.3f}"


def fmt_r(t):
    return "        -" if t is None else f"{1.0 / t:11,.0f}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small counts, B = 1 and 64 only (smoke test)")
    ap.add_argument("--out", type=Path, default=None, help="also write the numbers as JSON here")
    ap.add_argument("--no-mujoco", action="store_true")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore", category=StabilityWarning)
    quick = args.quick
    target, repeats = (0.02, 2) if quick else (0.15, 3)
    Bs = (1, 64) if quick else (1, 64, 1024, 4096)
    numpy_limit = 2e6
    try:
        import mujoco
        from mujoco import rollout
    except ImportError:
        mujoco = rollout = None
    if args.no_mujoco:
        mujoco = rollout = None
    import numba
    info = dict(python=platform.python_version(), numpy=np.__version__, numba=numba.__version__,
                mujoco=getattr(mujoco, "__version__", None), cpu=platform.processor() or platform.machine(),
                cores=os.cpu_count(), numba_threads=numba.get_num_threads(),
                load_average_start=os.getloadavg(), dt=DT, quick=quick, date=time.strftime("%Y-%m-%d %H:%M UTC",
                                                                                             time.gmtime()))
    print(f"# bench_dynamics: dt = {DT} s, {info['cores']} cores, numba {info['numba']} "
          f"({info['numba_threads']} threads), mujoco {info['mujoco']}, load average {info['load_average_start']}")
    results = dict(info=info, rows=[], single_env=[], checks={})

    if mujoco is not None:
        slack = mujoco_slack_check(mujoco)
        results["checks"]["mujoco_tendon_dead_band"] = slack
        print("\n## MuJoCo tendon dead band (springlength = [0, l0], k = 1000 N/m, l0 = 1 m)")
        for r in slack:
            print(f"  L = {r['length']:.2f} m: MuJoCo force {r['mujoco_force_x']:9.3f} N, "
                  f"expected -k max(L - l0, 0) = {r['expected_force_x']:9.3f} N  {'ok' if r['ok'] else 'MISMATCH'}")
        same = mujoco_same_scene(mujoco, quick)
        results["checks"]["mujoco_same_scene"] = same
        print(f"  MuJoCo prism at the prestressed equilibrium: max |qacc| = {same['mujoco_max_qacc_at_equilibrium']:.2e}")
        print(f"  MuJoCo vs tensegrity_gym, RK4 dt = 1e-4, {same['duration_s']} s from a perturbed state: "
              f"max node difference {same['max_node_difference_m']:.2e} m "
              f"(nodes moved up to {same['max_node_displacement_m']:.2e} m)")

    models = {name: compile_model(s) for name, s in scenes(quick).items()}
    t0 = time.perf_counter()        # compile (or load from numba's disk cache) every kernel before timing
    for integ in ("semi_implicit_euler", "rk4"):
        for B in (1, 4096):
            st = perturbed_state(models["prism3"], B, 0.05)
            numba_api.step_inplace(models["prism3"], st.q, st.qd, DT, integ)
            numba_api.step_inplace(models["prism3"], st.q, st.qd, DT, integ, rest_length=models["prism3"].rest_length)
    results["info"]["kernel_load_or_compile_s"] = time.perf_counter() - t0
    print(f"\n(numba kernels compiled or loaded from the disk cache in {time.perf_counter() - t0:.1f} s)")
    print("\n## Wall time per environment step (us) and environment steps per second")
    print("ours numba = the numba backend's step_inplace (one call per step for the whole batch); numpy: the "
          "NumPy equations are the test oracle, not timed; MuJoCo B = 1: mj_step; MuJoCo B > 1: mujoco.rollout "
          f"({os.cpu_count()} threads, 4 steps per call) and a Python loop of mj_step over B MjData.")
    hdr = (f"{'scene':12s} {'integrator':20s} {'B':>5s} | {'numba us':>9s} {'numba /s':>11s} | {'numpy us':>9s} "
           f"{'numpy /s':>11s} | {'MuJoCo us':>9s} {'MuJoCo /s':>11s} | {'mj loop us':>10s} | {'ours/MuJoCo':>11s}")
    print(hdr)
    print("-" * len(hdr))
    for name, model in models.items():
        for integ in ("semi_implicit_euler", "rk4"):
            for B in Bs:
                t_nb, _ = bench_ours(model, B, integ, "numba", target, repeats, numpy_limit)
                t_np, why_np = bench_ours(model, B, integ, "numpy", target, repeats, numpy_limit)
                t_mj = t_loop = None
                if mujoco is not None:
                    t_mj, t_loop = bench_mujoco(mujoco, rollout, model, B, integ, target, repeats,
                                                loop_limit=3e5 if not quick else 5e4)
                t_mj_best = min([t for t in (t_mj, t_loop) if t is not None], default=None)
                ratio = None if (t_mj_best is None or t_nb is None) else t_mj_best / t_nb
                row = dict(scene=name, integrator=integ, B=B, numba_s_per_env_step=t_nb,
                           numpy_s_per_env_step=t_np, numpy_note=why_np, mujoco_s_per_env_step=t_mj,
                           mujoco_loop_s_per_env_step=t_loop, ratio_ours_over_mujoco_steps_per_s=ratio)
                results["rows"].append(row)
                print(f"{name:12s} {integ:20s} {B:5d} | {fmt_t(t_nb)} {fmt_r(t_nb)} | {fmt_t(t_np)} {fmt_r(t_np)} | "
                      f"{fmt_t(t_mj)} {fmt_r(t_mj)} | {fmt_t(t_loop):>10s} | "
                      f"{'-' if ratio is None else f'{ratio:.2f}':>11s}", flush=True)
    print("(ours/MuJoCo: our env-steps/s over MuJoCo's best of rollout and loop; '-' = not run: NumPy "
          f"is skipped where B x (strings + rods) > {numpy_limit:.0e}, the mj_step loop where B x tendons is large)")

    print("\n## B = 1 free 3-prism, one step per call: cost of each entry point (us per step)")
    tg_inplace = {}
    prism = models["prism3"]
    for integ in ("semi_implicit_euler", "rk4"):
        api = single_env_api(prism, integ, target, repeats)
        mj = next((r["mujoco_s_per_env_step"] for r in results["rows"]
                   if r["scene"] == "prism3" and r["integrator"] == integ and r["B"] == 1), None)
        api["MuJoCo mj_step"] = mj
        kernel = api["numba step_inplace"]
        for k, v in api.items():
            rel = "" if (mj is None or v is None) else f"   ours/MuJoCo = {mj / v:.2f}"
            vs = "" if (v is None or k == "MuJoCo mj_step") else f"   / kernel step_inplace = {v / kernel:.2f}"
            print(f"  {integ:20s} {k:26s} {fmt_t(v)} us  {fmt_r(v)} steps/s{vs}{rel}")
        results["single_env"].append(dict(integrator=integ, **{k: v for k, v in api.items()}))
        ratio = api["physics.step_inplace"] / kernel
        tg_inplace[integ] = ratio

    print("\n## dop853 (scipy solve_ivp, rtol = atol = 1e-10), B = 1: wall seconds per simulated second")
    results["dop853_wall_s_per_sim_s"] = {}
    for name in ("prism3", "icosahedron"):
        c = dop853_cost(models[name], 0.05 if quick else 0.2)
        results["dop853_wall_s_per_sim_s"][name] = c
        print(f"  {name:12s} {c:8.2f} s per simulated s")

    print("\n## Accuracy (free 3-prism perturbed by a 0.05 m/s random velocity; no string goes slack)")
    acc = accuracy_checks(quick)
    results["checks"]["accuracy"] = acc
    print(f"  RK4 dt = 1e-4 vs DOP853 rtol = atol = 1e-12 over {acc['duration_s']} s: "
          f"max node error {acc['rk4_vs_dop853_max_node_error_m']:.3e} m")
    print(f"  RK4 dt = 1e-4 over {acc['energy_duration_s']} s: relative energy drift "
          f"{acc['energy_relative_drift']:.3e} (E = {acc['energy_J']:.4f} J), smallest string stretch "
          f"{acc['min_string_stretch_m']:.3e} m (all taut: {acc['all_strings_taut']}), "
          f"rod length drift {acc['rod_length_drift']:.1e}")

    # ------------------------------------------------------------------ targets
    def row(scene, integ, B):
        return next((r for r in results["rows"] if r["scene"] == scene and r["integrator"] == integ
                     and r["B"] == B), None)
    tg = {}
    for integ, absolute in (("semi_implicit_euler", 300e3), ("rk4", 80e3)):
        api = next(s for s in results["single_env"] if s["integrator"] == integ)
        mj = api.get("MuJoCo mj_step")
        for k in ("numba step_inplace", "numba step", "physics.step", "physics.step_inplace"):
            ours = api[k]
            tg[f"single env {integ}, {k}: >= mj_step"] = dict(
                ours_steps_per_s=1 / ours, mujoco_steps_per_s=None if mj is None else 1 / mj,
                reference_steps_per_s=absolute, met=None if mj is None else ours <= mj)
    for integ, ratio in tg_inplace.items():
        tg[f"single env {integ}: physics.step_inplace within 1.5x of the kernel's step_inplace"] = dict(
            ratio=ratio, met=ratio <= 1.5)
    r4096 = row("prism3", "semi_implicit_euler", 4096)
    if r4096 is not None and r4096["numba_s_per_env_step"]:
        v = 1 / r4096["numba_s_per_env_step"]
        tg["B = 4096 semi-implicit Euler >= 3M env-steps/s"] = dict(env_steps_per_s=v, met=v >= 3e6)
    tg["RK4 dt = 1e-4 within 1e-8 m of DOP853 over 2 s"] = dict(
        value_m=acc["rk4_vs_dop853_max_node_error_m"], met=acc["rk4_vs_dop853_max_node_error_m"] <= 1e-8,
        duration_s=acc["duration_s"])
    tg["energy drift < 1e-9 over 10 s (RK4 dt = 1e-4)"] = dict(
        value=acc["energy_relative_drift"], met=acc["energy_relative_drift"] < 1e-9,
        duration_s=acc["energy_duration_s"])
    results["targets"] = tg
    results["info"]["load_average_end"] = os.getloadavg()
    print("\n## Targets" + ("  [--quick: shortened, not the real check]" if quick else ""))
    for k, v in tg.items():
        met = v.get("met")
        vals = ", ".join(f"{a} = {b:,.4g}" if isinstance(b, float) else f"{a} = {b}"
                         for a, b in v.items() if a != "met" and b is not None)
        print(f"  [{'MET ' if met else 'MISS' if met is not None else ' ?  '}] {k}: {vals}")
    print(f"load average at the end: {results['info']['load_average_end']}")
    if rollout is not None:
        rollout.shutdown_persistent_pool()
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_suffix(args.out.suffix + ".tmp")
        tmp.write_text(json.dumps(results, indent=1, default=float))
        tmp.replace(args.out)
        print(f"wrote {args.out}")
    return results


if __name__ == "__main__":
    main()
