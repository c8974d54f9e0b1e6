"""Rod-rod contact: the rods as capsules that push each other apart (optional physics module).

Without it rods pass through each other; only scenes that create a :class:`RodContact` pay
for it. The forces are computed by the numba backend (:mod:`tensegrity_gym.backends.numba.rod_contact`;
torch twin :func:`tensegrity_gym.backends.torch.rod_contact.rod_contact_forces`, NumPy reference
``tests/oracle_numpy.rod_contact_forces``) and enter the equations of motion as external nodal
forces, as the ground contact's do (:mod:`tensegrity_gym.physics.contact`). SI units.

Geometry. A rod is the segment between its two nodes ``a = r + eta_a b`` and
``c = r + eta_c b``, swept by a sphere of radius ``radius`` (m): a capsule. For every pair of
rods i < j the closest points ``p_i = a_i + s (c_i - a_i)`` and ``p_j = a_j + t (c_j - a_j)``,
``s, t`` in [0, 1], are those of the two segments (parallel segments included: there the
middle of their overlap); the overlap is ``delta = 2 radius - |p_i - p_j|`` (m).

Law, where ``delta > 0`` (``n`` the unit vector from ``p_j`` to ``p_i``, ``v`` the velocity of
the material point ``p_i`` relative to ``p_j``)::

    F_n = max(0, k delta + min(c, c_max) delta'),  delta' = -n . v      (never pulling)
    F_t = -min(mu F_n / max(|v_t|, v_eps), c_max) v_t,  v_t = v - (n . v) n

rod i takes ``F = F_n n + F_t`` at ``p_i``, rod j ``-F`` at ``p_j``. Friction is a regularised
Coulomb law: a viscous damper below the speed ``v_eps`` (``friction_speed``), ``mu F_n``
against the sliding above it; it has no stick phase (rods resting on each other creep at a
speed of order ``v_eps`` times the tangential load over ``mu F_n``), a simplification of the
ground's stick-slip friction. Both damping coefficients are capped at ``max_damping`` so that
an explicit step stays passive in fast impacts (as the ground's, :func:`~tensegrity_gym.physics.contact.impact_damping_cap`).

Application. A force ``F`` at the parameter ``s`` of a segment does the virtual work
``F . ((1 - s) da + s dc)``: its generalized force is exactly ``(1 - s) F`` on node a and
``s F`` on node c, because the nodes are linear in the state (q = [r, b]). The power of the
contact forces is therefore ``F . v`` at the closest points, and without damping and friction
an impact returns the energy it stored in the spring ``k delta^2 / 2`` (up to the time step's
error). When the two axes meet exactly (``|p_i - p_j| = 0``) the normal is the normal of the
plane of the two axes, pointing from rod j's centre to rod i's.

Coupling: the forces are computed from the state at the start of each physics step and held
over it, as the ground's, in the loop driver at every sub-step (:func:`tensegrity_gym.physics.pipeline.run_steps`
and :func:`tensegrity_gym.physics.terrain.advance` with ``rods=``). Every pair of rods is
checked (k (k - 1) / 2 pairs, a centre-distance test first); pairs that share a node, which a
class-1 structure has not, are not excluded.

Stable step: the contact adds the stiffness ``k`` between two rod ends, whose relative effective
mass is ``m_min / 8`` (two rod ends of ``m / 4`` in series): semi-implicit Euler needs about
``dt < 2 / sqrt(k / (m_min / 8))`` (:func:`stable_step`; 1.4 ms for the defaults on 0.2 kg rods).
How deep a rod can be pushed: a head-on impact at the relative speed ``v`` stores
``m_eff v^2 / 2`` in the spring, so the overlap stays below ``2 radius`` (no pass-through) for
``v < 2 radius sqrt(k / m_eff)``: 14 m/s between rod ends (``m_eff = m / 8``) and 7 m/s between
rod centres (``m_eff = m / 2``) of 0.2 kg rods with the defaults (``radius`` = 5 mm, ``k`` =
5e4 N/m); 25 and 13 m/s with ``radius`` = 0.02 m and ``k`` = 1e4 N/m. A thinner rod needs a
stiffer contact (``k`` grows as ``1 / radius^2`` for the same speed), and a stiffer contact a
smaller step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..backends.numba.rod_contact import ROD_COLUMNS, pair_distances_kernel, rod_forces_kernel
from ..core.checks import check_positive
from ..core.model import Model

__all__ = ["RodContact", "rod_contact_forces", "add_rod_forces", "pair_distances", "rod_contact_energy",
           "stable_step", "pair_damping_cap", "resolve_option", "ROD_COLUMNS"]


@dataclass(frozen=True)
class RodContact:
    """Parameters of rod-rod contact (SI units; the law: the module doc).

    Parameters
    ----------
    radius : the rods' capsule radius, m (default 0.005: rods of 1 cm diameter).
    stiffness : normal stiffness k, N/m (default 5e4: no pass-through below 7 m/s between the
        centres of 0.2 kg rods, stable at the envs' 1 ms step; see the module doc).
    damping : normal damping c, N s/m (default 10).
    friction : Coulomb coefficient mu >= 0 (default 0.5; 0: frictionless).
    max_damping : cap on the normal and tangential damping coefficients, N s/m (default inf;
        the envs use :func:`pair_damping_cap`).
    friction_speed : v_eps, m/s (default 0.01): below this sliding speed friction is a viscous damper.
    """

    radius: float = 0.005
    stiffness: float = 5e4
    damping: float = 10.0
    friction: float = 0.5
    max_damping: float = math.inf
    friction_speed: float = 0.01

    def __post_init__(self):
        s = object.__setattr__
        s(self, "radius", check_positive(self.radius, "radius", "m"))
        s(self, "stiffness", check_positive(self.stiffness, "stiffness", "N/m"))
        s(self, "damping", check_positive(self.damping, "damping", "N s/m", allow_zero=True))
        s(self, "friction", check_positive(self.friction, "friction", "1", allow_zero=True))
        if isinstance(self.max_damping, (str, bytes, bool, np.bool_)):
            raise ValueError(f"max_damping: expected a number (N s/m), got {self.max_damping!r}")
        try:
            cmax = float(self.max_damping)
        except (TypeError, ValueError):
            raise ValueError(f"max_damping: expected a number (N s/m), got {self.max_damping!r}") from None
        if not cmax > 0:   # NaN or <= 0
            raise ValueError(f"max_damping: must be positive (N s/m; inf = no cap), got {self.max_damping!r}")
        s(self, "max_damping", cmax)
        s(self, "friction_speed", check_positive(self.friction_speed, "friction_speed", "m/s"))
        prm = np.array([[getattr(self, f) for f in ROD_COLUMNS]], float)
        prm.setflags(write=False)
        s(self, "_prm", prm)

    @property
    def prm(self) -> np.ndarray:
        """(1, 6) read-only row of the parameters (columns :data:`ROD_COLUMNS`), as the kernels take it."""
        return self._prm

    def replace(self, **kw) -> "RodContact":
        return replace(self, **kw)


def pair_damping_cap(rod_mass, dt: float) -> float:
    """The damping cap (N s/m) that keeps rod-rod impacts passive with an explicit step of
    ``dt`` s: ``m_min / 8 / dt``, ``m_min`` the lightest of ``rod_mass`` (kg): the relative
    effective mass of two rod ends is ``m / 8``, half the ground's ``m / 4``
    (:func:`tensegrity_gym.physics.contact.impact_damping_cap`)."""
    return float(np.min(rod_mass)) / 8.0 / float(dt)


def _arrays(q, qd=None):
    q = np.ascontiguousarray(q, dtype=np.float64)
    q = q[None] if q.ndim == 2 else q
    if qd is None:
        return q, None
    qd = np.ascontiguousarray(qd, dtype=np.float64)
    return q, (qd[None] if qd.ndim == 2 else qd)


def add_rod_forces(rc: RodContact, model: Model, q: np.ndarray, qd: np.ndarray, W: np.ndarray) -> None:
    """In place: adds the rod-rod contact forces at the state ``q``, ``qd`` (B, k, 6), C-contiguous
    float64 (m, m/s), into ``W`` (B, n, 3) N, C-contiguous float64 (shapes are the caller's duty).
    What the Python loops of the physics steps call after the ground or terrain forces (the loop
    driver adds the same numbers at the same place)."""
    rod_forces_kernel(q, qd, model.eta, model.rod_a, model.rod_c, rc._prm, W)


def rod_contact_forces(rc: RodContact, model: Model, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """(B, n, 3) N: the rod-rod contact forces at the state ``q``, ``qd`` ((B, k, 6) or (k, 6),
    m, m/s) on the nodes (zero where no rods touch)."""
    q, qd = _arrays(q, qd)
    if q.shape != qd.shape or q.ndim != 3 or q.shape[1:] != (model.n_bars, 6):
        raise ValueError(f"q, qd: expected shape (B, {model.n_bars}, 6), got {q.shape} and {qd.shape}")
    W = np.zeros((q.shape[0], model.n_nodes, 3))
    add_rod_forces(rc, model, q, qd, W)
    return W


def pair_distances(model: Model, q: np.ndarray) -> np.ndarray:
    """(B, P) m: the distance between the axes (segments between the nodes) of every rod pair
    i < j (P = k (k - 1) / 2, in the order (0, 1), (0, 2), ..., (1, 2), ...) at ``q`` ((B, k, 6)
    or (k, 6)); 0 where two axes cross. The contact's own closest points."""
    q, _ = _arrays(q)
    k = model.n_bars
    if q.ndim != 3 or q.shape[1:] != (k, 6):
        raise ValueError(f"q: expected shape (B, {k}, 6) or ({k}, 6), got {np.shape(q)}")
    D = np.empty((q.shape[0], k * (k - 1) // 2))
    pair_distances_kernel(q, model.eta, D)
    return D


def rod_contact_energy(rc: RodContact, model: Model, q: np.ndarray) -> np.ndarray:
    """(B,) J: the energy stored in the contact springs, ``k delta^2 / 2`` summed over the pairs
    that overlap (``delta = 2 radius - distance``)."""
    delta = np.maximum(2.0 * rc.radius - pair_distances(model, q), 0.0)
    return 0.5 * rc.stiffness * (delta * delta).sum(axis=1)


def stable_step(rc: RodContact, model: Model) -> float:
    """Estimated largest stable step (s) of semi-implicit Euler for the contact alone: a damped
    oscillator of stiffness ``k`` on the relative effective mass ``m_min / 8`` of two rod ends,
    ``2 (sqrt(1 + zeta^2) - zeta) / omega`` with ``omega = sqrt(k / m_eff)`` and ``zeta = c / (2
    sqrt(k m_eff))``, ``c`` the capped damping."""
    m_eff = float(np.min(model.mass)) / 8.0
    om = math.sqrt(rc.stiffness / m_eff)
    zeta = min(rc.damping, rc.max_damping) / (2.0 * math.sqrt(rc.stiffness * m_eff))
    return 2.0 * (math.sqrt(1.0 + zeta * zeta) - zeta) / om


def resolve_option(value, max_damping: float, name: str = "rod_contact") -> RodContact | None:
    """An env's ``rod_contact`` argument as a :class:`RodContact` or None: None or False (off),
    True (the defaults with the damping cap ``max_damping`` N s/m), a ``RodContact`` (as it is) or
    a dict of its fields (the others as True's). ValueError naming ``name`` (and the field) otherwise."""
    if value is None or value is False:
        return None
    if isinstance(value, RodContact):
        return value
    base = {"max_damping": max_damping}
    if value is True:
        fields = base
    elif isinstance(value, dict):
        unknown = [f for f in value if f not in ROD_COLUMNS]
        if unknown:
            raise ValueError(f"{name}: unknown field {unknown[0]!r}; choose from {list(ROD_COLUMNS)}")
        fields = {**base, **value}
    else:
        raise ValueError(f"{name}: expected None, True, False, a RodContact or a dict of its fields "
                         f"{list(ROD_COLUMNS)}, got {value!r:.80}")
    try:
        return RodContact(**fields)
    except ValueError as e:
        raise ValueError(f"{name}: {e}") from None
