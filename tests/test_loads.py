"""Member loads (physics.loads): rod compression against statics, a spinning rod's tension and the
momentum balance of half a rod under the project's own accelerations; member capacities."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tensegrity_gym.core.builders import load_structure, prism
from tensegrity_gym.core.model import compile_model, initial_state
from tensegrity_gym.core.structure import Structure
from tensegrity_gym.physics.evaluate import accelerations, string_forces
from tensegrity_gym.physics.loads import MATERIALS, RodSection, member_loads, overload


def test_prestressed_prism_at_rest_rods_carry_what_their_strings_pull():
    s = prism(3)     # no gravity: a self-stressed equilibrium
    m = compile_model(s)
    st = initial_state(m)
    ld = member_loads(m, st.q, st.qd)
    gamma, L, F = string_forces(m, st.q, st.qd)
    # statics: the strings pulling at a rod's end c, along the rod's axis, is its compression
    b = st.q[0, :, 3:]
    fc = F[0, m.rod_c]
    np.testing.assert_allclose(ld["rod_compression"][0], -np.einsum("ki,ki->k", fc, b), rtol=1e-6)
    assert np.all(ld["rod_compression"] > 0) and np.all(ld["string_tension"] >= 0)
    np.testing.assert_allclose(ld["string_tension"], gamma * L)


def _free_rod(mass=0.3, length=0.5):
    return Structure(nodes=np.array([[0.0, 0, 0], [length, 0, 0]]), bars=np.array([[0, 1]]),
                     strings=np.zeros((0, 2), int), stiffness=np.zeros(0), rest_length=np.zeros(0), bar_mass=mass)


def test_spinning_rod_is_in_tension_m_l_omega2_over_8():
    s = _free_rod()
    m = compile_model(s)
    st = initial_state(m)
    qd = st.qd.copy()
    w = 7.0
    qd[0, 0, 3:] = [0.0, w, 0.0]      # b' = omega x b, |b'| = omega
    ld = member_loads(m, st.q, qd)
    assert ld["rod_compression"][0, 0] == pytest.approx(-0.3 * 0.5 * w * w / 8, rel=1e-12)


def test_half_rod_momentum_balance_under_the_dynamics():
    """The formula against the half rod's momentum along its axis, integrated from the
    accelerations the dynamics give (r'', b''), with arbitrary end forces and spin."""
    s = _free_rod(mass=0.4, length=0.6)
    m = compile_model(s)
    rng = np.random.default_rng(1)
    st = initial_state(m)
    b = rng.standard_normal(3)
    b /= np.linalg.norm(b)
    q = st.q.copy()
    q[0, 0, 3:] = b
    qd = np.zeros_like(q)
    qd[0, 0, :3] = rng.standard_normal(3)
    w = rng.standard_normal(3)
    qd[0, 0, 3:] = np.cross(w, b)
    ext = rng.standard_normal((1, 2, 3)) * 5
    a = accelerations(m, q, qd, external=ext)[0, 0]
    rdd, bdd = a[:3], a[3:]
    lam, l = 0.4 / 0.6, 0.6
    s_ = np.linspace(0, l / 2, 20001)
    axial = lam * np.trapezoid(rdd @ b + s_ * (bdd @ b), s_)       # half rod: integral of rho a . b
    fc = ext[0, m.rod_c[0]]
    expect = axial - fc @ b
    got = member_loads(m, q, qd, external=ext)["rod_compression"][0, 0]
    assert got == pytest.approx(expect, rel=1e-6, abs=1e-9)


def test_tube_capacity_and_overload():
    al = RodSection.of("aluminium_6061_t6", 0.01, 0.001)
    ti = RodSection.of("titanium_ti6al4v", 0.01, 0.001)
    E, sy = MATERIALS["aluminium_6061_t6"][:2]
    I = math.pi / 64 * (0.01 ** 4 - 0.008 ** 4)
    assert al.capacity(0.5) == pytest.approx(min(math.pi ** 2 * E * I / 0.25, sy * al.area))
    assert ti.capacity(0.5) > al.capacity(0.5)
    loads = {"rod_compression": np.array([[10.0, 2000.0]]), "string_tension": np.array([[5.0]])}
    o = overload(loads, rod_capacity=al.capacity([0.5, 0.5]), string_capacity=100.0)
    assert o["member_overload"].tolist() == [True] and o["rod_load_ratio"][0, 0] < 1 < o["rod_load_ratio"][0, 1]
    for bad, msg in ((dict(outer_diameter=-1.0), "outer_diameter"), (dict(wall=0.02), "wall"),
                     (dict(youngs_modulus=float("nan")), "youngs_modulus")):
        kw = dict(outer_diameter=0.01, wall=0.001, youngs_modulus=E, yield_stress=sy) | bad
        with pytest.raises(ValueError, match=msg):
            RodSection(**kw)
    with pytest.raises(ValueError, match="material: unknown 'wood'"):
        RodSection.of("wood", 0.01, 0.001)


def test_drop_records_peak_loads():
    from tensegrity_gym.core.terrain import Terrain
    from tensegrity_gym.tools.drops import drop
    r = drop(load_structure("prism_robot"), Terrain(), 1.0, after=0.3, record_every=1, loads=True)
    i = int(np.argmax(r.contact_force))
    assert r.contact_force[i] > 20 * r.contact_force[0] + 1.0      # the impact
    assert r.rod_compression.max() > r.rod_compression[0]


def test_cli_simulate_loads(tmp_path):
    import subprocess
    import sys
    out = tmp_path / "l.npz"
    p = subprocess.run([sys.executable, "-m", "tensegrity_gym", "simulate", "prism_robot", "--ground", "--loads",
                        "--duration", "0.2", "--integrator", "semi_implicit_euler", "--record-every", "10",
                        "--no-progress", "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    assert "peak string tension" in p.stdout and "peak rod compression" in p.stdout
    z = np.load(out)
    S = z["t"].shape[0]
    assert z["string_tension"].shape == (S, 9) and z["rod_compression"].shape == (S, 3)
    assert np.all(z["rod_compression"] > 0)      # the prestressed robot's rods are in compression
    # without --loads the output is as before
    p = subprocess.run([sys.executable, "-m", "tensegrity_gym", "simulate", "prism_robot", "--ground", "--duration",
                        "0.05", "--no-progress", "--out", str(tmp_path / "n.npz")], capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0 and "string_tension" not in np.load(tmp_path / "n.npz")
