#!/usr/bin/env python
"""Speed-accuracy trade of the integrators, per scene; feature costs; MuJoCo on the same axes.

For each scene (free prism, anchored prism with gravity and damping, icosahedron, stiff
prism with 1e5 N/m strings on 0.1 kg rods; the rolling prism with contact when
``tensegrity_gym.physics.contact`` exists), each fixed-step integrator and a sweep of time steps,
it measures against a DOP853 reference at rtol = atol = 1e-12:

* ``pos_err``: largest node position error over the record times (m),
* ``energy_err``: largest |E(t) - E_ref(t)| / |E_ref(0)| over the record times,
* ``rod_drift``: largest | |b| - 1 | over the record times (rods projected after each step),
* ``wall_per_sim_s``: wall-clock seconds per simulated second (B = 1),

and MuJoCo (rods as free bodies with thin-rod inertia, strings as spatial tendons with a
``springlength`` dead band [0, l0], Euler and RK4) on the free prism against the same
reference. Then it times one step of the same 3-prism with and without each optional
feature (gravity, string damping, node constraints, contact).

Outputs: ``results/speed_accuracy.csv``, ``results/speed_accuracy.png`` (error vs cost,
log-log, one panel per scene, one curve per integrator), ``results/feature_costs.csv`` and
``docs/speed_accuracy.md`` (tables, recommendation).

Usage::

    .venv/bin/python -m scripts.figures.speed_accuracy            # full run (a few minutes)
    .venv/bin/python -m scripts.figures.speed_accuracy --quick    # smoke run (~30 s), does not touch docs/
"""
from __future__ import annotations

import argparse
import csv
import os
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

import tensegrity_gym as tg  # noqa: E402
from tensegrity_gym.core.model import State, compile_model, initial_state  # noqa: E402
from tensegrity_gym.physics.evaluate import project  # noqa: E402
from tensegrity_gym.physics.integrate import step  # noqa: E402
from tensegrity_gym.physics.rollout import simulate  # noqa: E402
from tensegrity_gym.core.errors import SimulationDiverged, StabilityWarning  # noqa: E402
from tensegrity_gym.physics.geometry import energy, node_positions, rod_length_drift  # noqa: E402
from tensegrity_gym.physics.stability import stability_limit  # noqa: E402
from scripts._bench import timed as _timed  # noqa: E402
from tensegrity_gym.io.mjcf import to_mjcf  # noqa: E402

FIXED = ("semi_implicit_euler", "rk4", "implicit_euler")


# ----------------------------------------------------------------------------- scenes
def _perturbed(model, scale, seed):
    """The structure's initial state with random rod velocities (m/s, 1/s) of std ``scale``,
    projected onto the constraints (so b . b' = 0 and constrained nodes move on their set)."""
    st = initial_state(model)
    rng = np.random.default_rng(seed)
    q, qd = project(model, st.q, scale * rng.normal(size=st.qd.shape))
    return State(q=q, qd=qd, t=0.0)


def _contact_available():
    return (ROOT / "tensegrity_gym" / "contact.py").exists()


def rolling_scene(T):
    """The TensegrityRoll-v0 robot prism (0.2 kg rods, 1e3 N/m strings with 2 N s/m damping,
    gravity) standing on the default ground (Hunt-Crossley 1e4 N/m, Coulomb mu = 1 with stick
    springs), launched at 1 m/s along x with an 8 rad/s spin about y, so that it slides, tips
    and rolls. Contact is a discrete-time model (stick anchors updated once per
    step): the reference is semi-implicit Euler at dt = 5e-6 s, not DOP853."""
    from tensegrity_gym.physics.contact import GroundContact
    from tensegrity_gym.envs.roll import robot_prism
    s = robot_prism()
    m = compile_model(s)
    nodes = s.nodes.copy()
    nodes[:, 2] += 0.02 - nodes[:, 2].min()             # caps (radius 2 cm) touching the ground
    st = initial_state(m, nodes=nodes)
    c = st.q[0, :, :3].mean(axis=0)
    w = np.array([0.0, 8.0, 0.0])                       # rad/s spin about y, about the prism's centre
    vel = np.array([1.0, 0.0, 0.0]) + np.cross(w, nodes - c)
    st = initial_state(m, nodes=nodes, velocities=vel)
    q, qd = project(m, st.q, st.qd)
    return dict(model=m, state=State(q, qd, 0.0), T=T, contact=GroundContact(),
                description="TensegrityRoll-v0 robot prism (0.2 kg rods, 1e3 N/m strings, 2 N s/m "
                            "damping, gravity) on the ground (contact 1e4 N/m, mu = 1), launched at 1 m/s "
                            "with an 8 rad/s spin; reference: semi-implicit Euler at dt = 5e-6 s (contact "
                            "is a discrete-time model, no DOP853); energy includes the contact springs")


