"""System identification: fit physical parameters so that simulated motion matches a recorded one.

:func:`identify` fits named :class:`~tensegrity_gym.params.Params` fields of a structure (string
``stiffness`` N/m, string ``damping`` N s/m, rod ``mass`` kg, ``node_damping`` N s/m) to a
recorded trajectory: times ``t`` (S,) in s and node positions ``nodes`` (S, n, 3) in m, with
the strings' rest lengths ``rest_length`` (S, m) in m when the cables were actuated, and a
``node_mask`` when only some nodes were tracked (motion capture).

Method: multiple shooting with variable projection
--------------------------------------------------
The record is cut into W windows of K consecutive samples (``window`` seconds each; windows do
not share samples, so every sample is counted once). Each window is simulated from its own
initial state with the fit's ``integrator`` and step ``dt`` (which divides the sample spacing),
so an error in the parameters cannot accumulate over the whole record: short windows keep the
problem close to linear and well conditioned, long enough windows (about one period of the
slowest mode you want to see) keep the parameters observable.

The initial state of each window (rod positions *and* velocities) is an unknown of the fit,
not read off the record. It starts from the recorded node positions of the window's first
sample and velocities from a local quadratic fit to its first samples (untracked nodes: the
structure's reference shape rigidly aligned to the tracked ones), then is fitted together with
the parameters. Why unknowns rather than finite differences: with 1 mm of position noise a
finite-difference velocity at 1 kHz is off by ~0.1 m/s, and a noisy initial state is an
errors-in-variables bias in every window; untracked nodes have no recorded state at all. As
unknowns, each window's state is set by all K samples of the window (a maximum-likelihood fit
for Gaussian position noise). Per rod the state has ``2 d + 4`` coordinates (``d`` = 3 for a
free rod, fewer for a rod with a constrained node: position and velocity of its reference
point in the allowed directions, 2 tangent directions of ``b`` and 2 of ``b'``).

The state unknowns are eliminated by *variable projection*: for given parameters ``theta`` each
window's state is fitted by a batched Levenberg-Marquardt (all windows in one call), and
:func:`scipy.optimize.least_squares` minimises the remaining residual over ``theta`` alone with
the Jacobian ``(I - J_x J_x^+) J_theta`` per window (Kaufman's projection; ``J_x``: window
state, ``J_theta``: parameters). Every Jacobian is a forward finite difference, and all its
columns, for every window, are ONE batched :func:`~tensegrity_gym.integrators.step` call: copy
``c`` carries its own physical values through per-copy :class:`~tensegrity_gym.params.Params`
(W x (1 + p + n_state) copies). Positive quantities are fitted in log space:
``theta = log(value / initial)``, so a step of 0.01 is a 1 % change, the fit cannot make a
value negative, and ``mode="scale"`` fits one ``log`` factor per field.

Standard errors
---------------
``cov(theta) = sigma^2 (J^T J)^-1`` with the projected Jacobian ``J`` (the parameter block of
the inverse of the full normal matrix, i.e. the window states' uncertainty is accounted for)
and ``sigma^2 = SSR / (N_obs - p - W n_state)``, the residual variance per observed coordinate.
They are the 1-sigma errors of a locally linear, unbiased fit with independent Gaussian
position noise of the same size on every coordinate: they say how well the *record*
determines the values, not how wrong the *model* is (integrator error, unmodelled friction).
Standard errors in SI are ``value * se(theta)`` (first order). A parameter with a (near) zero
direction of ``J^T J`` (singular value of the column-scaled Jacobian below ``rank_rtol`` times
the largest, e.g. the damping of a string that never goes taut, anything when nothing moves)
is flagged ``identifiable = False`` with an infinite standard error, and the result is not
``ok``; a fit that stops without meeting its tolerances is ``converged = False``. Both also
raise a :class:`SysIdWarning`. A weak pull towards the starting values (rows
``rank_rtol |J| theta``) keeps the optimiser from wandering along such a flat direction; when
every direction turns out determined, the fit is polished without it (no bias).

Mass, stiffness and damping: string forces scale with stiffness and damping, weight and
inertia with mass, so a robot with all three scaled by one factor moves identically (gravity
and supports do not break this). Motion fixes the ratios; pass the weighed total rod mass
(``total_mass``, kg) and the rod masses are held to sum to it (their ratios are fitted).
Without it such a fit is flagged.

Units: SI throughout (s, m, kg, N/m, N s/m). ``jacobian="torch"`` computes the outer residual
Jacobian by forward-mode autograd through the torch backend's rollout instead
(:meth:`_Problem.torch_jacobian`, exact to round-off); the default stays the batched forward
differences (exact to ~1e-7 relative, one numba call per Jacobian), which are faster on CPU.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from . import dynamics as dyn
from .checks import check_real, load_npz, read_bounded
from .dynamics import Model, State
from .integrators import resolve, step
from .params import Params, default_params
from .statics import tangent_basis

__all__ = ["identify", "SysIdResult", "SysIdWarning", "FITTABLE", "load_csv", "load_trajectory"]

#: fittable field -> what its items are (positive quantities, fitted in log space)
FITTABLE = {"stiffness": "string", "damping": "string", "mass": "rod", "node_damping": "node"}
_ALIASES = {"rod_mass": "mass", "bar_mass": "mass"}
#: largest trajectory CSV read, bytes (counted while reading: a device or FIFO reports no size)
MAX_CSV_BYTES = 1 << 30
_UNITS = {"stiffness": "N/m", "damping": "N s/m", "mass": "kg", "node_damping": "N s/m"}

_EPS_THETA = 1e-6      # FD step in log space (relative change of a parameter)
_EPS_POS = 1e-6        # FD step of a position / direction coordinate, m or 1
_EPS_VEL = 1e-5        # FD step of a velocity coordinate, m/s or 1/s
_THETA_MAX = 5.0       # |log(value / initial)| is clipped here (a factor of 148)


class SysIdWarning(UserWarning):
    """A fit did not converge or a parameter is not identifiable from the record."""


# ----------------------------------------------------------------------------- result
@dataclass
class SysIdResult:
    """Outcome of :func:`identify` (SI units).

    ``values[f]``, ``initial[f]``, ``std_errors[f]``, ``identifiable[f]``: arrays over the items
    ``items[f]`` (string / rod / node indices) of each fitted field ``f``. ``scale[f]`` and
    ``scale_std_errors[f]``: the fitted factor of field ``f`` (``mode="scale"`` only).
    ``rms_m``: RMS node error over every observed coordinate after the fit (``rms_initial_m``:
    with the initial values, window states fitted). ``converged``: the optimiser met its
    tolerances and every window's state fit converged. ``ok``: converged and every fitted
    parameter identifiable. ``params``: the fitted :class:`Params` (one row)."""

    fields: tuple
    mode: str
    items: dict
    values: dict
    initial: dict
    std_errors: dict
    rel_std_errors: dict
    identifiable: dict
    scale: dict
    scale_std_errors: dict
    converged: bool
    rms_m: float
    rms_initial_m: float
    max_error_m: float
    message: str
    warnings: list
    n_windows: int
    samples_per_window: int
    window_s: float
    sample_dt_s: float
    dt_s: float
    n_substeps: int
    integrator: str
    n_observations: int
    n_state_unknowns: int
    nfev: int
    njev: int
    wall_s: float
    params: Params = field(repr=False, default=None)
    _plot: dict = field(repr=False, default=None)

    @property
    def ok(self) -> bool:
        return bool(self.converged and all(np.all(v) for v in self.identifiable.values()))

    def to_dict(self) -> dict:
        """JSON-ready summary (infinite standard errors as None)."""
        def arr(a):
            return [None if not np.isfinite(x) else float(x) for x in np.asarray(a, float)]
        out = {"ok": self.ok, "converged": self.converged, "message": self.message, "warnings": list(self.warnings),
               "mode": self.mode, "fields": list(self.fields), "units": {f: _UNITS[f] for f in self.fields},
               "items": {f: [int(i) for i in v] for f, v in self.items.items()},
               "values": {f: arr(v) for f, v in self.values.items()},
               "initial": {f: arr(v) for f, v in self.initial.items()},
               "std_errors": {f: arr(v) for f, v in self.std_errors.items()},
               "rel_std_errors": {f: arr(v) for f, v in self.rel_std_errors.items()},
               "identifiable": {f: [bool(x) for x in v] for f, v in self.identifiable.items()},
               "rms_m": self.rms_m, "rms_initial_m": self.rms_initial_m, "max_error_m": self.max_error_m,
               "n_windows": self.n_windows, "samples_per_window": self.samples_per_window,
               "window_s": self.window_s, "sample_dt_s": self.sample_dt_s, "dt_s": self.dt_s,
               "n_substeps": self.n_substeps, "integrator": self.integrator,
               "n_observations": self.n_observations, "n_state_unknowns": self.n_state_unknowns,
               "nfev": self.nfev, "njev": self.njev, "wall_s": self.wall_s,
               "gradient": "batched forward finite differences (per-copy Params)"}
        if self.mode == "scale":
            out["scale"] = {f: float(v) for f, v in self.scale.items()}
            out["scale_std_errors"] = {f: (None if not np.isfinite(v) else float(v))
                                       for f, v in self.scale_std_errors.items()}
        return out

    def plot(self, path=None, nodes=None, max_nodes: int = 3):
        """Recorded (dots) vs fitted (lines, one segment per shooting window) displacements of
        node coordinates from their mean over the record, mm, for the ``max_nodes`` tracked nodes
        that move most (or the given ``nodes``), and the RMS error per sample. Writes a PNG to
        ``path`` if given; returns the matplotlib figure (Agg)."""
        import matplotlib
        if matplotlib.get_backend().lower() not in ("agg", "module://matplotlib_inline.backend_inline"):
            matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        d = self._plot
        t, rec, fit, mask = d["t"], d["recorded"], d["fitted"], d["mask"]   # (W,K), (W,K,n,3) ...
        recn = np.where(mask[..., None], rec, np.nan)
        mean = np.nanmean(recn, axis=(0, 1))                                   # (n, 3)
        span = np.nan_to_num(np.nanmax(recn, axis=(0, 1)) - np.nanmin(recn, axis=(0, 1)), nan=-1.0).max(1)
        show = list(np.argsort(-span)[:max_nodes]) if nodes is None else [int(i) for i in nodes]
        fig, ax = plt.subplots(len(show) + 1, 1, figsize=(10, 2.2 * (len(show) + 1)), sharex=True, squeeze=False)
        ax = ax[:, 0]
        colors = ("tab:blue", "tab:orange", "tab:green")
        for a, i in zip(ax, show):
            for c in range(3):
                for w in range(t.shape[0]):
                    mk = mask[w, :, i]
                    a.plot(t[w][mk], 1e3 * (rec[w, mk, i, c] - mean[i, c]), ".", ms=2, color=colors[c],
                           label=f"{'xyz'[c]} recorded" if w == 0 else None)
                    a.plot(t[w], 1e3 * (fit[w, :, i, c] - mean[i, c]), "-", lw=1, color="k", alpha=0.7,
                           label="fitted" if (w == 0 and c == 0) else None)
            a.set_ylabel(f"node {i} [mm]")
        ax[0].legend(loc="upper right", ncol=4, fontsize=7)
        err = np.where(mask[..., None], fit - rec, np.nan)
        rms = np.sqrt(np.nanmean(err ** 2, axis=(2, 3)))
        for w in range(t.shape[0]):
            ax[-1].plot(t[w], rms[w] * 1e3, "-", color="tab:red", lw=1)
        ax[-1].set(ylabel="RMS error [mm]", xlabel="t [s]")
        ax[0].set_title(f"recorded vs fitted ({self.n_windows} shooting windows of {self.window_s:g} s); "
                        f"RMS {self.rms_m * 1e3:.3g} mm")
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=100)
        return fig


# ----------------------------------------------------------------------------- input checks
def _model_of(structure_or_model) -> Model:
    if isinstance(structure_or_model, Model):
        return structure_or_model
    from . import load_structure
    return dyn.compile_model(load_structure(structure_or_model))


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
    if initial:
        base = base.replace(**initial)
    items, init = {}, {}
    for g in names:
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
            raise ValueError(f"initial: {g} of {FITTABLE[g]} {bad[0]} starts at {float(vals[bad[0]])!r} {_UNITS[g]}; it is "
                             f"fitted in log space and needs a positive starting value (pass initial={{{g!r}: ...}})")
        items[g], init[g] = idx, vals[idx].copy()
    return names, items, init, base


# ----------------------------------------------------------------------------- state coordinates
class _Problem:
    """The multiple-shooting problem: windows, their state coordinates, batched simulation."""

    def __init__(self, model, t, rec, mask, rl, h, names, items, init, base, mode, window, integrator, dt,
                 stride, total_mass=None):
        self.model, self.names, self.items, self.init, self.base, self.mode = model, names, items, init, base, mode
        self.integrator = resolve(integrator).name
        if self.integrator in ("dop853", "radau"):
            raise ValueError(f"integrator: {integrator!r} is adaptive (copy-by-copy solve_ivp, far too slow for the "
                             f"thousands of copies of a Jacobian); use 'rk4' or 'semi_implicit_euler'")
        stride = int(stride)
        if stride < 1:
            raise ValueError(f"stride: must be a positive integer, got {stride}")
        t, rec, mask = t[::stride], rec[::stride], mask[::stride]
        rl = None if rl is None else rl[::stride]
        h = h * stride
        if not (np.isfinite(window) and window > 0):
            raise ValueError(f"window: must be a positive duration in s, got {window!r}")
        K = int(round(window / h)) + 1
        if K < 3:
            raise ValueError(f"window: {window} s holds fewer than 3 samples at a spacing of {h:.6g} s")
        S = t.size
        W = S // K
        if W < 1:
            raise ValueError(f"window: {window} s ({K} samples) is longer than the record ({S} samples, "
                             f"{t[-1] - t[0]:.6g} s)")
        if dt is None:
            om = dyn.stable_step_estimate(model)["omega_max"]
            dt_max = 0.2 / om if np.isfinite(om) and om > 0 else h
            n_sub = max(1, math.ceil(h / dt_max - 1e-9))
        else:
            if not (np.isfinite(dt) and dt > 0):
                raise ValueError(f"dt: must be a positive time step in s, got {dt!r}")
            n_sub = max(1, int(round(h / dt)))
        self.n_sub, self.dt, self.h, self.K, self.W = n_sub, h / n_sub, h, K, W
        sl = slice(0, W * K)
        self.t = t[sl].reshape(W, K)
        self.rec = rec[sl].reshape(W, K, model.n_nodes, 3)
        self.mask = mask[sl].reshape(W, K, model.n_nodes)
        self.rl = None if rl is None else rl[sl].reshape(W, K, model.n_strings)
        self.n_obs = int(self.mask.sum()) * 3
        empty = np.flatnonzero(~self.mask.any(axis=(1, 2)))
        if empty.size:
            raise ValueError(f"nodes: window {empty[0]} (t = {self.t[empty[0], 0]:.6g} s) has no tracked node")
        # state coordinates per rod: r (d), b tangent (2), rd (d), bd tangent (2)
        self.E = []
        for j in range(model.n_bars):
            w_, v_ = np.linalg.eigh(model.proj[j])
            self.E.append(v_[:, w_ > 0.5])
        self.ns = sum(2 * E.shape[1] + 4 for E in self.E)
        eps = []
        for E in self.E:
            d = E.shape[1]
            eps += [_EPS_POS] * (d + 2) + [_EPS_VEL] * (d + 2)
        self.eps_x = np.array(eps)
        # parameter vector
        self.total_mass = total_mass
        self.slices, p = {}, 0
        for g in names:
            n_ = len(items[g]) if mode == "per_member" else 1
            if g == "mass" and total_mass is not None:
                n_ -= 1          # the weighed total fixes the common scale: rod 0's share is the reference
            self.slices[g] = slice(p, p + n_)
            p += n_
        if p == 0:
            raise ValueError("fit: nothing left to fit (the total mass fixes a single mass or the mass scale)")
        self.p = p
        dof = self.n_obs - p - W * self.ns
        if dof < 1:
            raise ValueError(f"record: {self.n_obs} observed coordinates are too few for {p} parameters and "
                             f"{W} x {self.ns} window-state unknowns; track more nodes or use longer windows")
        self.dof = dof
        self.nfev = self.njev = 0
        self.jacobian = "fd"
        self.inner_ok = True

    # -- parameters
    def log_factors(self, thetas: np.ndarray) -> dict:
        """{field: (C, n_items) log(value / initial)} for parameter rows ``thetas`` (C, p)."""
        out = {}
        for g in self.names:
            # a bounded step: an unidentifiable direction must not run off to exp(700)
            th = np.clip(thetas[:, self.slices[g]], -_THETA_MAX, _THETA_MAX)
            n_ = len(self.items[g])
            if g == "mass" and self.total_mass is not None:
                th = np.concatenate([np.zeros((th.shape[0], 1)), th], axis=1) if self.mode == "per_member" \
                    else np.zeros((th.shape[0], 1))
                raw = self.init[g][None] * np.exp(np.broadcast_to(th, (th.shape[0], n_)))
                out[g] = np.log(self.total_mass / raw.sum(1, keepdims=True)) + np.broadcast_to(th, raw.shape)
            else:
                out[g] = np.broadcast_to(th, (th.shape[0], n_))
        return out

    def log_jacobian(self, theta) -> dict:
        """{field: (n_items, p) d log(value) / d theta} (forward differences of :meth:`log_factors`;
        exact for every field but a total-mass-normalised mass, where it is linear to 1e-7)."""
        base = self.log_factors(theta[None])
        th = np.repeat(theta[None], self.p, 0) + 1e-7 * np.eye(self.p)
        pert = self.log_factors(th)
        return {g: ((pert[g] - base[g]) / 1e-7).T for g in self.names}

    def params(self, thetas: np.ndarray) -> Params:
        """Params with one row per row of ``thetas`` (C, p)."""
        thetas = np.atleast_2d(thetas)
        C = thetas.shape[0]
        lf = self.log_factors(thetas)
        vals = {}
        for g in self.names:
            full = np.repeat(getattr(self.base, g), C, axis=0)
            full[:, self.items[g]] = self.init[g][None] * np.exp(lf[g])
            vals[g] = full
        return self.base.replace(**vals)

    def values(self, theta) -> dict:
        lf = self.log_factors(theta[None])
        return {g: self.init[g] * np.exp(lf[g][0]) for g in self.names}

    # -- states
    def apply(self, q0, qd0, x):
        """States (C, k, 6) from bases ``q0``, ``qd0`` and coordinates ``x`` (C, ns)."""
        r, b = q0[..., :3].copy(), q0[..., 3:]
        rd, bd = qd0[..., :3].copy(), qd0[..., 3:].copy()
        T = tangent_basis(b)
        t1, t2 = T[..., 0], T[..., 1]
        bn = b.copy()
        o = 0
        for j, E in enumerate(self.E):
            d = E.shape[1]
            r[:, j] += x[:, o:o + d] @ E.T
            bn[:, j] += x[:, o + d, None] * t1[:, j] + x[:, o + d + 1, None] * t2[:, j]
            o += d + 2
            rd[:, j] += x[:, o:o + d] @ E.T
            bd[:, j] += x[:, o + d, None] * t1[:, j] + x[:, o + d + 1, None] * t2[:, j]
            o += d + 2
        bn /= np.linalg.norm(bn, axis=-1, keepdims=True)
        return dyn.project(self.model, np.concatenate([r, bn], -1), np.concatenate([rd, bd], -1))

    def simulate(self, q, qd, params, win):
        """Node positions (C, K, n, 3) of copies starting at ``q``, ``qd`` (C, k, 6); copy c lies in
        window ``win[c]`` (for the rest lengths). Non-finite results come back as NaN."""
        C = q.shape[0]
        out = np.empty((C, self.K, self.model.n_nodes, 3))
        out[:, 0] = dyn.node_positions(self.model, q)
        st = State(q=q, qd=qd)
        with np.errstate(all="ignore"):
            for k in range(1, self.K):
                rl = None if self.rl is None else self.rl[win, k - 1]
                try:
                    st = step(self.model, st, self.dt, self.integrator, n_steps=self.n_sub, params=params,
                              rest_length=rl)
                except (ZeroDivisionError, OverflowError, FloatingPointError):
                    out[:, k:] = np.nan
                    break
                out[:, k] = dyn.node_positions(self.model, st.q)
        return out

    def residual(self, sim, win):
        """(C, K*n*3) masked residuals of simulated node positions of copies in windows ``win``."""
        r = (sim - self.rec[win]) * self.mask[win][..., None]
        return r.reshape(r.shape[0], -1)

    # -- data-based initial guess of every window's state
    def guess(self):
        model, W, K = self.model, self.W, self.K
        n = model.n_nodes
        ref = model.structure.nodes
        L = min(K, 5)
        tau = np.arange(L) * self.h
        V = np.stack([np.ones(L), tau, tau ** 2], 1)
        Nw = self.rec[:, :L]                     # (W, L, n, 3)
        Mw = self.mask[:, :L]
        pos = Nw[:, 0].copy()
        vel = np.zeros((W, n, 3))
        pinv = np.linalg.pinv(V)                 # (3, L)
        full = Mw.all(axis=1)                    # nodes tracked at all L first samples
        vel_fit = np.einsum("l,wlnc->wnc", pinv[1], Nw)
        pos_fit = np.einsum("l,wlnc->wnc", pinv[0], Nw)
        vel[full] = vel_fit[full]
        pos[full] = pos_fit[full]
        for w in range(W):
            miss = ~Mw[w, 0]
            miss[model.anchor_idx] = False
            if not miss.any():
                continue
            trk = np.flatnonzero(Mw[w, 0])
            if trk.size >= 3:
                R0, c0, cr = _kabsch(ref[trk], Nw[w, 0, trk])
                pos[w, miss] = (ref[miss] - cr) @ R0.T + c0
                trk1 = np.flatnonzero(Mw[w, 1])
                if trk1.size >= 3:
                    R1, c1, cr1 = _kabsch(ref[trk1], Nw[w, 1, trk1])
                    vel[w, miss] = (((ref[miss] - cr1) @ R1.T + c1) - pos[w, miss]) / self.h
            else:
                pos[w, miss] = ref[miss]
        st = dyn.initial_state(model, W, nodes=pos, velocities=vel)
        q, qd = st.q.copy(), st.qd.copy()
        free = ~np.asarray(model.constrained)
        sig = model.sigma[None, free, None]
        a, c = model.rod_a[free], model.rod_c[free]
        q[:, free, :3] = pos[:, a] + sig * (pos[:, c] - pos[:, a])
        qd[:, free, :3] = vel[:, a] + sig * (vel[:, c] - vel[:, a])
        return dyn.project(model, q, qd)

    # -- inner problem: every window's state for given parameters (batched Levenberg-Marquardt)
    def fit_states(self, theta, q0, qd0, max_iter=30, Jx_old=None):
        W, ns = self.W, self.ns
        win = np.arange(W)
        P1 = self.params(theta)
        lam = np.full(W, 1e-3)
        sim = self.simulate(q0, qd0, P1, win)
        res = self.residual(sim, win)
        cost = np.where(np.isfinite(res).all(1), np.einsum("wi,wi->w", res, res), np.inf)
        if not np.isfinite(cost).all():
            return q0, qd0, res, False
        converged = np.zeros(W, bool)
        for it in range(max_iter):
            act = np.flatnonzero(~converged)
            if act.size == 0:
                break
            if Jx_old is not None and it < 3:
                Jx = Jx_old[act]           # the last Jacobian (states and parameters moved little)
            else:
                Jx = self.state_jacobian(q0[act], qd0[act], P1, act, sim[act])      # (A, R, ns)
            A = np.einsum("ari,arj->aij", Jx, Jx)
            g = np.einsum("ari,ar->ai", Jx, res[act])
            dA = np.einsum("aii->ai", A)
            for _ in range(12):
                M = A + (lam[act, None] * (dA + 1e-12 * dA.max(1, keepdims=True)))[:, :, None] * np.eye(ns)
                dx = -np.linalg.solve(M, g[..., None])[..., 0]
                qn, qdn = self.apply(q0[act], qd0[act], dx)
                sim_n = self.simulate(qn, qdn, P1, act)
                res_n = self.residual(sim_n, act)
                cost_n = np.where(np.isfinite(res_n).all(1), np.einsum("wi,wi->w", res_n, res_n), np.inf)
                better = cost_n <= cost[act]
                step_small = np.abs(dx / self.eps_x).max(1) < 1e-3     # below 1/1000 of an FD step
                rel = (cost[act] - cost_n) <= 1e-12 * cost[act] + 1e-30
                done = step_small | (better & rel)
                ai = act[better]
                q0 = q0.copy(); qd0 = qd0.copy(); sim = sim.copy(); res = res.copy()
                q0[ai], qd0[ai], sim[ai], res[ai], cost[ai] = qn[better], qdn[better], sim_n[better], \
                    res_n[better], cost_n[better]
                lam[ai] = np.maximum(lam[ai] / 5, 1e-9)
                lam[act[~better]] *= 8
                converged[act[done]] = True
                # keep iterating LM only on windows that did not improve
                if better.all():
                    break
                keep = ~better
                act, A, g, dA = act[keep], A[keep], g[keep], dA[keep]
            if np.all(lam > 1e12):
                break
        return q0, qd0, res, bool(converged.all())

    def state_jacobian(self, q0, qd0, P, win, sim0):
        """(A, R, ns) forward-difference Jacobian of the residual of windows ``win`` w.r.t. their
        state coordinates: one batched simulation of A x ns copies."""
        A, ns = q0.shape[0], self.ns
        X = np.repeat(np.diag(self.eps_x)[None], A, axis=0).reshape(A * ns, ns)
        qp, qdp = self.apply(np.repeat(q0, ns, 0), np.repeat(qd0, ns, 0), X)
        simp = self.simulate(qp, qdp, P, np.repeat(win, ns)).reshape((A, ns) + sim0.shape[1:])
        d = (simp - sim0[:, None]) * self.mask[win][:, None, ..., None] / self.eps_x[None, :, None, None, None]
        return d.reshape(A, ns, -1).transpose(0, 2, 1)

    def full_jacobian(self, theta, q0, qd0, sim0):
        """Projected parameter Jacobian (W, R, p) and the state Jacobian (W, R, ns): one batched
        call of W x (p + ns) copies with per-copy parameters (``jacobian="fd"``), or forward-mode
        autograd through the torch backend's rollout (``jacobian="torch"``, :meth:`torch_jacobian`)."""
        W, ns, p = self.W, self.ns, self.p
        if self.jacobian == "torch":
            d = self.torch_jacobian(theta, q0, qd0)
        else:
            thetas = np.repeat(theta[None], p + ns, 0)
            thetas[np.arange(p), np.arange(p)] += _EPS_THETA
            X = np.zeros((p + ns, ns))
            X[p + np.arange(ns), np.arange(ns)] = self.eps_x
            P = self.params(np.tile(thetas, (W, 1)))
            qp, qdp = self.apply(np.repeat(q0, p + ns, 0), np.repeat(qd0, p + ns, 0), np.tile(X, (W, 1)))
            win = np.repeat(np.arange(W), p + ns)
            simp = self.simulate(qp, qdp, P, win).reshape((W, p + ns) + sim0.shape[1:])
            scale = np.concatenate([np.full(p, _EPS_THETA), self.eps_x])
            d = (simp - sim0[:, None]) * self.mask[:, None, ..., None] / scale[None, :, None, None, None]
            d = d.reshape(W, p + ns, -1).transpose(0, 2, 1)
        Jt, Jx = d[..., :p], d[..., p:]
        # Kaufman's variable projection: remove what the window state can absorb
        G = np.einsum("wri,wrj->wij", Jx, Jx)
        Gi = np.linalg.pinv(G, rcond=1e-12, hermitian=True)
        proj = Jt - np.einsum("wri,wij,wjs,wsp->wrp", Jx, Gi, Jx.transpose(0, 2, 1), Jt, optimize=True)
        return proj, Jx


    def torch_jacobian(self, theta, q0, qd0):
        """(W, R, p + ns) masked residual Jacobian of every window with respect to the
        parameters ``theta`` and the window state coordinates (at ``x = 0``), by autograd through
        the torch backend's float64 rollout (:func:`tensegrity_gym.torch_backend.step`: the same
        equations as the NumPy/numba path). As the finite differences, all columns of all
        windows come from ONE batched rollout of W x (n_u + ns) copies, copy ``c`` carrying the
        tangent of one column (its own per-copy parameters): Jacobian-vector products by the
        double-backward trick (``u -> (du/dz)^T``, then its derivative along the tangent; copies
        are independent, so one pair of backward passes gives every column). The columns are
        exact derivatives instead of differences. (torch's forward-mode AD computes the same
        numbers but ran 30-100x slower per operation on CPU with torch 2.13.) They are taken
        with respect to the log values of the fitted items and chained with :meth:`log_jacobian`
        (d log value / d theta)."""
        import torch
        from . import torch_backend as tb
        W, ns, p, K = self.W, self.ns, self.p, self.K
        T = torch.float64
        tm = tb.torch_model(self.model, torch.device("cpu"), T)
        sizes = [len(self.items[g]) for g in self.names]
        nu = sum(sizes)
        nc = nu + ns                                  # columns per window
        C = W * nc

        def t_(x):
            return torch.as_tensor(np.array(x, dtype=float), dtype=T)
        LJ = self.log_jacobian(theta)                 # {field: (n_items, p)}
        lf0 = self.log_factors(theta[None])            # {field: (1, n_items)}
        fields = ["mass", "stiffness", "damping", "rest_length", "node_damping", "gravity", "anchor_pos"]
        if "mass" not in self.names:                  # a fitted mass scales f and J (torch_params)
            fields += ["f", "J"]
        prm = {f: t_(getattr(self.base, f)) for f in fields}
        with torch.enable_grad():
            z = torch.zeros((C, nc), dtype=T, requires_grad=True)
            o = 0
            for g, sz in zip(self.names, sizes):      # value = init * exp(log factor + u)
                val = t_(self.init[g])[None] * torch.exp(t_(lf0[g]) + z[:, o:o + sz])
                idx = torch.as_tensor(np.asarray(self.items[g], dtype=np.int64))
                prm[g] = prm[g].expand(C, -1).index_copy(1, idx, val)
                o += sz
            x = z[:, nu:]
            # window states as _Problem.apply (tangent basis at the base state)
            q0c, qd0c = np.repeat(q0, nc, 0), np.repeat(qd0, nc, 0)
            T0 = tangent_basis(q0c[..., 3:])
            t1, t2 = t_(T0[..., 0]), t_(T0[..., 1])
            q0t, qd0t = t_(q0c), t_(qd0c)
            rs, bs, rds, bds, o = [], [], [], [], 0
            for j, E in enumerate(self.E):
                d, Et = E.shape[1], t_(E.T)
                rs.append(q0t[:, j, :3] + x[:, o:o + d] @ Et)
                bn = q0t[:, j, 3:] + x[:, o + d, None] * t1[:, j] + x[:, o + d + 1, None] * t2[:, j]
                bs.append(bn / torch.sqrt((bn * bn).sum(-1, keepdim=True)))
                o += d + 2
                rds.append(qd0t[:, j, :3] + x[:, o:o + d] @ Et)
                bds.append(qd0t[:, j, 3:] + x[:, o + d, None] * t1[:, j] + x[:, o + d + 1, None] * t2[:, j])
                o += d + 2
            q, qd = tb.project(tm, torch.cat([torch.stack(rs, 1), torch.stack(bs, 1)], -1),
                               torch.cat([torch.stack(rds, 1), torch.stack(bds, 1)], -1))
            node_prm = tb.torch_params(tm, prm, C)
            rl = None if self.rl is None else t_(np.repeat(self.rl, nc, 0))     # (C, K, m)
            out = [tb.node_positions(tm, q, node_prm)]
            for k in range(1, K):
                q, qd = tb.step(tm, q, qd, self.dt, self.integrator, self.n_sub, params=prm,
                                rest_length=None if rl is None else rl[:, k - 1])
                out.append(tb.node_positions(tm, q, node_prm))
            out = torch.stack(out, 1)                                    # (C, K, n, 3)
            u = torch.zeros_like(out, requires_grad=True)
            (g,) = torch.autograd.grad(out, z, grad_outputs=u, create_graph=True)       # u^T dout/dz, (C, nc)
            (jv,) = torch.autograd.grad(g, u, grad_outputs=torch.eye(nc, dtype=T).repeat(W, 1))
        d = jv.detach().numpy().reshape((W, nc) + self.rec.shape[1:])
        d = (d * self.mask[:, None, ..., None]).reshape(W, nc, -1).transpose(0, 2, 1)   # (W, R, nc)
        Jth = np.zeros(d.shape[:2] + (p,))
        o = 0
        for g, sz in zip(self.names, sizes):         # chain rule: d/d theta = d/d log value . d log value/d theta
            Jth += d[..., o:o + sz] @ LJ[g]
            o += sz
        return np.concatenate([Jth, d[..., nu:]], axis=-1)


