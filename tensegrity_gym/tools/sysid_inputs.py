"""Input checks of :func:`tensegrity_gym.tools.sysid.identify`: the recorded trajectory and the
names and starting values of the fitted parameters.

SI units: sample times in s, node positions and rest lengths in m, starting values in the
fitted fields' units (N/m, N s/m, kg). Every check raises ValueError naming the field, the
sample and the item (node, string, rod), so a bad record is refused before any simulation
runs; the fit itself only sees evenly spaced, finite, masked records and positive starting
values (they are fitted in log space).
"""
from __future__ import annotations

import numpy as np

from ..core.model import Model
from ..core.params import default_params
from ..physics.contact import GroundContact
from .sysid_result import _ALIASES, _UNITS, CONTACT_FIELDS, FITTABLE



class StartValueError(ValueError):
    """A fitted parameter starts at a value <= 0 (it is fitted in log space): ``name`` the
    parameter, ``unit`` its unit, ``problem`` what is wrong. The message ends with the Python
    remedy (``initial={name: value}``); the command line gives its own (``--initial``)."""

    def __init__(self, name: str, unit: str, problem: str):
        self.name, self.unit, self.problem = name, unit, problem
        super().__init__(f"initial: {problem} (pass initial={{{name!r}: value}})")


def _check_record(model: Model, t, nodes, rest_length, node_mask):
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size < 3:
        raise ValueError(f"t: expected a 1-D array of at least 3 sample times (s), got shape {t.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ValueError(f"t: sample {bad[0]} is {t[bad[0]]!r}; sample times must be finite (s)")
    dtt = np.diff(t)
    bad = np.flatnonzero(dtt <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(f"t: times must be strictly increasing; sample {i} (t = {t[i]!r} s) does not come after "
                         f"sample {i - 1} (t = {t[i - 1]!r} s)")
    h = float(np.median(dtt))
    bad = np.flatnonzero(np.abs(dtt - h) > 1e-6 * h + 1e-12)
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(f"t: samples must be evenly spaced (a fixed capture rate); sample {i} is {dtt[i - 1]:.6g} s "
                         f"after sample {i - 1}, the median spacing is {h:.6g} s (give missing frames as NaN rows "
                         f"instead of leaving them out)")
    nodes = np.asarray(nodes, dtype=float)
    n = model.n_nodes
    if nodes.ndim != 3 or nodes.shape[2] != 3:
        raise ValueError(f"nodes: expected shape (S, n, 3) in m, got {nodes.shape}")
    if nodes.shape[0] != t.size:
        raise ValueError(f"nodes: {nodes.shape[0]} samples but t has {t.size}")
    if nodes.shape[1] != n:
        raise ValueError(f"nodes: the trajectory has {nodes.shape[1]} nodes per sample but structure "
                         f"{model.structure.name!r} has {n} nodes")
    S = t.size
    if node_mask is None:
        mask = np.ones((S, n), bool)
    else:
        nm = np.asarray(node_mask)
        if nm.dtype != bool:
            idx = nm.astype(int).ravel()
            if idx.size and (idx.min() < 0 or idx.max() >= n):
                b = idx[(idx < 0) | (idx >= n)][0]
                raise ValueError(f"node_mask: node {b} does not exist (structure has {n} nodes)")
            nm = np.zeros(n, bool)
            nm[idx] = True
        if nm.shape == (n,):
            mask = np.broadcast_to(nm, (S, n)).copy()
        elif nm.shape == (S, n):
            mask = nm.copy()
        else:
            raise ValueError(f"node_mask: expected node indices, a bool array ({n},) or ({S}, {n}), got shape "
                             f"{nm.shape}")
    finite = np.isfinite(nodes).all(axis=2)
    bad = np.argwhere(mask & ~finite)
    if bad.size:
        s_, i = bad[0]
        raise ValueError(f"nodes: sample {s_} (t = {t[s_]:.6g} s), node {i} is {nodes[s_, i].tolist()}: tracked "
                         f"nodes must be finite; mark untracked nodes / dropped frames with node_mask")
    if model.anchor_idx.size:
        mask[:, model.anchor_idx] = False   # anchors do not move: no information
    if not mask.any():
        raise ValueError("node_mask: no moving node is tracked in any sample")
    rl = None
    if rest_length is not None:
        rl = np.asarray(rest_length, dtype=float)
        if rl.shape != (S, model.n_strings):
            raise ValueError(f"rest_length: expected shape ({S}, {model.n_strings}) (one row per sample, m), "
                             f"got {rl.shape}")
        bad = np.argwhere(~(np.isfinite(rl) & (rl >= 0)))
        if bad.size:
            s_, i = bad[0]
            raise ValueError(f"rest_length: sample {s_}, string {i} is {rl[s_, i]!r}; must be finite and >= 0 m")
    return t, np.where(mask[..., None], nodes, 0.0), mask, rl, h


def _parse_fit(model: Model, fit, mode, initial):
    if isinstance(fit, str):
        fit = (fit,)
    names = []
    for f in fit:
        g = _ALIASES.get(f, f)
        if g not in FITTABLE:
            raise ValueError(f"fit: unknown parameter {f!r}; fittable parameters are {sorted(FITTABLE)} "
                             f"(aliases {sorted(_ALIASES)})")
        if g in names:
            raise ValueError(f"fit: parameter {f!r} named twice")
        names.append(g)
    if not names:
        raise ValueError("fit: name at least one parameter to fit")
    if mode not in ("per_member", "scale"):
        raise ValueError(f"mode: expected 'per_member' or 'scale', got {mode!r}")
    base = default_params(model)
    initial = dict(initial or {})
    for k in list(initial):
        g = _ALIASES.get(k, k)
        if g not in FITTABLE:
            raise ValueError(f"initial: unknown parameter {k!r}; fittable parameters are {sorted(FITTABLE)}")
        initial[g] = initial.pop(k)
    initial = {g: v for g, v in initial.items() if g not in CONTACT_FIELDS}    # _parse_contact's
    if initial:
        base = base.replace(**initial)
    items, init = {}, {}
    for g in names:
        if g in CONTACT_FIELDS:
            continue
        vals = getattr(base, g)[0]
        if g in ("stiffness", "damping"):
            idx = np.flatnonzero(~np.asarray(model.active))
        elif g == "node_damping":
            idx = np.setdiff1d(np.arange(model.n_nodes), model.anchor_idx)
        else:
            idx = np.arange(model.n_bars)
        if idx.size == 0:
            raise ValueError(f"fit: {g!r} has nothing to fit in this structure")
        bad = idx[~(vals[idx] > 0)]
        if bad.size:
            raise StartValueError(g, _UNITS[g], f"{g} of {FITTABLE[g]} {bad[0]} starts at {float(vals[bad[0]])!r} "
                                  f"{_UNITS[g]}; it is fitted in log space and needs a positive starting value")
        items[g], init[g] = idx, vals[idx].copy()
    return names, items, init, base


def _parse_contact(names, contact, initial):
    """The ground contact of a fit: ``(contact, tie_tangential)`` with the start values of
    ``initial`` applied (None without contact). ``contact``: a GroundContact, a dict of its fields
    or None. ``tie_tangential``: the tangential stiffness equals the normal one at the start (the
    GroundContact default, and what ``simulate --ground`` runs), so it follows the fitted
    ``ground_stiffness``. ValueError naming the field for a contact field fitted without a contact
    or a bad contact; StartValueError for a start value <= 0."""
    fitted = [g for g in names if g in CONTACT_FIELDS]
    if contact is None:
        given = [k for k in (initial or {}) if k in CONTACT_FIELDS]
        if given:
            raise ValueError(f"initial: {given[0]!r} is a ground contact parameter; pass contact=GroundContact(...)")
        if fitted:
            raise ValueError(f"fit: {fitted[0]!r} is a ground contact parameter; pass contact=GroundContact(...) "
                             f"(or a dict of its fields) and a recording made on that ground")
        return None, False
    if isinstance(contact, dict):
        known = GroundContact.__dataclass_fields__
        bad = [k for k in contact if k not in known]
        if bad:
            raise ValueError(f"contact: unknown field {bad[0]!r}; GroundContact fields are {sorted(known)}")
        contact = GroundContact(**contact)
    elif not isinstance(contact, GroundContact):
        raise ValueError(f"contact: expected a GroundContact or a dict of its fields, got {type(contact).__name__}")
    tie = contact.tangential_stiffness == contact.stiffness
    start = {}
    for k, v in dict(initial or {}).items():
        if k not in CONTACT_FIELDS:
            continue
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            a = np.full(2, np.nan)
        if a.size != 1 or not np.isfinite(a).all():
            raise ValueError(f"initial: {k} must be one finite number ({_UNITS[k]}), got {v!r}")
        start[CONTACT_FIELDS[k]] = float(a.reshape(-1)[0])
    if tie and "stiffness" in start:
        start["tangential_stiffness"] = start["stiffness"]
    try:
        contact = contact.replace(**start) if start else contact
    except ValueError as e:
        raise ValueError(f"initial: {e}") from None
    for g in fitted:
        v = getattr(contact, CONTACT_FIELDS[g])
        if not v > 0:
            raise StartValueError(g, _UNITS[g], f"{g} of the ground starts at {v!r} {_UNITS[g]}; it is fitted in "
                                  "log space and needs a positive starting value")
    return contact, bool(tie)


def _check_above_ground(contact, t, nodes, mask):
    """ValueError naming the sample and the node for a tracked node whose centre lies below the
    ground plane (a cap sunk deeper than its radius): the recording was not made on this ground
    (another height, or a structure's own coordinates instead of the recorded ones)."""
    z = np.where(mask, nodes[..., 2], np.inf)
    bad = np.argwhere(z < contact.height)
    if bad.size:
        s_, i = bad[0]
        raise ValueError(f"nodes: sample {s_} (t = {t[s_]:.6g} s), node {i} is at z = {nodes[s_, i, 2]:.6g} m, below "
                         f"the ground (z = {contact.height:g} m): a recording on this ground has every node at least "
                         f"about a cap radius ({contact.radius:g} m) above it")