def _contact_run(sc, dt, integrator, backend, n_rec):
    """Records (S+1 of them) of (q, qd, contact energy) stepping with contact_step."""
    from tensegrity_gym.physics.contact import contact_energy, init_contact_state
    from tensegrity_gym.physics.pipeline import contact_step
    m, st, T, c = sc["model"], sc["state"], sc["T"], sc["contact"]
    n = int(round(T / dt))
    every = n // n_rec
    cs = init_contact_state(m)
    qs, qds, ec = [st.q], [st.qd], [contact_energy(c, m, st.q, cs)[0]]
    for _ in range(n_rec):
        st, cs = contact_step(m, c, st, cs, dt, integrator, n_steps=every, backend=backend)
        if not (np.all(np.isfinite(st.q)) and np.all(np.isfinite(st.qd))):
            raise SimulationDiverged(f"{integrator}: non-finite state with contact by t = {st.t:.4g} s")
        qs.append(st.q)
        qds.append(st.qd)
        ec.append(contact_energy(c, m, st.q, cs)[0])
    return np.array(qs), np.array(qds), np.array(ec)


def contact_self_convergence(sc, dts=(1e-3, 2.5e-4, 6.25e-5, 3.125e-5, 1.5625e-5)):
    """[(dt, largest node distance at T to the dt = 5e-6 s run)] for semi-implicit Euler + contact."""
    m = sc["model"]
    end = {}
    for dt in dts + (5e-6,):
        q, _, _ = _contact_run(sc, dt, "semi_implicit_euler", "auto", 1)
        end[dt] = node_positions(m, q[-1])[0]
    return [(dt, float(np.linalg.norm(end[dt] - end[5e-6], axis=1).max())) for dt in dts]


def scenes(quick: bool):
    """name -> dict(model, state, T (s), n_rec, dts {integrator: [dt]}, description)."""
    T = 0.25 if quick else 0.5
    out = {}
    m = compile_model(tg.prism())
    out["free_prism"] = dict(
        model=m, state=_perturbed(m, 0.3, 0), T=T,
        description="3-prism, 1 kg rods, 1e3 N/m strings, 100 N prestress, no gravity, random "
                    "velocities 0.3 m/s", )
    m = compile_model(tg.constrained_prism(damping=5.0))
    out["anchored_prism"] = dict(
        model=m, state=_perturbed(m, 0.3, 1), T=T,
        description="seed Example 5.8 prism (node 0 pinned, node 1 on a line, node 2 on a plane), "
                    "gravity, string damping 5 N s/m, random velocities 0.3 m/s")
    m = compile_model(tg.icosahedron())
    out["icosahedron"] = dict(
        model=m, state=_perturbed(m, 0.3, 2), T=T,
        description="6-bar icosahedron, 1 kg rods, 1e3 N/m strings, 50 N prestress, no gravity, "
                    "random velocities 0.3 m/s")
    m = compile_model(tg.prism(stiffness=1e5, bar_mass=0.1))
    out["stiff_prism"] = dict(
        model=m, state=_perturbed(m, 0.1, 3), T=T / 5,
        description="3-prism, 0.1 kg rods, 1e5 N/m strings (real cables), 100 N prestress, no "
                    "gravity, random velocities 0.1 m/s")
    if _contact_available():
        out["rolling_prism"] = rolling_scene(0.6 * T)
    for name, sc in out.items():
        sc["n_rec"] = 5 if quick else 10
        stiff = name in ("stiff_prism", "rolling_prism")   # quick sweep: the small steps
        if quick:
            base = [2e-3, 5e-4, 1e-4] if stiff else [1e-2, 2e-3, 5e-4]
            sc["dts"] = {"semi_implicit_euler": base, "rk4": base, "implicit_euler": base[:2]}
        elif name == "rolling_prism":
            sc["dts"] = {"semi_implicit_euler": [2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5],
                         "rk4": [2e-3, 1e-3, 5e-4, 2e-4],
                         "implicit_euler": [2e-3, 1e-3, 5e-4]}
        elif stiff:
            sc["dts"] = {"semi_implicit_euler": [2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5],
                         "rk4": [2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5],
                         "implicit_euler": [2e-3, 1e-3, 5e-4, 2e-4]}
        else:
            sc["dts"] = {"semi_implicit_euler": [1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4],
                         "rk4": [2.5e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4],
                         "implicit_euler": [1e-2, 5e-3, 2e-3, 1e-3, 5e-4]}
    return out


