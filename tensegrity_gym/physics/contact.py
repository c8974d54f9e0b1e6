"""Ground contact with Coulomb friction for the rods' end caps (optional physics module).

The forces are computed by the numba backend (:mod:`tensegrity_gym.backends.numba.contact`);
never imports gymnasium. SI units: m, kg, s, N. Only scenes that model a ground create a
:class:`GroundContact` and pay for it; the model and state (:mod:`tensegrity_gym.core.model`)
know nothing about contact: contact forces enter the equations of motion as external nodal
forces ``W`` (the seed's (5.21)) through ``physics.step(..., external=W)``, or inside the
loop driver (:func:`tensegrity_gym.physics.pipeline.run_steps`).

Geometry: where a rod can touch the ground
------------------------------------------
The ground is the half-space ``z >= height`` (normal ``+z``). A rod is a capsule: a segment
between its two nodes, swept by a sphere of radius ``radius`` (the end cap radius, m). The
signed height of a point of the segment above the plane is *linear* along the segment, so
its minimum is at one of the two ends: **the end caps (spheres of radius ``radius`` centred
at the rod's nodes) are exactly where a capsule first touches a plane.** A prism or an
icosahedron rolls from end cap to end cap, so this is the contact model real 3-bar and 6-bar
robots (which have rubber end caps) need. A rod lying exactly flat touches along its whole
length; the two end-cap contacts are then statically equivalent to that line contact for the
normal force and for the net friction force (Coulomb friction is linear in the normal force
and every point of a translating rod has the same velocity), so sliding and resting are
exact. The one thing that differs is the friction *torque* about the vertical of a flat rod
spinning in place (ends only: ``mu N l/2``; uniform line: ``mu N l/4``): documented
limitation. Strings are massless and never touch the ground.

Normal force (compliant, never pulling)
---------------------------------------
Penetration ``delta = height + radius - z_node`` (m), rate ``delta' = -v_z``. Hunt-Crossley::

    F_n = max(0, k delta^e + min(k delta^e d, c_max) delta')       if delta > 0, else 0

``k`` = ``stiffness`` (N/m^e), ``e`` = ``exponent`` (default 1: a linear spring, k in N/m;
1.5 = Hertz for a sphere), ``d`` = ``damping`` (s/m). The damping force is proportional to the
penetration, so the force is continuous at touch-down and lift-off (no impulse on impact and
no sticky pull); ``max(0, .)`` forbids pulling. Coefficient of restitution for an impact at
speed ``v``: about ``1 - 2 d v / 3`` for small ``d v`` (Hunt & Crossley 1975). ``c_max`` =
``max_damping`` (default no cap) bounds the damping coefficient so that an explicit step stays
stable in fast impacts (where ``k delta^e d`` grows with the penetration).

Friction: Coulomb with a real stick phase
-----------------------------------------
Each contact carries an *anchor* (x, y on the ground, m): the point where the cap first
touched (or last slipped to). A tangential spring-damper pulls the contact back to it::

    xi   = p_t - anchor                                (tangential displacement, m)
    F_t* = -k_t xi - c_t v_t                            (trial friction force, N)
    stick: |F_t*| <= mu F_n  ->  F_t = F_t*             (anchor kept)
    slip : otherwise         ->  F_t = mu F_n F_t*/|F_t*|, anchor slid to p_t + F_t/k_t

so that after a slip the spring alone carries exactly ``mu F_n``. While the contact sticks the
spring holds it at a bounded offset ``|xi| <= mu F_n / k_t``: **resting bodies do not creep**
(a purely velocity-regularised friction law would let them creep at a speed proportional to
the tangential load). While it slides the friction force is exactly ``mu F_n`` against the
motion (the deceleration of a sliding body is ``mu g``). The anchor is forgotten when the
cap leaves the ground. ``k_t`` = ``tangential_stiffness`` (N/m), ``c_t`` =
``tangential_damping`` (N s/m).

Application point. The contact force is applied at the node (the cap's centre) and the
contact velocity is the node's velocity, so the power of the contact force is exactly
``F . v_node``: with the stored spring energies (:func:`contact_energy`) the total energy can
only decrease (checked in ``tests/test_contact.py``). This neglects the couple
``radius x F_t`` of friction about the cap's centre, a relative error of order
``radius / rod length`` on the friction's moment on a rod (about 5% for the default
TensegrityRoll-v0 robot: 2 cm caps on 0.38 m rods).

Coupling with the integrator
----------------------------
Contact forces are computed once per physics step from the state at the start of the step
and held over it (``external=W``): the pipeline (:func:`tensegrity_gym.physics.pipeline.step`, which
:func:`step` calls) computes the forces then takes one integrator step with ``external=W``,
once per step for the whole batch. For
``semi_implicit_euler`` this is *exactly* the method applied to the full force (it evaluates
all forces at the start of the step anyway); for ``rk4`` it is a zero-order hold (first order
in the contact force), so use ``semi_implicit_euler`` with contact. The anchors (stick/slip
state) are updated at the same time, once per step, which is what makes the state
(``ContactState``) a discrete-time state carried by the environment between steps.

Stable time step
----------------
A contact adds a stiffness ``k`` (normal, e = 1) and ``k_t`` (tangential) to the node it acts
on. The smallest effective mass of a rod end is ``m/4`` (a transverse force at the end of a
uniform rod: ``1/(1/m + (l/2)^2/J)``), so the contact frequency is
``omega_c = sqrt(k / (m/4))`` and semi-implicit Euler needs ``dt < 2/omega_c`` (less with
damping: :func:`stable_step`). For the defaults (k = k_t = 1e4 N/m) on the 0.2 kg rods of the
TensegrityRoll-v0 prism: ``omega_c`` = 447 rad/s, with the strings 509 rad/s, estimated limit
2.5 ms with damping; measured: stable at 2 ms, unstable at 3 ms. TensegrityRoll-v0 steps at
1 ms (see ``docs/contact.md``).

State and shapes
----------------
``n_c`` contacts = 2 k (both ends of every rod, in the order rod 0 end a, rod 0 end c, rod 1
end a, ...). :class:`ContactState` holds ``anchor`` (B, n_c, 2) in m and ``active`` (B, n_c)
bool; :func:`contact_forces` returns ``W`` (B, n, 3) in N and the new state.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..backends.numba.contact import forces_kernel
from ..core.checks import check_positive
from ..core.integrators import numba_backend
from ..core.model import Model
from ..core.param_table import contact_columns
from .stability import stability_limit

__all__ = ["GroundContact", "ContactState", "init_contact_state", "contact_forces", "forces_inplace",
           "contact_energy", "stable_step", "contact_nodes", "check_prm_rows", "set_copy_values", "PRM_FIELDS",
           "PER_COPY_FIELDS"]


@dataclass(frozen=True)
class GroundContact:
    """Parameters of the ground half-space ``z >= height`` and the end caps (SI units).

    Parameters
    ----------
    stiffness : normal stiffness k, N/m^exponent (default 1e4 N/m).
    damping : Hunt-Crossley damping d, s/m (default 10 s/m): F_n = k delta^e (1 + d delta').
    exponent : e >= 1 (1 = linear spring, 1.5 = Hertz sphere).
    friction : Coulomb coefficient mu >= 0 (default 1.0, rubber caps on a floor).
    tangential_stiffness : k_t, N/m (default: ``stiffness``).
    tangential_damping : c_t, N s/m (default 10 N s/m).
    radius : end-cap radius, m (default 0.02).
    height : ground height, m (default 0).
    max_damping : cap on the normal damping coefficient ``k delta^e d``, N s/m (default inf).
        An explicit step is unstable once ``c dt / m_eff > 2``; in a fast impact the
        Hunt-Crossley coefficient grows with the penetration, so envs cap it at
        ``m_eff / dt`` (TensegrityRoll-v0: 50 N s/m for 0.2 kg rods at 1 ms).
    backend : "auto" or "numba" (the same: the contact forces are a numba kernel).
    """

    stiffness: float = 1e4
    damping: float = 10.0
    exponent: float = 1.0
    friction: float = 1.0
    tangential_stiffness: float | None = None
    tangential_damping: float = 10.0
    radius: float = 0.02
    height: float = 0.0
    max_damping: float = math.inf
    backend: str = "auto"

    def __post_init__(self):
        s = object.__setattr__
        s(self, "stiffness", check_positive(self.stiffness, "stiffness", "N/m^exponent"))
        s(self, "damping", check_positive(self.damping, "damping", "s/m", allow_zero=True))
        e = check_positive(self.exponent, "exponent", "1")
        if e < 1:
            raise ValueError(f"exponent: must be >= 1 (1 linear, 1.5 Hertz), got {self.exponent!r}")
        s(self, "exponent", e)
        s(self, "friction", check_positive(self.friction, "friction", "1", allow_zero=True))
        kt = self.stiffness if self.tangential_stiffness is None else self.tangential_stiffness
        s(self, "tangential_stiffness", check_positive(kt, "tangential_stiffness", "N/m"))
        s(self, "tangential_damping", check_positive(self.tangential_damping, "tangential_damping", "N s/m",
                                                allow_zero=True))
        s(self, "radius", check_positive(self.radius, "radius", "m", allow_zero=True))
        try:
            h = float(self.height)
        except (TypeError, ValueError):
            raise ValueError(f"height: expected a number (m), got {self.height!r}") from None
        if not math.isfinite(h):
            raise ValueError(f"height: must be finite (m), got {self.height!r}")
        s(self, "height", h)
        numba_backend(self.backend)   # "auto"/"numba"; the same ValueError as step's otherwise
        try:
            cmax = float(self.max_damping)
        except (TypeError, ValueError):
            raise ValueError(f"max_damping: expected a number (N s/m), got {self.max_damping!r}") from None
        if not cmax > 0:   # NaN or <= 0
            raise ValueError(f"max_damping: must be positive (N s/m; inf = no cap), got {self.max_damping!r}")
        s(self, "max_damping", cmax)
        prm = np.array([[getattr(self, f) for f in PRM_FIELDS]], float)   # (1, 9): see PRM_FIELDS
        prm.setflags(write=False)
        s(self, "_prm", prm)

    @property
    def prm(self) -> np.ndarray:
        """(1, 9) read-only row of this contact's parameters (columns :data:`PRM_FIELDS`): the
        ``prm`` the kernels take when no per-copy rows are given."""
        return self._prm

    def replace(self, **kw) -> "GroundContact":
        return replace(self, **kw)

    def per_copy(self, batch_size: int) -> np.ndarray:
        """(B, 9) per-copy contact parameters (columns :data:`PRM_FIELDS`), every row this
        contact's values: pass it as ``prm`` to :func:`contact_forces` / :func:`forces_inplace`
        after changing rows with :func:`set_copy_values` (each copy its own friction, stiffness...)."""
        return np.repeat(self._prm, int(batch_size), axis=0)


#: columns of the (P, 9) contact parameter array (the kernels' ``prm``): SI units as in GroundContact
PRM_FIELDS = contact_columns()   # a view of tensegrity_gym.core.param_table
#: the fields that may differ per copy (the exponent is one per contact model)
PER_COPY_FIELDS = tuple(f for f in PRM_FIELDS if f != "exponent")


def set_copy_values(prm: np.ndarray, idx, name: str, values) -> None:
    """In place: rows ``idx`` of a per-copy parameter array get ``values`` (a number or one per
    row) for field ``name`` (one of :data:`PER_COPY_FIELDS`), checked as the constructor checks it
    (ValueError naming the field, the copy and the value). ``prm``: the ground's (B, 9) (from
    :meth:`GroundContact.per_copy`) or a terrain's (B, F, 8) (every part of a row gets its value;
    the same columns without ``height``)."""
    if name not in PER_COPY_FIELDS:
        raise ValueError(f"contact parameter: unknown or not per copy {name!r}; choose one of {PER_COPY_FIELDS}")
    idx = np.asarray(idx, dtype=int).reshape(-1)
    v = np.broadcast_to(np.asarray(values, dtype=float), idx.shape)
    nonneg = name in ("damping", "friction", "tangential_damping", "radius")
    bad = ~np.isfinite(v) | ((v < 0) if nonneg else (v <= 0))
    if name in ("height",):
        bad = ~np.isfinite(v)
    elif name == "max_damping":
        bad = ~(v > 0)
    if bad.any():
        j = int(np.flatnonzero(bad)[0])
        raise ValueError(f"contact {name}: copy {int(idx[j])}: must be {'>= 0' if nonneg else '> 0'}, "
                         f"got {float(v[j])!r}")
    col = PRM_FIELDS.index(name)
    if prm.shape[-1] != len(PRM_FIELDS) and col >= prm.shape[-1]:
        raise ValueError(f"contact parameter {name!r}: not a column of a terrain part's parameters "
                         f"{PRM_FIELDS[:prm.shape[-1]]}")
    prm[idx, ..., col] = v.reshape(v.shape + (1,) * (prm.ndim - 2))


@dataclass(frozen=True, eq=False)
class ContactState:
    """Stick/slip state of B x n_c contacts: ``anchor`` (B, n_c, 2) m, ``active`` (B, n_c) bool."""

    anchor: np.ndarray
    active: np.ndarray

    def copy(self) -> "ContactState":
        return ContactState(self.anchor.copy(), self.active.copy())


def contact_nodes(model: Model) -> np.ndarray:
    """(n_c,) node index of each contact: rod 0 node a, rod 0 node c, rod 1 node a, ..."""
    return np.stack([model.rod_a, model.rod_c], axis=1).reshape(-1)


def init_contact_state(model: Model, batch_size: int = 1) -> ContactState:
    """No contact active, anchors zero."""
    nc = 2 * model.n_bars
    return ContactState(np.zeros((batch_size, nc, 2)), np.zeros((batch_size, nc), bool))



def contact_forces(contact: GroundContact, model: Model, q: np.ndarray, qd: np.ndarray,
                   cstate: ContactState, out: np.ndarray | None = None, inplace: bool = False, prm=None):
    """Contact forces at the state ``q``, ``qd`` (B, k, 6) and the updated stick/slip state.

    Returns ``(W, new_state, slip)``: ``W`` (B, n, 3) nodal forces in N (normal along +z,
    friction in x, y), ``new_state`` a :class:`ContactState` (anchors moved on slip, set on
    touch-down; ``active`` = cap below ``height + radius``) and ``slip`` (B, n_c) bool.
    With ``inplace=True`` the arrays of ``cstate`` are updated in place (and returned) and
    ``out`` (B, n, 3) is reused for ``W`` (see :func:`forces_inplace` for the fastest path).
    ``prm``: per-copy parameters (B, 9) from :meth:`GroundContact.per_copy` (default: the
    contact's own values for every copy; the exponent is always the contact's)."""
    B = q.shape[0]
    nc = 2 * model.n_bars
    if cstate.anchor.shape != (B, nc, 2) or cstate.active.shape != (B, nc):
        raise ValueError(f"contact state: expected anchor ({B}, {nc}, 2) and active ({B}, {nc}), got "
                         f"{cstate.anchor.shape} and {cstate.active.shape}")
    anchor = cstate.anchor if inplace else cstate.anchor.copy()
    active = cstate.active if inplace else cstate.active.copy()
    W = out if out is not None else np.empty((B, model.n_nodes, 3))
    slip = np.empty((B, nc), bool)
    qc = np.ascontiguousarray(q, dtype=np.float64)
    qdc = np.ascontiguousarray(qd, dtype=np.float64)
    forces_kernel(qc, qdc, model.eta, model.rod_a, model.rod_c, anchor, active, W, slip,
                   contact._prm if prm is None else check_prm_rows(contact, prm, B))
    return W, (cstate if inplace else ContactState(anchor, active)), slip


def check_prm_rows(contact, prm, B):
    """``prm`` as a C-contiguous float64 (1, 9) or (B, 9) array of per-copy contact parameters
    (columns :data:`PRM_FIELDS`); ValueError for another shape or an exponent column that is not
    the contact's."""
    prm = np.ascontiguousarray(prm, dtype=np.float64)
    if prm.ndim != 2 or prm.shape[1] != len(PRM_FIELDS) or prm.shape[0] not in (1, B):
        raise ValueError(f"contact prm: expected shape (1, 9) or ({B}, 9) (GroundContact.per_copy), got {prm.shape}")
    if np.any(prm[:, PRM_FIELDS.index("exponent")] != contact.exponent):
        raise ValueError("contact prm: the exponent column must equal the contact's exponent "
                         f"{contact.exponent} (one exponent per contact model)")
    return prm


