"""Ground-contact validation figures and numbers (tensegrity_gym.physics.contact), SI units.

Writes PNG figures and ``results/contact/contact.json`` (the numbers quoted in docs/contact.md):

1. ``sliding.png``   -- a rod lying flat, launched at v0: speed vs time against v0 - mu g t;
                        measured deceleration / (mu g), stopping distance / (v0^2 / 2 mu g).
2. ``slope.png``     -- a flat rod on slopes of atan(mu) +- 5 deg (gravity tilted): slides with
                        g (sin - mu cos) above, stays below.
3. ``creep.png``     -- the prestressed 3-bar prism (the TensegrityRoll-v0 robot's rods and strings,
                        standing on its bottom face) resting under gravity: horizontal displacement of
                        its caps over 10 s after 1 s of settling (requirement: < 1 mm).
4. ``drop.png``      -- the prism dropped from 5 cm: penetration and total energy (mechanical +
                        contact springs) vs time at dt = 1 ms and 0.25 ms.
5. stable time step  -- estimate (contact.stable_step) and the measured largest stable dt of the
                        resting prism (2 s at each dt in a sweep).

Run: ``python -m scripts.figures.contact_figures`` (about a minute on one core).
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

import matplotlib  # noqa: E402
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from tensegrity_gym.core import builders  # noqa: E402
from tensegrity_gym.core.model import compile_model, initial_state  # noqa: E402
from tensegrity_gym.physics.contact import GroundContact, contact_energy, init_contact_state, stable_step  # noqa: E402
from tensegrity_gym.physics.pipeline import contact_step  # noqa: E402
from tensegrity_gym.physics.geometry import center_of_mass, energy, linear_momentum, node_positions  # noqa: E402
from tensegrity_gym.core.structure import Structure  # noqa: E402

G = 9.81
OUT = ROOT / "results" / "contact"


def flat_rod(v0=0.0, gravity=(0.0, 0.0, -G), length=0.4, mass=0.2, radius=0.02):
    s = Structure([[0, 0, radius], [length, 0, radius]], [[0, 1]], np.zeros((0, 2), int), bar_mass=mass,
                  gravity=gravity, velocities=[[v0, 0, 0], [v0, 0, 0]])
    return compile_model(s)


def prism(drop=0.0):
    s = builders.prism(3, radius=0.15, height=0.25, bar_mass=0.2, stiffness=1000.0, prestress=20.0, damping=2.0,
                       gravity=(0.0, 0.0, -G))
    nodes = s.nodes.copy()
    nodes[:, 2] += 0.02 + drop
    return compile_model(s.replace(nodes=nodes))


def simulate(model, contact, T, dt=1e-3, record=None):
    st = initial_state(model, 1)
    cs = init_contact_state(model, 1)
    rec = []
    for i in range(int(round(T / dt))):
        if record is not None:
            rec.append(record(st, cs))
        st, cs = contact_step(model, contact, st, cs, dt)
    if record is not None:
        rec.append(record(st, cs))
    return st, cs, rec


def sliding(res):
    mu = 0.5
    c = GroundContact(friction=mu)
    fig, ax = plt.subplots(figsize=(5, 3.4))
    out = []
    for v0 in (0.5, 1.0, 2.0):
        m = flat_rod(v0)
        T = v0 / (mu * G) + 0.3
        _, _, rec = simulate(m, c, T, record=lambda st, cs: (st.t, center_of_mass(m, st.q)[0, 0],
                                                             linear_momentum(m, st.qd)[0, 0] / 0.2))
        t, x, v = (np.array(a) for a in zip(*rec))
        sel = (v < 0.8 * v0) & (v > 0.2 * v0)
        a = -np.polyfit(t[sel], v[sel], 1)[0]
        d = x[-1] - x[0]
        d_th = v0 ** 2 / (2 * mu * G)
        out.append({"v0_m_s": v0, "deceleration_m_s2": a, "mu_g_m_s2": mu * G, "rel_error": a / (mu * G) - 1,
                    "stop_distance_m": d, "theory_m": d_th, "stop_rel_error": d / d_th - 1,
                    "final_speed_m_s": float(abs(v[-1]))})
        ax.plot(t, v, label=f"v0 = {v0} m/s")
        ax.plot(t, np.maximum(v0 - mu * G * t, 0), "k:", lw=0.8)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("speed (m/s)")
    ax.set_title(f"flat rod sliding, mu = {mu} (dotted: v0 - mu g t)", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / "sliding.png", dpi=120)
    plt.close(fig)
    res["sliding"] = out


def slope(res):
    mu = 0.5
    c = GroundContact(friction=mu)
    crit = math.atan(mu)
    fig, ax = plt.subplots(figsize=(5, 3.4))
    out = []
    for dtheta in (+5.0, +1.0, -1.0, -5.0):
        th = crit + math.radians(dtheta)
        m = flat_rod(0.0, gravity=(G * math.sin(th), 0.0, -G * math.cos(th)))
        _, _, rec = simulate(m, c, 1.0, record=lambda st, cs: (st.t, center_of_mass(m, st.q)[0, 0],
                                                               linear_momentum(m, st.qd)[0, 0] / 0.2))
        t, x, v = (np.array(a) for a in zip(*rec))
        a_th = max(G * (math.sin(th) - mu * math.cos(th)), 0.0)
        sel = t > 0.2
        a = float(np.polyfit(t[sel], v[sel], 1)[0])
        out.append({"slope_deg": math.degrees(th), "atan_mu_deg": math.degrees(crit),
                    "displacement_1s_m": float(x[-1] - x[0]), "acceleration_m_s2": a, "theory_m_s2": a_th})
        ax.plot(t, (x - x[0]) * 1e3, label=f"atan(mu) {dtheta:+.0f} deg")
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("displacement down the slope (mm)")
    ax.set_title(f"flat rod on a slope, mu = {mu}, atan(mu) = {math.degrees(crit):.2f} deg", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / "slope.png", dpi=120)
    plt.close(fig)
    res["slope"] = out


def creep(res):
    m = prism()
    c = GroundContact()
    st, cs, _ = simulate(m, c, 1.0)
    n0 = node_positions(m, st.q)[0]
    t0 = st.t
    rec = []
    st2 = st
    cs2 = cs
    for i in range(10000):
        if i % 10 == 0:
            rec.append((st2.t - t0, node_positions(m, st2.q)[0]))
        st2, cs2 = contact_step(m, c, st2, cs2, 1e-3)
    rec.append((st2.t - t0, node_positions(m, st2.q)[0]))
    t = np.array([r[0] for r in rec])
    N = np.array([r[1] for r in rec])
    disp = np.linalg.norm(N[:, :, :2] - n0[None, :, :2], axis=-1)   # (T, n)
    fig, ax = plt.subplots(figsize=(5, 3.4))
    for i in range(3):
        ax.plot(t, disp[:, i] * 1e3, label=f"cap of node {i} (on the ground)")
    ax.axhline(1.0, color="r", ls="--", lw=0.8, label="1 mm requirement")
    ax.set_yscale("symlog", linthresh=1e-4)
    ax.set_xlabel("t after 1 s of settling (s)")
    ax.set_ylabel("horizontal displacement (mm)")
    ax.set_title("prestressed prism resting under gravity", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / "creep.png", dpi=120)
    plt.close(fig)
    com0 = center_of_mass(m, st.q)[0]
    com1 = center_of_mass(m, st2.q)[0]
    res["creep"] = {"duration_s": 10.0, "max_cap_horizontal_displacement_m": float(disp[:, :3].max()),
                    "max_node_displacement_m": float(np.linalg.norm(N - n0[None], axis=-1).max()),
                    "com_horizontal_drift_m": float(np.linalg.norm(com1[:2] - com0[:2])),
                    "rest_penetration_m": float(c.radius - n0[:3, 2].min()),
                    "contacts_active": int(cs2.active.sum())}


def drop(res):
    fig, axs = plt.subplots(1, 2, figsize=(8, 3.2))
    out = {}
    for dt in (1e-3, 2.5e-4):
        m = prism(drop=0.05)
        c = GroundContact()

        def rec(st, cs):
            return (st.t, c.radius - node_positions(m, st.q)[0, :, 2].min(),
                    energy(m, st.q, st.qd)[0] + contact_energy(c, m, st.q, cs)[0])
        _, _, r = simulate(m, c, 1.0, dt=dt, record=rec)
        t, pen, E = (np.array(a) for a in zip(*r))
        excess = E - np.minimum.accumulate(E)
        out[f"dt_{dt:g}"] = {"max_penetration_m": float(pen.max()), "final_penetration_m": float(pen[-1]),
                             "E0_J": float(E[0]), "E_end_J": float(E[-1]),
                             "max_energy_rise_above_running_min_J": float(excess.max()),
                             "max_energy_rise_rel": float(excess.max() / E[0])}
        axs[0].plot(t, np.maximum(pen, 0.0) * 1e3, label=f"dt = {dt * 1e3:g} ms")
        axs[1].plot(t, E, label=f"dt = {dt * 1e3:g} ms")
    axs[0].set_xlabel("t (s)")
    axs[0].set_ylabel("largest cap penetration (mm; 0 = in the air)")
    axs[1].set_xlabel("t (s)")
    axs[1].set_ylabel("total energy incl. contact springs (J)")
    for a in axs:
        a.legend(fontsize=8)
    fig.suptitle("prism dropped from 5 cm (k = 1e4 N/m, Hunt-Crossley d = 10 s/m)", fontsize=9)
    fig.tight_layout()
    fig.savefig(OUT / "drop.png", dpi=120)
    plt.close(fig)
    res["drop"] = out


def stable_dt(res):
    m = prism(drop=0.01)
    c = GroundContact()
    est = stable_step(c, m)
    sweep = {}
    for dt in (1e-3, 2e-3, 3e-3, 3.5e-3, 4e-3, 5e-3):
        with np.errstate(all="ignore"):
            import warnings
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                st, cs, _ = simulate(m, c, 2.0, dt=dt)
        N = node_positions(m, st.q)[0]
        ok = bool(np.all(np.isfinite(N)) and np.abs(N).max() < 2.0 and N[:, 2].min() > 0.0)
        sweep[f"{dt:g}"] = ok
    res["stable_step"] = {"estimate": est, "resting_prism_2s_stable": sweep,
                          "largest_stable_in_sweep_s": max([float(k) for k, v in sweep.items() if v], default=None)}


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    res = {"contact_defaults": {k: getattr(GroundContact(), k) for k in
                                ("stiffness", "damping", "exponent", "friction", "tangential_stiffness",
                                 "tangential_damping", "radius")},
           "dt_s": 1e-3, "integrator": "semi_implicit_euler"}
    t0 = time.time()
    for f in (sliding, slope, creep, drop, stable_dt):
        f(res)
        print(f"{f.__name__}: done ({time.time() - t0:.0f} s)", flush=True)
    (OUT / "contact.json").write_text(json.dumps(res, indent=2, default=float))
    print(json.dumps(res, indent=2, default=float))


if __name__ == "__main__":
    main()