# ----------------------------------------------------------------------------- measurement
def reference(sc):
    """DOP853 at rtol = atol = 1e-12 at the record times: (t, nodes (S, n, 3), energy (S,))."""
    m, st, T, S = sc["model"], sc["state"], sc["T"], sc["n_rec"]
    if "contact" in sc:
        q, qd, ec = _contact_run(sc, 5e-6, "semi_implicit_euler", "auto", S)
        t = np.linspace(0.0, T, S + 1)
    else:
        t, q, qd = simulate(m, st, T / S, S, "dop853", rtol=1e-12, atol=1e-12)
        ec = np.zeros(len(q))
    nodes = np.stack([node_positions(m, qi)[0] for qi in q])
    E = np.array([energy(m, qi, qdi)[0] for qi, qdi in zip(q, qd)]) + ec
    return t, nodes, E


def errors(sc, ref, q, qd, ec=None):
    m = sc["model"]
    _, nref, Eref = ref
    nodes = np.stack([node_positions(m, qi)[0] for qi in q])
    E = np.array([energy(m, qi, qdi)[0] for qi, qdi in zip(q, qd)]) + (0.0 if ec is None else ec)
    pos = float(np.max(np.linalg.norm(nodes - nref, axis=-1)))
    en = float(np.max(np.abs(E - Eref)) / abs(Eref[0]))
    rod = float(max(rod_length_drift(m, qi)[0] for qi in q))
    return pos, en, rod


def run_one(sc, ref, integrator, dt, backend):
    """One fixed-step run: returns a row dict (errors, cost, status)."""
    m, st, T, S = sc["model"], sc["state"], sc["T"], sc["n_rec"]
    n = int(round(T / dt))
    every = n // S
    assert every * S == n, (T, dt, S)
    row = dict(integrator=integrator, backend=backend, dt=dt, steps=n, status="ok", warned=False)
    m.__dict__.pop("_stability_checked", None)   # forget earlier checks: every row records its own warning
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("ignore", RuntimeWarning)
        warnings.simplefilter("always", StabilityWarning)
        try:
            if "contact" in sc:
                _contact_run(dict(sc, T=2 * dt * S), dt, integrator, backend, S)   # warm-up, not timed
                (q, qd, ec), wall = _timed(lambda: _contact_run(sc, dt, integrator, backend, S))
            else:
                step(m, st, dt, integrator, backend=backend, n_steps=2)            # warm-up, not timed
                (_, q, qd), wall = _timed(lambda: simulate(m, st, dt, n, integrator, record_every=every,
                                                           backend=backend))
                ec = None
            pos, en, rod = errors(sc, ref, q, qd, ec)
            if not np.isfinite(pos) or pos > 1e3 or en > 1.0:   # finite but energy off by > 100 %
                row["status"] = "unstable"
        except (SimulationDiverged, ZeroDivisionError, FloatingPointError):
            wall, pos, en, rod = np.nan, np.inf, np.inf, np.inf
            row["status"] = "diverged"
        row["warned"] = any(issubclass(w.category, StabilityWarning) for w in caught)
    row.update(pos_err=pos, energy_err=en, rod_drift=rod, wall_per_sim_s=wall / T,
               us_per_step=wall / n * 1e6)
    return row


def warm_up(model, state):
    """Compile (or load from numba's cache) the kernels before anything is timed."""
    step(model, state, 1e-4, "semi_implicit_euler", backend="numba")


# ----------------------------------------------------------------------------- MuJoCo
def mujoco_prism_xml(model, state, dt, integrator):
    """MJCF of the free prism in configuration ``state`` (copy 0), written by the package's MJCF
    writer (:func:`tensegrity_gym.io.mjcf.to_mjcf`) for the structure with its nodes moved to that
    configuration: one free body per rod at its centre of mass, sites ``node<i>`` at the rod ends,
    one tension-only spatial tendon per string, contact disabled."""
    r, b = state.q[0, :, :3], state.q[0, :, 3:]
    nodes = np.array(model.structure.nodes, float)
    for j in range(model.n_bars):
        a, c, L, sig = int(model.rod_a[j]), int(model.rod_c[j]), float(model.length[j]), float(model.sigma[j])
        nodes[a], nodes[c] = r[j] - sig * L * b[j], r[j] + (1.0 - sig) * L * b[j]
    return to_mjcf(model.structure.replace(nodes=nodes), timestep=dt, integrator=integrator)


