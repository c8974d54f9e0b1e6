"""Forward-mode derivatives of the system-identification residual through the torch backend:
:func:`torch_jacobian`, the ``jacobian="torch"`` path of :func:`tensegrity_gym.tools.sysid.identify`
(SI units as there)."""
from __future__ import annotations

import numpy as np

from ..physics.reduced_coordinates import tangent_basis


def torch_jacobian(pb, theta, q0, qd0):
    """(W, R, p + ns) masked residual Jacobian of every window with respect to the
    parameters ``theta`` and the window state coordinates (at ``x = 0``), by autograd through
    the torch backend's float64 rollout (:func:`tensegrity_gym.backends.torch.driver.step`: the same
    equations as the NumPy/numba path). As the finite differences, all columns of all
    windows come from ONE batched rollout of W x (n_u + ns) copies, copy ``c`` carrying the
    tangent of one column (its own per-copy parameters): Jacobian-vector products by the
    double-backward trick (``u -> (du/dz)^T``, then its derivative along the tangent; copies
    are independent, so one pair of backward passes gives every column). The columns are
    exact derivatives instead of differences. (torch's forward-mode AD computes the same
    numbers, much more slowly per operation on CPU.) They are taken
    with respect to the log values of the fitted items and chained with :meth:`_Problem.log_jacobian`
    (d log value / d theta)."""
    import torch
    from ..backends.torch.model import torch_model, torch_params
    from ..backends.torch.equations import node_positions, project
    from ..backends.torch.driver import step
    W, ns, p, K = pb.W, pb.ns, pb.p, pb.K
    T = torch.float64
    tm = torch_model(pb.model, torch.device("cpu"), T)
    sizes = [len(pb.items[g]) for g in pb.names]
    nu = sum(sizes)
    nc = nu + ns                                  # columns per window
    C = W * nc

    def t_(x):
        return torch.as_tensor(np.array(x, dtype=float), dtype=T)
    LJ = pb.log_jacobian(theta)                 # {field: (n_items, p)}
    lf0 = pb.log_factors(theta[None])            # {field: (1, n_items)}
    fields = ["mass", "stiffness", "damping", "rest_length", "node_damping", "gravity", "anchor_pos"]
    if "mass" not in pb.names:                  # a fitted mass scales f and J (torch_params)
        fields += ["f", "J"]
    prm = {f: t_(getattr(pb.base, f)) for f in fields}
    with torch.enable_grad():
        z = torch.zeros((C, nc), dtype=T, requires_grad=True)
        o = 0
        for g, sz in zip(pb.names, sizes):      # value = init * exp(log factor + u)
            val = t_(pb.init[g])[None] * torch.exp(t_(lf0[g]) + z[:, o:o + sz])
            idx = torch.as_tensor(np.asarray(pb.items[g], dtype=np.int64))
            prm[g] = prm[g].expand(C, -1).index_copy(1, idx, val)
            o += sz
        x = z[:, nu:]
        # window states as _Problem.apply (tangent basis at the base state)
        q0c, qd0c = np.repeat(q0, nc, 0), np.repeat(qd0, nc, 0)
        T0 = tangent_basis(q0c[..., 3:])
        t1, t2 = t_(T0[..., 0]), t_(T0[..., 1])
        q0t, qd0t = t_(q0c), t_(qd0c)
        rs, bs, rds, bds, o = [], [], [], [], 0
        for j, E in enumerate(pb.E):
            d, Et = E.shape[1], t_(E.T)
            rs.append(q0t[:, j, :3] + x[:, o:o + d] @ Et)
            bn = q0t[:, j, 3:] + x[:, o + d, None] * t1[:, j] + x[:, o + d + 1, None] * t2[:, j]
            bs.append(bn / torch.sqrt((bn * bn).sum(-1, keepdim=True)))
            o += d + 2
            rds.append(qd0t[:, j, :3] + x[:, o:o + d] @ Et)
            bds.append(qd0t[:, j, 3:] + x[:, o + d, None] * t1[:, j] + x[:, o + d + 1, None] * t2[:, j])
            o += d + 2
        q, qd = project(tm, torch.cat([torch.stack(rs, 1), torch.stack(bs, 1)], -1),
                           torch.cat([torch.stack(rds, 1), torch.stack(bds, 1)], -1))
        node_prm = torch_params(tm, prm, C)
        rl = None if pb.rl is None else t_(np.repeat(pb.rl, nc, 0))     # (C, K, m)
        out = [node_positions(tm, q, node_prm)]
        for k in range(1, K):
            q, qd = step(tm, q, qd, pb.dt, pb.integrator, pb.n_sub, params=prm,
                            rest_length=None if rl is None else rl[:, k - 1])
            out.append(node_positions(tm, q, node_prm))
        out = torch.stack(out, 1)                                    # (C, K, n, 3)
        u = torch.zeros_like(out, requires_grad=True)
        (g,) = torch.autograd.grad(out, z, grad_outputs=u, create_graph=True)       # u^T dout/dz, (C, nc)
        (jv,) = torch.autograd.grad(g, u, grad_outputs=torch.eye(nc, dtype=T).repeat(W, 1))
    d = jv.detach().numpy().reshape((W, nc) + pb.rec.shape[1:])
    d = (d * pb.mask[:, None, ..., None]).reshape(W, nc, -1).transpose(0, 2, 1)   # (W, R, nc)
    Jth = np.zeros(d.shape[:2] + (p,))
    o = 0
    for g, sz in zip(pb.names, sizes):         # chain rule: d/d theta = d/d log value . d log value/d theta
        Jth += d[..., o:o + sz] @ LJ[g]
        o += sz
    return np.concatenate([Jth, d[..., nu:]], axis=-1)