def _kabsch(src, dst):
    """Rotation R, centroid of dst and centroid of src with dst ~ (src - c_src) R^T + c_dst."""
    cs, cd = src.mean(0), dst.mean(0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T, cd, cs


# ----------------------------------------------------------------------------- main entry
def identify(structure_or_model, t, nodes, fit=("stiffness", "damping", "mass"), mode: str = "per_member", *,
             rest_length=None, node_mask=None, window: float = 0.2, integrator: str = "rk4", dt=None,
             stride: int = 1, initial=None, total_mass=None, max_nfev: int = 60, rank_rtol: float = 1e-4,
             verbose: int = 0, jacobian: str = "fd") -> SysIdResult:
    """Fit physical parameters so that simulated motion matches a recorded one (see module doc).

    Parameters
    ----------
    structure_or_model : Structure, built-in name, JSON path or compiled Model. Its values are
        the starting point of the fit (and the fixed values of everything not fitted).
    t : (S,) sample times, s, strictly increasing and evenly spaced.
    nodes : (S, n, 3) recorded node positions, m (NaN allowed where ``node_mask`` is False).
    fit : names of the fitted fields: ``"stiffness"`` (per string, N/m), ``"damping"`` (per
        string, N s/m), ``"mass"`` (alias ``"rod_mass"``; per rod, kg), ``"node_damping"``
        (per node, N s/m). Force-density-actuated strings and anchors are never fitted.
    mode : ``"per_member"`` (one value per string / rod / node) or ``"scale"`` (one factor
        per field multiplying the starting values).
    rest_length : (S, m) recorded rest lengths, m, for actuated cables; held constant over each
        sample interval at the interval's first value. Default: the structure's.
    node_mask : tracked nodes: node indices, a bool (n,) array or a bool (S, n) array (dropped
        frames). Default: every node, every sample.
    window : shooting window length, s. integrator : ``"rk4"`` (default) or
        ``"semi_implicit_euler"``/``"implicit_euler"``. dt : fit step, s, rounded so that it
        divides the sample spacing (default: ``0.2 / omega_max`` of the structure or the spacing).
    stride : fit every ``stride``-th sample only (the fit step is unchanged).
    initial : {field: value or per-item array} starting values replacing the structure's.
    total_mass : the structure's weighed total rod mass, kg. Motion alone cannot tell a robot
        from one with every mass, stiffness and damping scaled by the same factor (weight scales
        with mass too), so fitting ``mass`` together with ``stiffness``/``damping`` needs one
        absolute number: with ``total_mass`` the fitted rod masses are held to sum to it (their
        ratios are fitted). Without it such a fit is flagged unidentifiable.
    max_nfev : most evaluations of the outer least-squares problem.
    rank_rtol : singular values of the (column-scaled) projected Jacobian below ``rank_rtol``
        times the largest mark the directions as unidentifiable.
    jacobian : how the outer problem's residual Jacobian (parameters and window states) is
        computed: ``"fd"`` (default: batched forward differences, one numba call) or ``"torch"``
        (forward-mode autograd through the torch backend's float64 rollout, exact to round-off;
        needs PyTorch and ``integrator`` ``"rk4"`` or ``"semi_implicit_euler"``). The two agree
        to ~1e-6 relative; fd stays the default because it is faster on CPU
        (``docs/sysid.md``). The inner window-state fits use forward differences either way.

    Returns a :class:`SysIdResult`. Raises ValueError naming the field for bad input.
    """
    from scipy.optimize import least_squares
    t0 = time.perf_counter()
    check_real(t, "t", "sample times, s")          # before anything else: NumPy would drop the imaginary part
    check_real(nodes, "nodes", "node positions, m")
    model = _model_of(structure_or_model)
    names, items, init, base = _parse_fit(model, fit, mode, initial)
    t, rec, mask, rl, h = _check_record(model, t, nodes, rest_length, node_mask)
    if total_mass is not None:
        if "mass" not in names:
            raise ValueError("total_mass: only used when 'mass' is fitted")
        if not (np.isfinite(total_mass) and total_mass > 0):
            raise ValueError(f"total_mass: must be a positive mass in kg, got {total_mass!r}")
        total_mass = float(total_mass)
    if jacobian not in ("fd", "torch"):
        raise ValueError(f"jacobian: expected 'fd' or 'torch', got {jacobian!r}")
    if jacobian == "torch":
        try:
            import torch  # noqa: F401
        except ImportError:
            raise ValueError("jacobian: 'torch' needs PyTorch (pip install 'tensegrity_gym[torch]'); "
                             "use jacobian='fd'") from None
        if resolve(integrator).name not in ("rk4", "semi_implicit_euler"):
            raise ValueError(f"jacobian: 'torch' supports integrator 'rk4' or 'semi_implicit_euler', "
                             f"got {resolve(integrator).name!r}; use jacobian='fd'")
    pb = _Problem(model, t, rec, mask, rl, h, names, items, init, base, mode, float(window), integrator, dt, stride,
                  total_mass)
    if jacobian == "torch":
        pb.jacobian = "torch"
    q0, qd0 = pb.guess()
    cache = {"key": None}

    def solve(theta):
        key = theta.tobytes()
        if cache["key"] != key:
            q, qd = cache.get("q", q0), cache.get("qd", qd0)
            q, qd, res, ok = pb.fit_states(theta, q, qd, Jx_old=cache.get("Jx"))
            if not np.isfinite(res).all():   # a trial step that blew up: restart states from the data
                q, qd, res, ok = pb.fit_states(theta, q0, qd0)
            cache.update(key=key, q=q, qd=qd, res=res, ok=ok)
            pb.nfev += 1
        return cache

    reg = {"lam": 0.0}

    def fun(theta):
        c = solve(theta)
        r = c["res"].ravel()
        return np.concatenate([np.where(np.isfinite(r), r, 1e3),   # a diverged copy: large, finite
                               reg["lam"] * theta])

    def jac(theta):
        c = solve(theta)
        if c.get("Jp_key") != c["key"]:
            sim = pb.simulate(c["q"], c["qd"], pb.params(theta), np.arange(pb.W))
            Jp, Jx = pb.full_jacobian(theta, c["q"], c["qd"], sim)
            pb.njev += 1
            c.update(Jp=Jp, Jp_key=c["key"])
            cache["Jx"] = Jx
        J = np.where(np.isfinite(c["Jp"]), c["Jp"], 0.0).reshape(-1, pb.p)
        return np.concatenate([J, reg["lam"] * np.eye(pb.p)])

    theta0 = np.zeros(pb.p)
    r0 = fun(theta0)[:-pb.p]
    rms0 = float(np.sqrt(np.sum(r0 ** 2) / max(pb.n_obs, 1)))
    # a weak pull towards the starting values (rows lam * theta, lam = rank_rtol x the largest
    # column norm): it keeps a flat (unidentifiable) direction where it started instead of letting
    # the optimiser wander along it. When the fit then finds every direction determined, it is
    # polished without the pull (which would shift a parameter of relative singular value s by
    # ~(rank_rtol / s)^2 of its change).
    reg["lam"] = rank_rtol * float(np.linalg.norm(jac(theta0)[:-pb.p], axis=0).max())
    warn_list = []

    def run(theta_start):
        try:
            # 'lm' (MINPACK): its QR of the tall Jacobian runs in its own loops (BLAS threads on a
            # loaded machine made trf's SVD of the same matrix 20x slower)
            sol = least_squares(fun, theta_start, jac=jac, method="lm", x_scale=1.0, ftol=1e-10, xtol=1e-8,
                                gtol=1e-10, max_nfev=max_nfev, verbose=verbose)
            return sol.x, sol.status, sol.message
        except (np.linalg.LinAlgError, ValueError) as e:
            return theta_start, -1, f"optimiser failed: {e}"

    def assess(theta):
        """Projected Jacobian at ``theta`` and which parameters it determines (log coordinates)."""
        solve(theta)
        jac(theta)
        Jp = cache["Jp"].reshape(-1, pb.p)
        G = Jp.T @ Jp
        colnorm = np.sqrt(np.diag(G))
        scale = np.where(colnorm > 0, colnorm, 1.0)
        ev, V = np.linalg.eigh(G / np.outer(scale, scale))     # singular values^2 of the column-scaled Jacobian
        sv = np.sqrt(np.clip(ev, 0, None))
        smax = sv.max() if sv.size and sv.max() > 0 else 0.0
        null = (sv <= rank_rtol * smax) if smax > 0 else np.ones_like(sv, bool)
        ident = np.ones(pb.p, bool)
        ident[colnorm <= 1e-12 * max(colnorm.max(), 1e-300)] = False
        for v in V.T[null]:
            u = v / scale                      # the flat direction in log coordinates (relative changes)
            ident[np.abs(u) > 0.01 * np.abs(u).max()] = False
        return Jp, ident

    theta, status, message = run(theta0)
    Jp, ident = assess(theta)
    if status > 0 and ident.all():
        # every direction is determined: polish without the pull, so it biases nothing
        reg["lam"] = 0.0
        theta, status, message = run(theta)
        Jp, ident = assess(theta)
    c = cache
    inner_ok = bool(c["ok"])
    res = c["res"]
    ssr = float(np.sum(res ** 2))
    rms = float(np.sqrt(ssr / pb.n_obs))
    converged = bool(status > 0 and inner_ok and np.isfinite(res).all() and np.isfinite(Jp).all())
    if not inner_ok:
        message += "; the window-state fits did not all converge"
    sigma2 = ssr / pb.dof
    cov = np.full((pb.p, pb.p), np.inf)
    if ident.any():
        Ji = Jp[:, ident]
        cov_i = sigma2 * np.linalg.pinv(Ji.T @ Ji, rcond=rank_rtol ** 2, hermitian=True)
        ii = np.flatnonzero(ident)
        cov[np.ix_(ii, ii)] = cov_i
    vals = pb.values(theta)
    LJ = pb.log_jacobian(theta)
    covf = np.where(np.isfinite(cov), cov, 0.0)
    values, std, rel, idf, scl, scl_se = {}, {}, {}, {}, {}, {}
    for g in names:
        values[g] = vals[g]
        Gg = LJ[g]                                  # (n_items, p): d log value / d theta
        dep = np.abs(Gg) > 1e-9
        idf[g] = ~np.any(dep & ~ident[None], axis=1)
        var = np.einsum("ip,pq,iq->i", Gg, covf, Gg)
        rel[g] = np.where(idf[g], np.sqrt(np.abs(var)), np.inf)
        std[g] = values[g] * rel[g]
        if mode == "scale":
            scl[g] = float(values[g][0] / init[g][0])
            scl_se[g] = float(scl[g] * rel[g][0])
    bad = [f"{g} {FITTABLE[g]} {i}" for g in names for i, ok in zip(items[g], idf[g]) if not ok]
    if bad:
        warn_list.append("not identifiable from this record (flat or degenerate directions of the residual; "
                         "infinite standard error): " + ", ".join(bad))
    if not converged:
        warn_list.append(f"the fit did not converge: {message}")
    for w_ in warn_list:
        warnings.warn(w_, SysIdWarning, stacklevel=2)
    fitted_params = pb.params(theta)
    sim = pb.simulate(c["q"], c["qd"], fitted_params, np.arange(pb.W))
    err = np.linalg.norm(sim - pb.rec, axis=-1)[pb.mask]
    return SysIdResult(
        fields=tuple(names), mode=mode, items={g: items[g].copy() for g in names}, values=values, initial=init,
        std_errors=std, rel_std_errors=rel, identifiable=idf, scale=scl, scale_std_errors=scl_se,
        converged=converged, rms_m=rms, rms_initial_m=rms0, max_error_m=float(err.max()) if err.size else 0.0,
        message=str(message), warnings=warn_list, n_windows=pb.W, samples_per_window=pb.K,
        window_s=(pb.K - 1) * pb.h, sample_dt_s=pb.h, dt_s=pb.dt, n_substeps=pb.n_sub, integrator=pb.integrator,
        n_observations=pb.n_obs, n_state_unknowns=pb.W * pb.ns, nfev=pb.nfev, njev=pb.njev,
        wall_s=time.perf_counter() - t0, params=fitted_params,
        _plot={"t": pb.t, "recorded": pb.rec, "fitted": sim, "mask": pb.mask})


# ----------------------------------------------------------------------------- file input
def load_csv(path, n_nodes: int):
    """Read a long-format motion-capture CSV: a header line with the columns ``t,node,x,y,z``
    (any order, extra columns ignored), one row per tracked node per sample; ``t`` in s,
    ``node`` the 0-based node index of the structure, ``x,y,z`` in m. A node missing from a
    sample (no row, or NaN coordinates) is untracked at that sample.

    Returns ``t`` (S,), ``nodes`` (S, n_nodes, 3) with NaN where untracked, and the mask
    (S, n_nodes). Raises ValueError naming the line for bad rows."""
    import csv
    import io
    text = read_bounded(path, MAX_CSV_BYTES, "trajectory CSV")     # a BOM is dropped; /dev/zero, FIFOs refused
    with io.StringIO(text, newline="") as fh:
        rd = csv.reader(fh)
        try:
            header = [h.strip().lower() for h in next(rd)]
        except StopIteration:
            raise ValueError(f"{path}: empty CSV file") from None
        need = ("t", "node", "x", "y", "z")
        miss = [c for c in need if c not in header]
        if miss:
            raise ValueError(f"{path}: missing column(s) {miss}; expected a header with t,node,x,y,z")
        col = [header.index(c) for c in need]
        rows = []
        for ln, row in enumerate(rd, start=2):
            if not row or all(not x.strip() for x in row):
                continue
            try:
                tt = float(row[col[0]])
                nd = float(row[col[1]])
                xyz = [float(row[c]) if row[c].strip() else float("nan") for c in col[2:]]
            except (ValueError, IndexError):
                raise ValueError(f"{path}: line {ln}: cannot read {row!r} as t,node,x,y,z numbers") from None
            if not np.isfinite(tt):
                raise ValueError(f"{path}: line {ln}: t is {row[col[0]]!r}; sample times must be finite")
            if not np.isfinite(nd) or nd != int(nd) or not 0 <= nd < n_nodes:
                raise ValueError(f"{path}: line {ln}: node {row[col[1]]!r} is not a node index 0..{n_nodes - 1}")
            rows.append((tt, int(nd), *xyz))
    if not rows:
        raise ValueError(f"{path}: no data rows")
    a = np.array(rows, dtype=float)
    t, inv = np.unique(a[:, 0], return_inverse=True)
    nodes = np.full((t.size, n_nodes, 3), np.nan)
    seen = np.zeros((t.size, n_nodes), bool)
    for r, (s_, nd) in enumerate(zip(inv, a[:, 1].astype(int))):
        if seen[s_, nd]:
            raise ValueError(f"{path}: node {nd} appears twice at t = {t[s_]!r} s")
        seen[s_, nd] = True
        nodes[s_, nd] = a[r, 2:]
    mask = np.isfinite(nodes).all(axis=2)
    return t, nodes, mask


def load_trajectory(path, n_nodes: int):
    """``(t, nodes, rest_length, mask)`` from a ``.npz`` as written by ``simulate`` (``t``,
    ``nodes``, optional ``rest_length``, optional bool ``node_mask`` (n,) or (S, n)) or a
    long-format CSV (:func:`load_csv`; NaN / missing rows = untracked)."""
    p = str(path)
    if p.lower().endswith(".csv"):
        t, nodes, mask = load_csv(p, n_nodes)
        return t, nodes, None, mask
    z = load_npz(p, "t (S,) s and nodes (S, n, 3) m as written by `python -m tensegrity_gym simulate`, "
                    "or a long-format .csv")
    for k in ("t", "nodes"):
        if k not in z:
            raise ValueError(f"{p}: no array {k!r} (found {sorted(z)}); expected t (S,) s and nodes "
                             f"(S, n, 3) m as written by `python -m tensegrity_gym simulate`")
    t, nodes = z["t"], z["nodes"]
    rl, mask = z.get("rest_length"), z.get("node_mask")
    if mask is None and np.asarray(nodes).ndim == 3:
        fin = np.isfinite(np.asarray(nodes, float)).all(axis=2)
        if not fin.all() and (fin | ~fin.any(axis=0)).all():
            mask = fin        # whole nodes NaN: untracked nodes (other NaN samples are reported as errors)
    return t, nodes, rl, mask