def mujoco_rows(sc, ref, dts, integrators=("Euler", "RK4")):
    import mujoco
    m, st, T, S = sc["model"], sc["state"], sc["T"], sc["n_rec"]
    _, nref, _ = ref
    rows = []
    for integ in integrators:
        for dt in dts:
            n = int(round(T / dt))
            every = n // S
            mm = mujoco.MjModel.from_xml_string(mujoco_prism_xml(m, st, dt, integ))
            d = mujoco.MjData(mm)
            site_node = [int(mm.site(i).name[len("node"):]) for i in range(mm.nsite)]
            for j in range(m.n_bars):
                rd, bd = st.qd[0, j, :3], st.qd[0, j, 3:]
                w = np.cross(st.q[0, j, 3:], bd)             # world angular velocity (b . b' = 0)
                adr = mm.jnt_dofadr[j]
                d.qvel[adr:adr + 3] = rd
                R = np.empty(9)
                mujoco.mju_quat2Mat(R, d.qpos[mm.jnt_qposadr[j] + 3: mm.jnt_qposadr[j] + 7])
                d.qvel[adr + 3:adr + 6] = R.reshape(3, 3).T @ w  # free joint: body-frame angular velocity
            mujoco.mj_forward(mm, d)
            nodes = np.empty((S + 1, m.n_nodes, 3))
            nodes[0][site_node] = d.site_xpos
            wall = 0.0
            ok = True
            for k in range(1, S + 1):
                t0 = time.perf_counter()
                mujoco.mj_step(mm, d, nstep=every)
                wall += time.perf_counter() - t0
                mujoco.mj_kinematics(mm, d)
                nodes[k][site_node] = d.site_xpos
                ok = ok and bool(np.all(np.isfinite(d.qpos)))
            pos = float(np.max(np.linalg.norm(nodes - nref, axis=-1))) if ok else np.inf
            rows.append(dict(scene="free_prism", integrator=f"mujoco_{integ.lower()}", backend="mujoco",
                             dt=dt, steps=n, status="ok" if ok else "diverged", warned=False,
                             pos_err=pos, energy_err=np.nan, rod_drift=0.0, wall_per_sim_s=wall / T,
                             us_per_step=wall / n * 1e6))
    return rows


