"""The multiple-shooting problem of :func:`tensegrity_gym.tools.sysid.identify`: window states,
batched finite-difference Jacobians and the variable-projection residual (:class:`_Problem`);
with ground contact, the stick/slip state each window starts from (:meth:`_Problem.carry`)."""
from __future__ import annotations

import math

import numpy as np

from ..physics.evaluate import project
from ..physics.geometry import kabsch, node_positions
from ..core.model import initial_state
from ..physics.stability import stable_step_estimate
from ..core.model import State
from ..core.integrators import resolve
from ..physics.integrate import step
from ..core.params import Params
from ..physics import contact as contact_mod
from ..physics import pipeline
from ..physics.reduced_coordinates import tangent_basis
from .sysid_result import CONTACT_FIELDS

_EPS_THETA = 1e-6      # FD step in log space (relative change of a parameter)
_EPS_POS = 1e-6        # FD step of a position / direction coordinate, m or 1
_EPS_VEL = 1e-5        # FD step of a velocity coordinate, m/s or 1/s
_THETA_MAX = 5.0       # |log(value / initial)| is clipped here (a factor of 148)


# ----------------------------------------------------------------------------- state coordinates
class _Problem:
    """The multiple-shooting problem: windows, their state coordinates, batched simulation."""

    def __init__(self, model, t, rec, mask, rl, h, names, items, init, base, mode, window, integrator, dt,
                 stride, total_mass=None, contact=None, tie_tangential=False):
        self.model, self.names, self.items, self.init, self.base, self.mode = model, names, items, init, base, mode
        self.contact, self.tie_tangential = contact, tie_tangential
        self.carried = None     # contact state at each window's start: offsets xi (W, n_c, 2) m, active (W, n_c)
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
            om = stable_step_estimate(model)["omega_max"]
            dt_max = 0.2 / om if np.isfinite(om) and om > 0 else h
            if contact is not None:     # the contact's springs are usually stiffer than the strings
                dt_max = min(dt_max, 0.5 * contact_mod.stable_step(contact, model)["semi_implicit_euler"])
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
        # a window's state has converged when its step is below tol_step FD steps or the cost falls
        # by less than 1e-12 (relative). Contact forces switch inside a window, so its cost has kinks
        # where LM zig-zags with steps of about one FD step for ever: 0.1 FD step is converged there;
        # through the kinks a window can need more than 30 iterations to converge (a noise-free
        # record of a landing prism did on one machine and not on another: the floating-point
        # rounding decides), so a contact window has up to 100
        self.tol_step = 1e-3 if contact is None else 0.1
        self.max_iter = 30 if contact is None else 100

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
            if g in CONTACT_FIELDS:
                continue
            full = np.repeat(getattr(self.base, g), C, axis=0)
            full[:, self.items[g]] = self.init[g][None] * np.exp(lf[g])
            vals[g] = full
        return self.base.replace(**vals)

    def contact_rows(self, thetas: np.ndarray):
        """(C, 9) per-copy contact parameters for rows ``thetas`` (C, p), None without contact."""
        if self.contact is None:
            return None
        thetas = np.atleast_2d(thetas)
        lf = self.log_factors(thetas)
        prm = self.contact.per_copy(thetas.shape[0])
        rows = np.arange(thetas.shape[0])
        for g in self.names:
            if g in CONTACT_FIELDS:
                v = self.init[g][0] * np.exp(lf[g][:, 0])
                contact_mod.set_copy_values(prm, rows, CONTACT_FIELDS[g], v)
                if g == "ground_stiffness" and self.tie_tangential:
                    contact_mod.set_copy_values(prm, rows, "tangential_stiffness", v)
        return prm

    def physics(self, thetas: np.ndarray):
        """``(Params, contact rows or None)`` with one row per row of ``thetas`` (C, p): what
        :meth:`simulate` takes."""
        return self.params(thetas), self.contact_rows(thetas)

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
        return project(self.model, np.concatenate([r, bn], -1), np.concatenate([rd, bd], -1))

    def simulate(self, q, qd, phys, win, extra=False):
        """Node positions (C, K, n, 3) of copies starting at ``q``, ``qd`` (C, k, 6) with the
        parameters ``phys`` (:meth:`physics`: one row or C rows); copy c lies in window ``win[c]``
        (for the rest lengths and its starting contact state). Non-finite results come back as
        NaN. ``extra``: also simulate the interval after the last sample and return ``(positions,
        state, contact state)`` at its end (where the next window starts)."""
        params, prm = phys
        C = q.shape[0]
        out = np.empty((C, self.K, self.model.n_nodes, 3))
        out[:, 0] = node_positions(self.model, q)
        st = State(q=q, qd=qd)
        cs = None
        if self.contact is not None:
            cs = contact_mod.init_contact_state(self.model, C)
            if self.carried is not None:
                xi, act = self.carried
                cs.anchor[...] = out[:, 0, contact_mod.contact_nodes(self.model), :2] - xi[win]
                cs.active[...] = act[win]
        dead = np.zeros(C, bool)     # copies whose state stopped being finite: NaN from then on
        with np.errstate(all="ignore"):
            for k in range(1, self.K + bool(extra)):
                rl = None if self.rl is None else self.rl[win, k - 1]
                try:
                    if cs is None:
                        new = step(self.model, st, self.dt, self.integrator, n_steps=self.n_sub, params=params,
                                   rest_length=rl)
                    else:
                        new, cs = pipeline.step(self.model, st, self.dt, self.integrator, n_steps=self.n_sub,
                                                contact=self.contact, cstate=cs, contact_params=prm, params=params,
                                                rest_length=rl)
                except (ZeroDivisionError, OverflowError, FloatingPointError):
                    out[:, k:] = np.nan
                    break
                # a copy that blew up carries its last finite state on (the next step takes only
                # finite states), its positions NaN: the other copies of the batch go on
                bad = ~(np.isfinite(new.q).all(axis=(1, 2)) & np.isfinite(new.qd).all(axis=(1, 2)))
                if bad.any():
                    dead |= bad
                    new = State(q=np.where(bad[:, None, None], st.q, new.q),
                                qd=np.where(bad[:, None, None], st.qd, new.qd))
                st = new
                if k < self.K:
                    out[:, k] = node_positions(self.model, st.q)
                    out[dead, k] = np.nan
        return (out, st, cs) if extra else out

    def at_bound(self, theta) -> dict:
        """{field: (n_items,) bool} the items whose value ``theta`` pins at the search bound
        (``|log(value / initial)|`` at :data:`_THETA_MAX`, where the residual no longer depends on it)."""
        out = {}
        for g in self.names:
            th = np.abs(np.asarray(theta)[self.slices[g]]) >= _THETA_MAX * (1 - 1e-9)
            n_ = len(self.items[g])
            if g == "mass" and self.total_mass is not None:      # every rod's share depends on every entry
                out[g] = np.full(n_, bool(th.any()))
            else:
                out[g] = np.broadcast_to(th, (n_,)).copy()
        return out

    def record_scales(self) -> tuple[float, float]:
        """``(noise, motion)`` m of the fitted samples: the position noise the record shows (RMS
        second difference of consecutive tracked samples over sqrt(6), white noise's; an upper
        bound, smooth motion adds ``a h^2``) and the RMS motion of the tracked nodes about their
        mean in each window (what a model predicting no motion would miss)."""
        m = self.mask[..., None] & np.ones(3, bool)
        x = np.where(m, self.rec, 0.0)
        cnt = m.sum(1)
        mean = x.sum(1) / np.maximum(cnt, 1)
        motion = math.sqrt(float(np.sum(np.where(m, x - mean[:, None], 0.0) ** 2)) / max(int(m.sum()), 1))
        ok = m[:, 2:] & m[:, 1:-1] & m[:, :-2]
        if not ok.any():
            return 0.0, motion
        d2 = np.where(ok, x[:, 2:] - 2 * x[:, 1:-1] + x[:, :-2], 0.0)
        return math.sqrt(float(np.sum(d2 ** 2)) / (6.0 * int(ok.sum()))), motion

    def carry(self, theta, q, qd):
        """With contact: every window but the first starts from the stick/slip state the previous
        window's simulation (states ``q``, ``qd``, parameters ``theta``) reaches one sample interval
        after its last sample, as the caps' offsets from their anchors. The record does not hold
        it, and a sticking cap's spring carries up to ``mu F_n`` (~0.1 mm): windows started relaxed
        let resting caps creep in the model (~80 um), which a wrong friction would absorb."""
        nc = 2 * self.model.n_bars
        self.carried = (np.zeros((self.W, nc, 2)), np.zeros((self.W, nc), bool))
        xi, act = self.carried
        for w in range(self.W - 1):     # in turn: window w starts from what window w - 1 handed on
            _, st, cs = self.simulate(q[w:w + 1], qd[w:w + 1], self.physics(theta), np.array([w]), extra=True)
            p = node_positions(self.model, st.q)[0, contact_mod.contact_nodes(self.model), :2]
            ok = np.isfinite(p).all(-1) & cs.active[0]
            xi[w + 1] = np.where(ok[:, None], p - cs.anchor[0], 0.0)
            act[w + 1] = ok

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
                R0, c0, cr = kabsch(ref[trk], Nw[w, 0, trk])
                pos[w, miss] = (ref[miss] - cr) @ R0.T + c0
                trk1 = np.flatnonzero(Mw[w, 1])
                if trk1.size >= 3:
                    R1, c1, cr1 = kabsch(ref[trk1], Nw[w, 1, trk1])
                    vel[w, miss] = (((ref[miss] - cr1) @ R1.T + c1) - pos[w, miss]) / self.h
            else:
                pos[w, miss] = ref[miss]
        st = initial_state(model, W, nodes=pos, velocities=vel)
        q, qd = st.q.copy(), st.qd.copy()
        free = ~np.asarray(model.constrained)
        sig = model.sigma[None, free, None]
        a, c = model.rod_a[free], model.rod_c[free]
        q[:, free, :3] = pos[:, a] + sig * (pos[:, c] - pos[:, a])
        qd[:, free, :3] = vel[:, a] + sig * (vel[:, c] - vel[:, a])
        return project(model, q, qd)

    # -- inner problem: every window's state for given parameters (batched Levenberg-Marquardt)
    def fit_states(self, theta, q0, qd0, max_iter=None, Jx_old=None):
        W, ns = self.W, self.ns
        max_iter = self.max_iter if max_iter is None else max_iter
        win = np.arange(W)
        P1 = self.physics(theta)
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
                step_small = np.abs(dx / self.eps_x).max(1) < self.tol_step
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
            P = self.physics(np.tile(thetas, (W, 1)))
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
        """(W, R, p + ns) residual Jacobian by autograd through the torch backend
        (:func:`tensegrity_gym.tools.sysid_torch.torch_jacobian`)."""
        from .sysid_torch import torch_jacobian
        return torch_jacobian(self, theta, q0, qd0)
