"""The model and state of a class-1 tensegrity in configuration-matrix form: :class:`Model`
(topology and nominal physics, compiled once from a :class:`~tensegrity_gym.core.structure.Structure`)
and :class:`State` (a batch of configurations). The equations below are computed by the
backends (:mod:`tensegrity_gym.backends`) through :mod:`tensegrity_gym.physics`.

This module never imports gymnasium. Everything is in SI units (m, kg, s, N).

Coordinates
-----------
Each rod j has a *reference point* ``r_j`` (m) and a unit vector ``b_j`` pointing from
its node a to its node c. The reference point sits at fraction ``sigma_j`` from node a:

* a free rod is described at its centre of mass (``sigma`` = mass-weighted centre,
  first mass moment ``f = 0``), exactly the seed's Theorem 5.1 with ``Q = [R B]``;
* a rod with a constrained end node (``D n = const``) is described at that node
  (``sigma = 0`` or ``1``), the seed's section 5.4 reduced form with
  ``r = D^+ rbar + E z``.

Nodes are linear in the configuration (5.17, 5.42):
``n_a = r + eta_a b``, ``n_c = r + eta_c b`` with ``eta_a = -sigma l``, ``eta_c = (1 - sigma) l``;
i.e. ``N = Q Psi^T + Y`` with anchors in ``Y``.

The state of a batch of B copies of one structure is ``q`` (B, k, 6) = ``[r, b]`` and
``qd`` (B, k, 6) = ``[r', b']`` (m, 1, m/s, 1/s).

Equations of motion (per rod; (5.49)-(5.51) of the seed, which reduce to (5.37)/(5.40)
for a free rod described at its centre of mass)::

    f_r = F_a + F_c                         (sum of nodal forces, N)
    f_b = eta_a F_a + eta_c F_c             (generalized force on b, N m)
    w   = |b'|^2 / |b|^2,   P = I - b b^T / |b|^2
    r'' = A(b) [ f_r - (f/J) P f_b + f w b ]
    b'' = P f_b / J - (f/J) P r'' - w b

with ``A = E (m I - f^2/J E^T P E)^{-1} E^T`` written branch-free through the projector
``Pi = E E^T`` onto the allowed directions of the reference point and Sherman-Morrison:
``A = (Pi - beta u u^T / (alpha + beta |u|^2)) / alpha``, ``u = Pi b/|b|``,
``alpha = m - f^2/J > 0`` (Lemma 5.1), ``beta = f^2/J``. For a free rod ``A = I/m``; for a
pinned rod ``A = 0``.

Strings are tension-only (5.20)::

    gamma_i = max(0, k_i (|s_i| - l0_i)/|s_i| + c_i (d|s_i|/dt)/|s_i|)   if |s_i| > l0_i, else 0
    gamma_i <- max(0, gamma_i + u_i)          (u: force density added by a controller, N/m)

so a string never pushes, damping included, and a slack string carries no force
(a controller may still pull through it with ``u > 0``). Force densities enter the
generalized forces linearly (5.21): ``F_Q = [W - N C_S^T Gamma C_S] Psi``.

Strings listed as *active* in :func:`compile_model` have no elastic part: their force
density is the control input ``u`` alone (clipped at 0: a cable cannot push).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, replace
from typing import Iterable

import numpy as np

from .checks import check_finite, is_integer
from .params import PARAM_FIELDS, Params, default_params, nominal_params
from .rod_mass import mass_moments
from .sizing import check_size
from .structure import Structure

__all__ = ["Model", "State", "compile_model", "Params", "default_params", "initial_state", "new_state"]


@dataclass(frozen=True, eq=False)
class Model:
    """Compiled, immutable arrays of one structure topology (SI units), and its nominal physical
    values.

    Shapes: k rods, n nodes, m strings, na anchors. The nominal physical values live in ONE
    place, ``nominal`` (a one-row :class:`~tensegrity_gym.core.params.Params`); each of its
    fields reads as a model attribute without the copy axis (``model.mass`` (k,) kg,
    ``model.stiffness`` (m,) N/m, ``model.rest_length`` (m,) m, ``model.node_damping`` (n,) N s/m,
    ``model.anchor_pos`` (na, 3) m, ``model.W0`` (n, 3) N, ...: the physics rows of
    :mod:`tensegrity_gym.core.param_table`), and ``model.has_<field>`` for the fields whose term
    the equations skip where it is 0 (``has_damping``, ``has_gravity``, ``has_node_damping``).
    """

    structure: Structure
    n_nodes: int
    n_bars: int
    n_strings: int
    rod_a: np.ndarray          # (k,) node a of each rod
    rod_c: np.ndarray          # (k,) node c of each rod
    length: np.ndarray         # (k,) rod length, m
    sigma: np.ndarray          # (k,) reference point as fraction from node a
    eta: np.ndarray            # (k, 2) signed distance of nodes a, c from the reference point, m
    proj: np.ndarray           # (k, 3, 3) projector Pi = E E^T onto allowed reference-point motion
    offset: np.ndarray         # (k, 3) fixed part (I - Pi) n0 of the reference point, m
    constrained: np.ndarray    # (k,) bool: rod has a constrained node
    anchor_idx: np.ndarray     # (na,) anchor node indices
    str_i: np.ndarray          # (m,) first node of each string
    str_j: np.ndarray          # (m,) second node (s = n_j - n_i); C_S = :func:`connectivity`
    active: np.ndarray         # (m,) bool: force-density-controlled strings
    nominal: Params            # the nominal physical values (one row; see the class doc)
    com_eta: np.ndarray = field(default=None)  # (k,) signed distance of centre of mass from ref. point, m

    def __getattr__(self, name):
        if name.startswith("__") or name == "nominal":
            raise AttributeError(name)
        nom = self.nominal
        if name in PARAM_FIELDS or name == "W0":
            return getattr(nom, name)[0]
        if name.startswith("has_"):
            return getattr(nom, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def gravity(self) -> np.ndarray | None:
        """(3,) gravitational acceleration, m/s^2, or None for a structure without gravity."""
        if self.structure.gravity is None and not self.nominal.may_be_nonzero("gravity"):
            return None
        return self.nominal.gravity[0]

    @property
    def node_velocity_free(self) -> bool:
        """True if no string is damped and no node has drag (forces then need no node velocities)."""
        return not (self.has_damping or self.has_node_damping)

    def replace(self, W0=None, **values) -> "Model":
        """The same topology with the nominal physical values ``values`` (Params fields, validated
        and completed as :meth:`Params.replace`: ``mass`` alone recomputes ``f``, ``J``; ``W0``,
        (n, 3) N, keeps those nodal loads instead of the ones of the new masses and gravity)."""
        p = default_params(self).replace(**values)
        new = {k: getattr(p, k)[0] for k in tuple(PARAM_FIELDS) + ("W0",)}
        if W0 is not None:
            new["W0"] = W0
        return replace(self, nominal=nominal_params(self, new))


@dataclass(frozen=True, eq=False)
class State:
    """Batched state. ``q``, ``qd``: (B, k, 6) arrays ``[r, b]``, ``[r', b']``; ``t``: s."""

    q: np.ndarray
    qd: np.ndarray
    t: float = 0.0

    @property
    def batch_size(self) -> int:
        return self.q.shape[0]

    def replace(self, **kw) -> "State":
        return replace(self, **kw)


def _fast_state_ok() -> bool:
    """Whether :class:`State` is still the plain frozen dataclass (q, qd, t) that :func:`new_state` fills directly."""
    return (dataclasses.is_dataclass(State) and [f.name for f in dataclasses.fields(State)] == ["q", "qd", "t"]
            and not hasattr(State, "__post_init__") and not hasattr(State, "__slots__"))


if _fast_state_ok():
    _object_new = object.__new__

    def new_state(q, qd, t):
        """State(q=q, qd=qd, t=t) without the frozen dataclass __init__ (3x faster; same object)."""
        s = _object_new(State)
        d = s.__dict__
        d["q"] = q
        d["qd"] = qd
        d["t"] = t
        return s
else:  # pragma: no cover - State changed shape: use its constructor
    def new_state(q, qd, t):
        return State(q=q, qd=qd, t=t)


def compile_model(structure: Structure, active_strings: Iterable[int] | None = None,
                  node_damping=None) -> Model:
    """Compile a :class:`Structure` into the arrays the dynamics use.

    ``active_strings``: indices of strings whose force density is a control input
    (no elastic part). Default: none (all strings elastic).

    ``node_damping``: viscous drag coefficient ``c`` (N s/m, >= 0), a number for every node or
    an (n,) array: node ``i`` feels ``-c_i v_i`` (``v_i`` its velocity; anchors do not move),
    added to the nodal forces ``W`` like any external force (so it enters ``f_r`` and ``f_b``
    by (5.21)). Default None / all zero: no drag, and no drag code runs."""
    s = structure
    k, n, m = s.n_bars, s.n_nodes, s.n_strings
    check_size(s)   # refuse at once (naming the size) what cannot fit in memory
    rod_a = s.bars[:, 0].copy()
    rod_c = s.bars[:, 1].copy()
    length = s.bar_lengths
    mp = s.mass_points or (None,) * k
    sigma = s.com_fraction.copy()
    proj = np.tile(np.eye(3), (k, 1, 1))
    offset = np.zeros((k, 3))
    constrained = np.zeros(k, bool)
    for j in range(k):
        for end, node in ((0, rod_a[j]), (1, rod_c[j])):
            if node in s.node_constraints:
                D = s.node_constraints[node]
                sigma[j] = float(end)
                # projector onto the null space of D (allowed motion)
                Pi = np.eye(3) - D.T @ np.linalg.solve(D @ D.T, D)
                Pi[np.abs(Pi) < 1e-15] = 0.0
                proj[j] = Pi
                offset[j] = (np.eye(3) - Pi) @ s.nodes[node]
                constrained[j] = True
    f = np.zeros(k)
    J = np.zeros(k)
    for j in range(k):
        fj, Jj = mass_moments(length[j], s.bar_mass[j], sigma[j], mp[j])
        f[j] = 0.0 if not constrained[j] else fj   # free rods: f = 0 exactly at the centre of mass
        J[j] = Jj
    eta = np.stack([-sigma * length, (1.0 - sigma) * length], axis=1)
    com_eta = (s.com_fraction - sigma) * length
    active = np.zeros(m, bool)
    if active_strings is not None:
        idx = np.asarray(list(active_strings), dtype=int)
        if idx.size and (idx.min() < 0 or idx.max() >= m):
            bad = idx[(idx < 0) | (idx >= m)][0]
            raise ValueError(f"active_strings: string {bad} does not exist (there are {m} strings)")
        active[idx] = True
    stiffness = np.where(active, 0.0, s.stiffness)
    damping = np.where(active, 0.0, s.damping)
    W0 = np.zeros((n, 3))
    if s.gravity is not None:
        # a rod's weight m g acts at its centre of mass: equivalent loads at its two nodes
        com = s.com_fraction
        W0[rod_a] += ((1.0 - com) * s.bar_mass)[:, None] * s.gravity
        W0[rod_c] += (com * s.bar_mass)[:, None] * s.gravity
    if node_damping is None:
        cn = np.zeros(n)
    else:
        cn = np.array(np.broadcast_to(np.asarray(node_damping, dtype=float), (n,))) \
            if np.ndim(node_damping) == 0 else np.asarray(node_damping, dtype=float).copy()
        if cn.shape != (n,):
            raise ValueError(f"node_damping: expected a number or an array of shape ({n},) (N s/m per node), "
                             f"got shape {cn.shape}")
        bad = ~(np.isfinite(cn) & (cn >= 0))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"node_damping: must be finite and >= 0 N s/m, got {cn[i]} at node {i}")
    anchor_idx = s.anchors
    arrays = dict(rod_a=rod_a, rod_c=rod_c, length=length, sigma=sigma, eta=eta, proj=proj, offset=offset,
                  constrained=constrained, anchor_idx=anchor_idx, str_i=s.strings[:, 0].copy(),
                  str_j=s.strings[:, 1].copy(), active=active, com_eta=com_eta)
    for a in arrays.values():
        a.setflags(write=False)
    model = Model(structure=s, n_nodes=n, n_bars=k, n_strings=m, nominal=None, **arrays)
    # the nominal values the structure gives; a physics row not listed here takes its table nominal
    computed = dict(mass=s.bar_mass, f=f, J=J, stiffness=stiffness, damping=damping, rest_length=s.rest_length,
                    node_damping=cn, gravity=np.zeros(3) if s.gravity is None else s.gravity,
                    anchor_pos=s.nodes[anchor_idx], W0=W0)
    object.__setattr__(model, "nominal", nominal_params(model, computed))
    return model


def initial_state(model: Model, batch_size: int = 1, nodes: np.ndarray | None = None,
                  velocities: np.ndarray | None = None) -> State:
    """State from node positions (n, 3) or (B, n, 3) m and velocities (n, 3) or (B, n, 3) m/s
    (default: the structure's), ``batch_size`` copies of (n, 3) inputs.

    Rod lengths are taken from the model; ``b`` is normalised. ValueError naming the argument for
    a batch size that is not a positive integer, a wrong shape, a NaN/inf entry or a rod whose
    two nodes coincide."""
    if not is_integer(batch_size) or batch_size < 1:
        raise ValueError(f"batch_size: must be a positive integer (copies), got {batch_size!r}")
    s = model.structure
    n = model.n_nodes
    nodes = s.nodes if nodes is None else np.asarray(nodes, float)
    vel = s.velocities if velocities is None else np.asarray(velocities, float)
    for x, name in ((nodes, "nodes"), (vel, "velocities")):
        if x.shape[-2:] != (n, 3) or x.ndim not in (2, 3):
            raise ValueError(f"{name}: expected shape ({n}, 3) or (B, {n}, 3), got {x.shape}")
        check_finite(x, name)
    if nodes.ndim == 2:
        nodes = np.broadcast_to(nodes, (batch_size,) + nodes.shape)
    if vel.ndim == 2:
        vel = np.broadcast_to(vel, (nodes.shape[0],) + vel.shape)
    elif vel.shape[0] != nodes.shape[0]:
        raise ValueError(f"velocities: {vel.shape[0]} copies for {nodes.shape[0]} copies of nodes")
    na, nc = nodes[:, model.rod_a], nodes[:, model.rod_c]
    d = nc - na
    length = np.linalg.norm(d, axis=-1, keepdims=True)
    if not (length > 0).all():
        b, j, _ = (int(i) for i in np.argwhere(~(length > 0))[0])
        raise ValueError(f"nodes: rod {j} (nodes {model.rod_a[j]} and {model.rod_c[j]}) has zero length in copy {b}")
    va, vc = vel[:, model.rod_a], vel[:, model.rod_c]
    b = d / length
    L = model.length[None, :, None]
    bd = (vc - va) / L
    sig = model.sigma[None, :, None]
    r = na + sig * L * b
    rd = va + sig * L * bd
    q = np.concatenate([r, b], axis=-1)
    qd = np.concatenate([rd, bd], axis=-1)
    return State(q=np.ascontiguousarray(q), qd=np.ascontiguousarray(qd), t=0.0)