# ----------------------------------------------------------------------------- feature costs
def _time_steps(model, state, integrator, backend, n=200, repeat=5):
    """Best-of-``repeat`` wall time of one step (us), stepping ``n`` steps in one call."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        step(model, state, 1e-3, integrator, backend=backend, n_steps=2)
        best = np.inf
        for _ in range(repeat):
            t0 = time.perf_counter()
            step(model, state, 1e-3, integrator, backend=backend, n_steps=n)
            best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def feature_costs(backends, quick):
    """Time one step of the 3-prism with each optional feature on, against the bare prism."""
    variants = {
        "bare": tg.prism(),
        "+gravity": tg.prism(gravity=(0.0, 0.0, -9.81)),
        "+damping": tg.prism(damping=5.0),
        "+constraints": tg.constrained_prism(gravity=None),
        "+all (gravity, damping, constraints)": tg.constrained_prism(damping=5.0),
    }
    rows = []
    n = 50 if quick else 200
    for B in ((1,) if quick else (1, 256)):
        for backend in backends:
            for integ in ("semi_implicit_euler", "rk4"):
                timers = {}
                for name, s in variants.items():
                    m = compile_model(s)
                    timers[name] = (lambda m=m, st=initial_state(m, batch_size=B):
                                    _time_steps(m, st, integ, backend, n=n, repeat=1))
                if _contact_available():
                    timers["+gravity +contact (contact_step)"] = (
                        lambda: _time_contact_steps(B, integ, backend, n=n, repeat=1))
                # interleaved rounds, best per variant: a shared machine's load drifts in time
                best = {k: np.inf for k in timers}
                for _ in range(3 if quick else 7):
                    for k, fn in timers.items():
                        best[k] = min(best[k], fn())
                for k, us in best.items():
                    rows.append(dict(feature=k, integrator=integ, backend=backend, batch=B,
                                     us_per_step=us, ratio_to_bare=us / best["bare"]))
    return rows


def _time_contact_steps(B, integrator, backend, n=200, repeat=5):
    """One step of the gravity prism standing on the ground with ``contact_step`` (us)."""
    from tensegrity_gym.physics.contact import GroundContact, init_contact_state
    from tensegrity_gym.physics.pipeline import contact_step
    s = tg.prism(gravity=(0.0, 0.0, -9.81))
    m = compile_model(s)
    nodes = s.nodes.copy()
    nodes[:, 2] += 0.02 - nodes[:, 2].min() - 1e-4       # caps 0.1 mm into the ground: contacts active
    st = initial_state(m, batch_size=B, nodes=nodes)
    c = GroundContact()
    cs = init_contact_state(m, B)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        contact_step(m, c, st, cs, 1e-3, integrator, n_steps=2, backend=backend)
        best = np.inf
        for _ in range(repeat):
            t0 = time.perf_counter()
            contact_step(m, c, st, cs, 1e-3, integrator, n_steps=n, backend=backend)
            best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


# ----------------------------------------------------------------------------- output
COLORS = {"semi_implicit_euler": "tab:blue", "rk4": "tab:green", "implicit_euler": "tab:red",
          "mujoco_euler": "tab:purple", "mujoco_rk4": "tab:brown"}
BACKEND_STYLE = {"numpy": ("-", "o"), "numba": (":", "s"), "mujoco": ("--", "D")}


def pareto_plot(rows, scene_names, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ncol = 3
    nrow = -(-len(scene_names) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(5.2 * ncol, 4.2 * nrow), squeeze=False)
    handles = {}
    for ax, scn in zip(axes.flat, scene_names):
        curves = {}
        for r in rows:
            if r["scene"] != scn or r["status"] != "ok" or not np.isfinite(r["pos_err"]):
                continue
            curves.setdefault((r["integrator"], r["backend"]), []).append(r)
        for (integ, backend), rs in sorted(curves.items()):
            rs = sorted(rs, key=lambda r: -r["dt"])
            x = [r["wall_per_sim_s"] for r in rs]
            y = [max(r["pos_err"], 1e-16) for r in rs]
            ls, mk = BACKEND_STYLE.get(backend, ("-", "x"))
            lab = f"{integ} ({backend})"
            h, = ax.loglog(x, y, ls=ls, marker=mk, color=COLORS.get(integ, "k"), label=lab, ms=4)
            handles[lab] = h
            ax.annotate(f"{rs[0]['dt']:g}", (x[0], y[0]), fontsize=6)
        ax.set_title(scn)
        ax.set_xlabel("wall s per simulated s (B = 1)")
        ax.set_ylabel("max node error (m)")
        ax.grid(True, which="major", alpha=0.3)
    for ax in list(axes.flat)[len(scene_names):]:
        ax.axis("off")
    last = list(axes.flat)[-1]
    last.legend(list(handles.values()), list(handles.keys()), loc="center", fontsize=8,
                title="integrator (backend)")
    fig.suptitle("speed-accuracy: node error vs DOP853 (rtol = atol = 1e-12; rolling_prism: vs "
                 "semi-implicit Euler at 5e-6 s) against cost; label = largest dt of each curve (s)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fmt(x, spec=".2e"):
    if isinstance(x, float) and not np.isfinite(x):
        return "inf" if x > 0 else "-"
    return format(x, spec)


def recommend(rows, backend="numba"):
    """Cheapest (integrator, dt) per scene whose node error is below 1 mm and energy error
    below 1 %, without a stability warning, among the rows of ``backend`` (the implicit
    method competes too); returns {scene: row}. (The NumPy formulation is the test
    oracle, not a backend: it has no rows.)"""
    best = {}
    for r in rows:
        if r["backend"] != backend:
            continue
        if r["status"] != "ok" or r["warned"]:
            continue
        if r["pos_err"] < 1e-3 and r["energy_err"] < 1e-2:
            b = best.get(r["scene"])
            if b is None or r["wall_per_sim_s"] < b["wall_per_sim_s"]:
                best[r["scene"]] = r
    return best


def write_markdown(path, rows, feats, scs, implicit_summary, cmd, elapsed):
    lines = ["# Speed-accuracy trade of the integrators", "",
             f"Generated by `{cmd}` ({elapsed:.0f} s on {platform.machine()} / {os.cpu_count()} cores, "
             "shared with other jobs: timings are indicative to ~30 %). Regenerate with:", "",
             "```", ".venv/bin/python -m scripts.figures.speed_accuracy", "```", "",
             "Outputs: `results/speed_accuracy.csv` (every row below), `results/speed_accuracy.png` "
             "(Pareto plot), `results/feature_costs.csv`.", "",
             "![speed-accuracy](../results/speed_accuracy.png)", "",
             "Errors are against `dop853` at rtol = atol = 1e-12 (`physics.simulate`), sampled at "
             "the record times: `pos_err` = largest node position error (m); `energy_err` = "
             "largest |E(t) - E_ref(t)| / |E_ref(0)| (E includes the prestress energy); "
             "`rod_drift` = largest | |b| - 1 | (rods are projected after every step, so this is "
             "round-off); status `unstable` = finite but node error > 1 km or energy error > 100 %; cost = wall-clock seconds per simulated second at B = 1 "
             "(`us/step` = microseconds per step). `warned` = the call raised a `StabilityWarning`.",
             ""]
    lines += ["## Scenes", ""]
    for n, sc in scs.items():
        lines.append(f"- **{n}** (T = {sc['T']:g} s): {sc['description']}; estimated explicit limits "
                     f"dt < {stability_limit(sc['model'])['semi_implicit_euler']:.3g} s (semi-implicit "
                     f"Euler), {stability_limit(sc['model'])['rk4']:.3g} s (RK4), "
                     f"omega_max = {stability_limit(sc['model'])['omega_max']:.4g} rad/s.")
    if not _contact_available():
        lines += ["- **rolling_prism with contact: TODO** - `tensegrity_gym/physics/contact.py` did not exist "
                  "when this was generated; no row is reported for it (no fake numbers). Rerun the "
                  "script once it exists."]
    lines += ["", "## Recommendation", ""]
    for backend in sorted({r["backend"] for r in rows} - {"mujoco"}):
        for scn, r in recommend(rows, backend).items():
            lines.append(f"- {scn}, {backend} backend: cheapest run with node error < 1 mm and energy "
                         f"error < 1 % and no `StabilityWarning`: `{r['integrator']}` at dt = {r['dt']:g} s "
                         f"({fmt(r['pos_err'])} m, {fmt(r['wall_per_sim_s'], '.3g')} s per simulated s).")
    lines += ["", RECOMMENDATION, ""]
    if "rolling_prism" in scs:
        lines += ["## Note on the rolling prism (contact)", "",
                  "Its errors stop falling at about 1e-3 m for dt <= 5e-4 s whatever the integrator. "
                  "Self-convergence of semi-implicit Euler with `contact_step` on this scene (largest "
                  "node distance at T to the dt = 5e-6 s run):", "",
                  "| dt (s) | node distance to dt = 5e-6 s (m) |", "|---|---|"]
        for dt, d in contact_self_convergence(scs["rolling_prism"]):
            lines.append(f"| {dt:g} | {d:.2e} |")
        lines += ["", "The discrete contact model (stick anchors set at touch-down, reset at lift-off, "
                  "with resting penetrations of only tens of micrometres so that string vibrations "
                  "make caps touch and leave) is sensitive to the step at the millimetre level: the "
                  "distances above do not fall steadily with dt. Below about 1e-3 m, the numbers on "
                  "this scene measure that sensitivity, not the integrators (reported to the contact "
                  "model's owner).", ""]
    lines += ["## Implicit Euler: damping and cost", "", implicit_summary, ""]
    for scn in scs:
        lines += [f"## {scn}", "", "| integrator | backend | dt (s) | status | warned | pos_err (m) | "
                  "energy_err | rod_drift | us/step | wall s / sim s |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            if r["scene"] != scn:
                continue
            lines.append(f"| {r['integrator']} | {r['backend']} | {r['dt']:g} | {r['status']} | "
                         f"{'yes' if r['warned'] else ''} | {fmt(r['pos_err'])} | {fmt(r['energy_err'])} | "
                         f"{fmt(r['rod_drift'])} | {fmt(r['us_per_step'], '.3g')} | "
                         f"{fmt(r['wall_per_sim_s'], '.3g')} |")
        lines.append("")
    lines += ["## What each optional feature costs per step", "",
              "One step of the 3-prism (dt = 1 ms), best of 7 interleaved runs of 200 steps; the bare prism has "
              "no gravity, no string damping and no node constraints. A model pays for a feature "
              "only when it has it (`Model.has_gravity`, `has_damping`, `constrained.any()`).", "",
              "| feature | integrator | backend | B | us/step | x bare |", "|---|---|---|---|---|---|"]
    for f in feats:
        lines.append(f"| {f['feature']} | {f['integrator']} | {f['backend']} | {f['batch']} | "
                     f"{f['us_per_step']:.3g} | {f['ratio_to_bare']:.2f} |")
    if not _contact_available():
        lines.append("")
        lines.append("Contact: **TODO** (`tensegrity_gym/physics/contact.py` absent when generated).")
    else:
        lines += ["", "`+gravity +contact`: the same prism with gravity standing on the ground "
                  "(`contact.GroundContact()` defaults, all three bottom caps in contact), stepped by "
                  "`contact_step` (contact forces once per step, then one `physics.step`); its ratio "
                  "is to the bare prism. Contact is a Python loop per step around the kernels, hence "
                  "its fixed cost of tens of microseconds with numba."]
    Path(path).write_text("\n".join(lines) + "\n")


RECOMMENDATION = """\
**Default for the envs: `semi_implicit_euler` at dt = 1 ms, numba backend** (what
`TensegrityShape-v0` and `TensegrityRoll-v0` use). Why, from the tables below: on the default
scenes (1e3 N/m strings, 0.2-1 kg rods; omega_max 80-250 rad/s, explicit limit 8-25 ms) the
cheapest runs under 1 mm node error and 1 % energy error are semi-implicit Euler at 2 ms and
RK4 at 5 ms (with numba within the timing noise of each other; the list above names whichever
measured cheaper in this run); for semi-implicit Euler 1 ms halves its error (about 1e-4 m after 0.5 s of a 0.3 m/s kick) for about 1 us per step with
numba, leaves a factor of 8 or more to the stability limit when actions stiffen the
structure, and stays under the contact limit of the rolling robot (about 2.5 ms,
`contact.stable_step`). Contact forces are held over a step, which is exact for
semi-implicit Euler and only first order for RK4. Its energy error is small and oscillates,
with a slow drift over very long runs (`docs/stability.md`, section 5). RK4 is the choice when
trajectories must be accurate to < 1e-6 m: at dt = 1 ms it is within 2e-7 m (free prism) and
2e-9 m (anchored prism) of the reference for 2-4x the cost per step. With stiff cables
(>= 1e5 N/m on ~0.1 kg rods: omega_max dt > 2 at 1 ms) the explicit methods diverge at 1 ms
(they warn first): either take the step that `StabilityWarning` names (0.2-0.5 ms for the
stiff prism: semi-implicit Euler at 0.2 ms is the cheapest accurate run there) or use
`implicit_euler`, stable at any dt, at the price of numerical damping of the fast string
vibrations and several times the NumPy cost of an explicit step (next section). Contact
forces stay explicit in `implicit_euler` (held over the step, not in its Jacobian), so the
contact stiffness still limits its step: on the rolling prism it is unstable at 2 ms. MuJoCo
(free prism, same axes): its Euler and RK4 land on exactly our errors at equal dt (the
same model and methods: a cross-check of both), at a higher cost per step than our numba
kernels in this run."""


IMPLICIT_DOC = """\
Implicit Euler damps every mode of frequency omega by the factor 1/sqrt(1 + (omega dt)^2) per
step (energy decays like exp(-omega^2 dt t) while omega dt << 1). Measured on the scenes
above (no physical damping there except `anchored_prism`), relative energy error after T:
{rows}
Newton: one linear solve per step in {smooth}; extra Newton iterations happen only when
strings switch slack/taut inside a step (see `docs/stability.md`)."""


def implicit_summary(rows):
    items = []
    for r in rows:
        if r["integrator"] == "implicit_euler" and r["backend"] == "numba" and r["dt"] in (1e-3, 2e-3, 1e-4):
            items.append(f"- {r['scene']}, dt = {r['dt']:g} s: energy error {fmt(r['energy_err'])}, "
                         f"node error {fmt(r['pos_err'])} m, {fmt(r['us_per_step'], '.3g')} us/step")
    expl = {}
    for r in rows:
        if r["integrator"] == "semi_implicit_euler" and r["backend"] == "numba" and r["status"] == "ok":
            expl.setdefault(r["scene"], []).append(r["us_per_step"])
    imp = {}
    for r in rows:
        if r["integrator"] == "implicit_euler" and r["backend"] == "numba" and r["status"] == "ok":
            imp.setdefault(r["scene"], []).append(r["us_per_step"])
    cost = [f"- cost per step {scn}: implicit_euler {np.median(imp[scn]):.3g} us vs semi_implicit_euler "
            f"{np.median(expl[scn]):.3g} us (numba, B = 1, median over dt): x{np.median(imp[scn]) / np.median(expl[scn]):.1f}"
            for scn in imp if scn in expl]
    return IMPLICIT_DOC.format(rows="\n".join(items), smooth="all the scenes above") + "\n\n" + "\n".join(cost)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="smoke run: fewer steps, short spans; docs untouched")
    ap.add_argument("--out", default=str(ROOT / "results"), help="output folder (CSV, PNG)")
    ap.add_argument("--docs", default=str(ROOT / "docs" / "speed_accuracy.md"), help="markdown output")
    ap.add_argument("--no-mujoco", action="store_true")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    out = Path(args.out) / "quick" if args.quick and args.out == str(ROOT / "results") else Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scs = scenes(args.quick)
    first = next(iter(scs.values()))
    warm_up(first["model"], first["state"])
    backends = ["numba"]   # the NumPy path is the test oracle (tests/oracle_numpy.py), not a backend
    rows = []
    for name, sc in scs.items():
        t0 = time.perf_counter()
        ref = reference(sc)
        print(f"{name}: reference in {time.perf_counter() - t0:.1f} s")
        for integ in FIXED:
            for dt in sc["dts"][integ]:
                for backend in backends:
                    r = run_one(sc, ref, integ, dt, backend)
                    r["scene"] = name
                    rows.append(r)
                    print(f"  {integ:20s} {backend:6s} dt={dt:<8g} {r['status']:9s} "
                          f"{'W' if r['warned'] else ' '} pos={fmt(r['pos_err'])} E={fmt(r['energy_err'])} "
                          f"rod={fmt(r['rod_drift'])} {fmt(r['us_per_step'], '8.3g')} us/step "
                          f"{fmt(r['wall_per_sim_s'], '.3g')} s/sim-s", flush=True)
        if name == "free_prism" and not args.no_mujoco:
            try:
                mrows = mujoco_rows(sc, ref, sc["dts"]["semi_implicit_euler"])
            except ImportError as e:
                print(f"  mujoco not available: {e}")
                mrows = []
            for r in mrows:
                rows.append(r)
                print(f"  {r['integrator']:20s} mujoco dt={r['dt']:<8g} {r['status']:9s}  pos={fmt(r['pos_err'])} "
                      f"{fmt(r['us_per_step'], '8.3g')} us/step {fmt(r['wall_per_sim_s'], '.3g')} s/sim-s",
                      flush=True)
    keys = ["scene", "integrator", "backend", "dt", "steps", "status", "warned", "pos_err", "energy_err",
            "rod_drift", "us_per_step", "wall_per_sim_s"]
    with open(out / "speed_accuracy.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: r[k] for k in keys})
    pareto_plot(rows, list(scs), out / "speed_accuracy.png")
    print("feature costs (us per step):")
    feats = feature_costs(backends, args.quick)
    for f in feats:
        print(f"  {f['feature']:38s} {f['integrator']:20s} {f['backend']:6s} B={f['batch']:<5d} "
              f"{f['us_per_step']:9.3g} us  x{f['ratio_to_bare']:.2f}")
    with open(out / "feature_costs.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(feats[0]))
        w.writeheader()
        w.writerows(feats)
    for backend in backends:
        for scn, r in recommend(rows, backend).items():
            print(f"cheapest < 1 mm, < 1 % energy, {backend:5s} {scn}: {r['integrator']} dt={r['dt']:g} "
                  f"({fmt(r['pos_err'])} m, {fmt(r['wall_per_sim_s'], '.3g')} s/sim-s)")
    elapsed = time.perf_counter() - t_start
    if not args.quick:
        cmd = "scripts/figures/speed_accuracy.py"
        write_markdown(args.docs, rows, feats, scs, implicit_summary(rows), cmd, elapsed)
        print(f"wrote {args.docs}")
    print(f"wrote {out / 'speed_accuracy.csv'}, {out / 'speed_accuracy.png'}, {out / 'feature_costs.csv'} "
          f"in {elapsed:.0f} s")


if __name__ == "__main__":
    main()