def forces_inplace(contact: GroundContact, model: Model, q: np.ndarray, qd: np.ndarray,
                   cstate: ContactState, W: np.ndarray, slip: np.ndarray, prm=None) -> None:
    """Allocation-free :func:`contact_forces` for environments that own their arrays: writes the
    forces into ``W`` (B, n, 3), the slip flags into ``slip`` (B, n_c) bool and updates ``cstate``
    in place. ``q``, ``qd``: C-contiguous float64 (B, k, 6). Shapes are the caller's duty.
    ``prm``: (B, 9) C-contiguous float64 per-copy parameters (:meth:`GroundContact.per_copy`) or
    None (the contact's own)."""
    prm = contact._prm if prm is None else prm
    forces_kernel(q, qd, model.eta, model.rod_a, model.rod_c, cstate.anchor, cstate.active, W, slip, prm)


def contact_energy(contact: GroundContact, model: Model, q: np.ndarray, cstate: ContactState) -> np.ndarray:
    """(B,) energy stored in the contact springs, J: normal ``k delta^(e+1)/(e+1)`` plus
    tangential ``k_t |xi|^2 / 2`` of the active contacts (anchors from ``cstate``)."""
    B, k = q.shape[0], model.n_bars
    r, b = q[..., :3], q[..., 3:]
    P = (r[:, :, None, :] + model.eta[None, :, :, None] * b[:, :, None, :]).reshape(B, 2 * k, 3)
    delta = np.maximum(contact.height + contact.radius - P[..., 2], 0.0)
    e = contact.exponent
    En = contact.stiffness * delta ** (e + 1) / (e + 1)
    xi = np.where(cstate.active[..., None], P[..., :2] - cstate.anchor, 0.0)
    Et = 0.5 * contact.tangential_stiffness * np.einsum("bci,bci->bc", xi, xi)
    return (En + np.where(delta > 0, Et, 0.0)).sum(axis=1)


