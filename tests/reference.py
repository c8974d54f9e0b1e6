"""Independent reference simulation of a class-1 tensegrity in node coordinates.

This module shares no code with :mod:`tensegrity_gym.physics`: it reads only the
data of a :class:`tensegrity_gym.core.structure.Structure` (nodes, bars, strings, masses,
mass points, stiffness, rest lengths, damping, gravity, node constraints) and
formulates the mechanics from scratch, in SI units (m, kg, s, N).

Formulation
-----------
* State: positions ``x`` (k, 2, 3) and velocities ``v`` (k, 2, 3) of the two end nodes
  ``(a, c)`` of every rod (anchors are fixed and not part of the state).
* A point of rod j at fraction ``mu`` from node a is ``(1 - mu) x_a + mu x_c``, so the
  kinetic energy ``1/2 int |v(mu)|^2 dm`` gives the *consistent* mass matrix
  ``M_j = sum_k m_k [[(1-mu_k)^2, (1-mu_k) mu_k], [(1-mu_k) mu_k, mu_k^2]] (x) I_3``
  for lumped masses and ``m/6 [[2 I, I], [I, 2 I]]`` for a uniform rod (the integral of the same).
  A thin rod has no inertia about its own axis, exactly like the 5-DOF rod model.
* Gravity: consistent nodal loads ``g int (1 - mu) dm`` at a and ``g int mu dm`` at c.
* Strings: tension-only, ``T = max(0, k (L - l0) + c dL/dt)`` while ``L > l0``, else 0;
  the force on the string's first node i is ``+T s/L`` with ``s = x_j - x_i``.
* Holonomic constraints held by Lagrange multipliers:
  rod lengths ``|x_c - x_a|^2 - l^2 = 0`` and node constraints ``D (x - x0) = 0``.
  At every evaluation the KKT system ``[[M, G^T], [G, 0]] [a; lambda] = [F; -Gdot v - 2 alpha C' - beta^2 C]``
  is solved (index-1 form with Baumgarte stabilisation; on the exact solution
  ``C = C' = 0`` so the stabilisation terms vanish).
* Integration: ``scipy.integrate.solve_ivp`` with DOP853, rtol = atol = 1e-12.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

__all__ = ["NodeReference", "rod_mass_matrix", "rigid_perturbation"]


def rod_mass_matrix(mass: float, mass_points=None) -> np.ndarray:
    """2x2 coefficients of the consistent mass matrix of one rod in its end nodes
    (to be multiplied by I_3), and the 2 coefficients of its gravity loads.
    Returns ``(Mc (2, 2), gw (2,))``: ``M = Mc (x) I_3`` (kg), nodal weight fractions (kg)."""
    if mass_points is None:
        Mc = mass / 6.0 * np.array([[2.0, 1.0], [1.0, 2.0]])
        gw = np.array([mass / 2.0, mass / 2.0])
    else:
        Mc = np.zeros((2, 2))
        gw = np.zeros(2)
        for mu, mk in mass_points:
            phi = np.array([1.0 - mu, mu])
            Mc += mk * np.outer(phi, phi)
            gw += mk * phi
    return Mc, gw


class NodeReference:
    """Node-coordinate DAE of a structure (see the module docstring).

    Parameters
    ----------
    structure : tensegrity_gym Structure (only its data is read).
    baumgarte : (alpha, beta) in 1/s for the constraint stabilisation.
    rest_length : (m,) rest lengths overriding the structure's, m.
    force_density : (m,) force densities added by a controller, N/m: the string's force
        density becomes ``max(0, T/L + u)`` (a cable cannot push).
    external : (n, 3) constant external nodal forces, N (on anchors: ignored).
    """

    def __init__(self, structure, baumgarte=(20.0, 20.0), rest_length=None, force_density=None,
                 external=None):
        s = structure
        self.s = s
        nodes = np.array(s.nodes, float)
        bars = np.array(s.bars, int)
        strings = np.array(s.strings, int)
        self.k = k = len(bars)
        self.n = n = len(nodes)
        self.bars = bars
        self.length = np.linalg.norm(nodes[bars[:, 1]] - nodes[bars[:, 0]], axis=1)
        # slot of each rod node in the flat state x (k*2, 3): rod j node a -> 2j, node c -> 2j+1
        self.slot = -np.ones(n, int)
        self.slot[bars[:, 0]] = 2 * np.arange(k)
        self.slot[bars[:, 1]] = 2 * np.arange(k) + 1
        self.anchor = np.flatnonzero(self.slot < 0)
        self.anchor_pos = nodes[self.anchor].copy()
        # mass matrix (6k, 6k) and gravity loads (2k, 3)
        mp = s.mass_points if s.mass_points is not None else (None,) * k
        M = np.zeros((6 * k, 6 * k))
        self.Wg = np.zeros((2 * k, 3))
        g = np.zeros(3) if s.gravity is None else np.array(s.gravity, float)
        for j in range(k):
            Mc, gw = rod_mass_matrix(float(s.bar_mass[j]), mp[j])
            M[6 * j:6 * j + 6, 6 * j:6 * j + 6] = np.kron(Mc, np.eye(3))
            self.Wg[2 * j] = gw[0] * g
            self.Wg[2 * j + 1] = gw[1] * g
        self.M = M
        if external is not None:
            ext = np.asarray(external, float)
            for node in range(n):
                if self.slot[node] >= 0:
                    self.Wg[self.slot[node]] += ext[node]
        self.Mc = [M[6 * j:6 * j + 6:3, 6 * j:6 * j + 6:3] for j in range(k)]
        # strings
        self.si, self.sj = strings[:, 0], strings[:, 1]
        self.kst = np.array(s.stiffness, float)
        self.l0 = np.array(s.rest_length if rest_length is None else rest_length, float)
        self.u = None if force_density is None else np.array(force_density, float)
        self.cst = np.array(s.damping, float)
        # node constraints: rows acting on a node slot, D x = D x0
        self.node_cons = []
        for node, D in s.node_constraints.items():
            D = np.array(D, float)
            self.node_cons.append((int(self.slot[int(node)]), D, D @ nodes[int(node)]))
        self.n_cons = k + sum(D.shape[0] for _, D, _ in self.node_cons)
        self.alpha, self.beta = baumgarte
        self.nfev = 0
        # string incidence onto rod-node slots (anchors dropped: they take no force)
        m = len(strings)
        self.Cslot = np.zeros((2 * k, m))
        for i, (a, b) in enumerate(strings):
            if self.slot[a] >= 0:
                self.Cslot[self.slot[a], i] += 1.0     # node i of the string pulled along +s
            if self.slot[b] >= 0:
                self.Cslot[self.slot[b], i] -= 1.0
        self.rod_nodes = np.flatnonzero(self.slot >= 0)
        # constant part of the KKT matrix: mass matrix and node-constraint rows
        nc = self.n_cons
        self.K0 = np.zeros((6 * k + nc, 6 * k + nc))
        self.K0[:6 * k, :6 * k] = M
        row = 6 * k + k
        for slot, D, c0 in self.node_cons:
            p = D.shape[0]
            self.K0[row:row + p, 3 * slot:3 * slot + 3] = D
            self.K0[3 * slot:3 * slot + 3, row:row + p] = D.T
            row += p
        self._ia = (6 * np.arange(k)[:, None] + np.arange(3)[None, :])     # (k, 3) columns of node a
        self._ic = self._ia + 3

    # ------------------------------------------------------------------ kinematics
    def split(self, y):
        """Flat state -> positions (2k, 3), velocities (2k, 3)."""
        h = 6 * self.k
        return y[:h].reshape(2 * self.k, 3), y[h:].reshape(2 * self.k, 3)

    def all_nodes(self, x):
        """(n, 3) positions of every node (rod nodes from x, anchors fixed)."""
        N = np.empty((self.n, 3))
        N[self.rod_nodes] = x[self.slot[self.rod_nodes]]
        N[self.anchor] = self.anchor_pos
        return N

    def all_velocities(self, v):
        V = np.zeros((self.n, 3))
        V[self.rod_nodes] = v[self.slot[self.rod_nodes]]
        return V

    def state_from_nodes(self, nodes, velocities):
        """Flat state from (n, 3) node positions and velocities."""
        x = np.empty((2 * self.k, 3))
        v = np.empty((2 * self.k, 3))
        x[0::2] = nodes[self.bars[:, 0]]
        x[1::2] = nodes[self.bars[:, 1]]
        v[0::2] = velocities[self.bars[:, 0]]
        v[1::2] = velocities[self.bars[:, 1]]
        return np.concatenate([x.ravel(), v.ravel()])

    # ------------------------------------------------------------------ forces
    def string_tensions(self, N, V):
        """(m,) string tensions, N (tension only)."""
        S = N[self.sj] - N[self.si]
        L = np.linalg.norm(S, axis=1)
        Ld = np.einsum("mi,mi->m", S, V[self.sj] - V[self.si]) / L
        T = self.kst * (L - self.l0) + self.cst * Ld
        return np.where(L > self.l0, np.maximum(T, 0.0), 0.0), S, L

    def nodal_forces(self, x, v):
        """(2k, 3) forces on the rod nodes: strings + gravity, N."""
        N, V = self.all_nodes(x), self.all_velocities(v)
        T, S, L = self.string_tensions(N, V)
        gamma = T / L
        if self.u is not None:
            gamma = np.maximum(gamma + self.u, 0.0)
        return self.Cslot @ (gamma[:, None] * S) + self.Wg

    # ------------------------------------------------------------------ KKT
    def accelerations(self, x, v):
        """(2k, 3) node accelerations and the multipliers, from the KKT system."""
        k = self.k
        d = x[1::2] - x[0::2]
        dv = v[1::2] - v[0::2]
        al, be = self.alpha, self.beta
        K = self.K0.copy()
        rows = 6 * k + np.arange(k)
        # rod-length rows: d/dt^2 |x_c - x_a|^2 = 2 d.(a_c - a_a) + 2 |dv|^2
        K[rows[:, None], self._ia] = -2.0 * d
        K[rows[:, None], self._ic] = 2.0 * d
        K[self._ia, rows[:, None]] = -2.0 * d
        K[self._ic, rows[:, None]] = 2.0 * d
        C = np.einsum("ki,ki->k", d, d) - self.length ** 2
        Cd = 2.0 * np.einsum("ki,ki->k", d, dv)
        rhs = [-2.0 * np.einsum("ki,ki->k", dv, dv) - 2.0 * al * Cd - be * be * C]
        for slot, D, c0 in self.node_cons:
            rhs.append(-2.0 * al * (D @ v[slot]) - be * be * (D @ x[slot] - c0))
        F = self.nodal_forces(x, v).ravel()
        sol = np.linalg.solve(K, np.concatenate([F] + rhs))
        return sol[:6 * k].reshape(2 * k, 3), sol[6 * k:]

    def rhs(self, t, y):
        self.nfev += 1
        x, v = self.split(y)
        a, _ = self.accelerations(x, v)
        return np.concatenate([v.ravel(), a.ravel()])

    def node_accelerations(self, nodes, velocities):
        """(n, 3) node accelerations (anchors 0) at given node positions/velocities."""
        y = self.state_from_nodes(nodes, velocities)
        x, v = self.split(y)
        a, _ = self.accelerations(x, v)
        return self.all_velocities(a)

    def simulate(self, nodes, velocities, t_eval, rtol=1e-12, atol=1e-12):
        """Integrate from (n, 3) ``nodes``/``velocities`` at t_eval[0]; returns node positions
        (S, n, 3) and velocities (S, n, 3) at ``t_eval`` (s)."""
        y0 = self.state_from_nodes(np.asarray(nodes, float), np.asarray(velocities, float))
        t_eval = np.asarray(t_eval, float)
        sol = solve_ivp(self.rhs, (t_eval[0], t_eval[-1]), y0, method="DOP853", rtol=rtol, atol=atol,
                        t_eval=t_eval)
        if sol.status != 0:
            raise RuntimeError(f"reference integration failed: {sol.message}")
        X = np.stack([self.all_nodes(self.split(y)[0]) for y in sol.y.T])
        V = np.stack([self.all_velocities(self.split(y)[1]) for y in sol.y.T])
        return X, V

    # ------------------------------------------------------------------ invariants
    def momenta(self, nodes, velocities, about=None):
        """Linear momentum (3,) and angular momentum (3,) about ``about`` (default the
        centre of mass) from node data and the consistent mass matrices, SI units."""
        about_com = about is None
        p = np.zeros(3)
        mass = 0.0
        mx = np.zeros(3)
        for j, (a, c) in enumerate(self.bars):
            Mc = self.Mc[j]
            X = np.stack([nodes[a], nodes[c]])
            V = np.stack([velocities[a], velocities[c]])
            p += (Mc @ V).sum(axis=0)
            mx += (Mc @ X).sum(axis=0)
            mass += Mc.sum()
        o = mx / mass if about_com else np.asarray(about, float)
        Lm = np.zeros(3)
        for j, (a, c) in enumerate(self.bars):
            Mc = self.Mc[j]
            X = np.stack([nodes[a], nodes[c]]) - o
            V = np.stack([velocities[a], velocities[c]])
            for i in range(2):
                for l in range(2):
                    Lm += Mc[i, l] * np.cross(X[i], V[l])
        return p, Lm

    def energy(self, nodes, velocities):
        """Kinetic + string potential + potential of the constant nodal loads (gravity and
        ``external``), J, from node data (n, 3)."""
        E = 0.0
        for j, (a, c) in enumerate(self.bars):
            V = np.stack([velocities[a], velocities[c]])
            E += 0.5 * np.sum(V * (self.Mc[j] @ V))
        S = nodes[self.sj] - nodes[self.si]
        L = np.linalg.norm(S, axis=1)
        E += 0.5 * np.sum(self.kst * np.maximum(L - self.l0, 0.0) ** 2)
        x = self.state_from_nodes(nodes, velocities)[:6 * self.k].reshape(2 * self.k, 3)
        E -= np.sum(self.Wg * x)
        return E


def rigid_perturbation(structure, rng, pos=0.02, rot=0.05, vel=0.2, omega=1.0, pivot=None):
    """Random rod-wise rigid perturbation of a structure's nodes and a consistent
    random velocity field.

    Every rod is rotated by a random angle up to ``rot`` rad about a random axis
    through its pivot (its midpoint, or its constrained node, which is kept on its
    constraint) and translated by up to ``pos`` m (constrained rods: only along the
    constraint's null space); velocities are a random rigid motion per rod (linear
    part up to ``vel`` m/s, angular up to ``omega`` rad/s), tangent to the constraints.
    Rod lengths and constraints hold exactly. Returns ``(nodes (n, 3), velocities (n, 3))``.
    """
    nodes = np.array(structure.nodes, float)
    vels = np.zeros_like(nodes)
    cons = structure.node_constraints
    for a, c in structure.bars:
        ca = cn = None
        if a in cons:
            ca, cn = a, a
        elif c in cons:
            ca, cn = c, c
        if ca is None:
            center = 0.5 * (nodes[a] + nodes[c])
            allowed = np.eye(3)
        else:
            center = nodes[ca].copy()
            D = np.array(cons[cn], float)
            allowed = np.eye(3) - D.T @ np.linalg.solve(D @ D.T, D)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        ang = rot * rng.uniform(-1, 1)
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        R = np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K
        shift = allowed @ (pos * rng.uniform(-1, 1, 3))
        vlin = allowed @ (vel * rng.uniform(-1, 1, 3))
        w = omega * rng.uniform(-1, 1, 3)
        for node in (a, c):
            nodes[node] = center + shift + R @ (nodes[node] - center)
        new_center = center + shift
        for node in (a, c):
            vels[node] = vlin + np.cross(w, nodes[node] - new_center)
    return nodes, vels