def impact_damping_cap(rod_mass, dt: float) -> float:
    """The normal damping cap (N s/m) that keeps impacts passive with an explicit step of ``dt``
    s: ``m_min / 4 / dt``, ``m_min`` the lightest of ``rod_mass`` (kg; a rod end's effective
    mass is m/4). Hunt-Crossley damping ``k delta^e d`` grows with the penetration, so a fast
    impact drives ``c dt / m_eff`` above 1, where the held damping force reverses the approach
    speed within one step and the explicit update injects energy (a prism dropped 5 m onto
    the default terrain came back 46 m up); at or below the cap the damping force can at most
    stop the approach in a step. Resting and rolling contact stay far below it (the damping at
    rest is ``d`` times the weight on the contact), so they are unchanged. What the envs and
    the command line use unless ``ground_max_damping`` is given (docs/contact.md)."""
    return float(np.min(rod_mass)) / 4.0 / float(dt)


def stable_step(contact: GroundContact, model: Model) -> dict:
    """Stability estimate (s) of semi-implicit Euler with ground contact.

    ``omega_c = sqrt(max(k, k_t) / (m_min/4))`` (m_min the lightest rod: the effective mass of a
    rod end under a transverse force is m/4), combined with the strings' highest frequency
    ``omega_s`` (:func:`tensegrity_gym.physics.stability.stability_limit`) as
    ``omega = sqrt(omega_c^2 + omega_s^2)``. Damping lowers the limit of an explicit method:
    for a damped oscillator semi-implicit Euler needs ``omega dt < 2 (sqrt(1 + zeta^2) - zeta)``,
    with ``zeta = c / (2 sqrt(k m_eff))`` and ``c`` the larger of the tangential damping ``c_t``
    and the Hunt-Crossley damping at rest ``d k delta_rest`` (``delta_rest`` the penetration
    under a third of the weight per contact). For exponent > 1 the stiffness is the tangent
    stiffness at ``delta_rest``. Returns ``{"omega_contact", "omega_strings", "omega", "zeta",
    "undamped": 2/omega, "semi_implicit_euler": damped limit}`` (rad/s, 1, s); the damped limit is
    also capped by the strings' own (string damping lowers it: :func:`tensegrity_gym.physics.stability.stability_limit`).
    For the defaults on the TensegrityRoll-v0 prism (0.2 kg rods): 447, 243, 509 rad/s,
    zeta 0.45, limit 2.5 ms; measured: stable at 2 ms, unstable at 3 ms (docs/contact.md)."""
    g = 9.81 if model.gravity is None else float(np.linalg.norm(model.gravity))
    w = max(model.mass.sum() * g / 3.0, 1e-9)        # N per contact, three caps carrying the weight
    e = contact.exponent
    d_rest = float((w / contact.stiffness) ** (1.0 / e))
    kn = e * contact.stiffness * d_rest ** (e - 1.0)
    k = max(kn, contact.tangential_stiffness)
    m_eff = float(model.mass.min()) / 4.0
    oc = math.sqrt(k / m_eff)
    c = max(contact.tangential_damping, min(contact.damping * contact.stiffness * d_rest ** e, contact.max_damping))
    zeta = float(c / (2.0 * math.sqrt(k * m_eff)))
    os_ = stability_limit(model)["omega_max"]
    os_ = 0.0 if not math.isfinite(os_) else os_
    om = math.sqrt(oc * oc + os_ * os_)
    # the strings' own damped limit (string damping lowers it; 6.4 ms for the default prism robot)
    strings = stability_limit(model)["semi_implicit_euler"]
    combined = 2.0 * (math.sqrt(1.0 + zeta * zeta) - zeta) / om
    return {"omega_contact": oc, "omega_strings": os_, "omega": om, "zeta": zeta, "undamped": 2.0 / om,
            "semi_implicit_euler": min(combined, strings) if math.isfinite(strings) else combined}

