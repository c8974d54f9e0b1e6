#!/usr/bin/env python
"""Fit rest-length controls by gradient descent through a 1 s rollout (torch backend example).

Scene: the 3-bar prism (``builders.prism(3)``, string damping 5 N s/m, no gravity) released
from its prestressed equilibrium. A hidden set of rest lengths (the vertical strings
shortened, the top ones lengthened by a few percent) gives the *target shape*: the node
positions after 1 s of semi-implicit Euler (dt = 2 ms), computed with the NumPy reference path
(:func:`tensegrity_gym.physics.integrate.step`, the numba kernels). Starting from the nominal rest
lengths, Adam adjusts the rest lengths of all 9 strings (held over the rollout) to minimise the
mean squared node distance to the target after the same 1 s, with the gradient computed by
autograd through all 500 steps of :func:`tensegrity_gym.backends.torch.driver.step` (float64, CPU or
``--device cuda``). Every string stays taut on the way, so the loss is smooth (see the
``torch_backend`` module doc for what the gradient is at a slack switch).

Prints the shape error (RMS node distance, m) before and after the fit, checked again with the
numba kernels, and how far the fitted rest lengths are from the hidden ones.

Usage::

    .venv/bin/python -m scripts.figures.torch_fit_controls            # ~1-2 min on 2 CPU cores
    .venv/bin/python -m scripts.figures.torch_fit_controls --iters 80 --device cuda
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import torch

from tensegrity_gym.core import builders
from tensegrity_gym.core.model import compile_model, initial_state
from tensegrity_gym.physics import geometry, integrate
from tensegrity_gym.backends.torch.model import resolve_device, torch_model, torch_params
from tensegrity_gym.backends.torch import driver, equations

DT = 2e-3
DURATION = 1.0


def main(argv=None):
    ap = argparse.ArgumentParser(description="fit rest lengths to a target shape through a 1 s rollout")
    ap.add_argument("--iters", type=int, default=40, help="Adam iterations")
    ap.add_argument("--lr", type=float, default=5e-3, help="Adam step size, m")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seed", type=int, default=0, help="seed of the hidden rest-length change")
    args = ap.parse_args(argv)
    dev = resolve_device(args.device)
    model = compile_model(builders.prism(3, damping=5.0))
    st = initial_state(model, 1)
    n = int(round(DURATION / DT))
    rng = np.random.default_rng(args.seed)
    l0 = model.rest_length
    change = np.concatenate([np.zeros(3), +0.03 * np.ones(3), -0.04 * np.ones(3)]) + 0.01 * rng.standard_normal(9)
    hidden = l0 * (1.0 + change)

    def shape_error_numpy(rest):
        out = integrate.step(model, st, DT, "semi_implicit_euler", n_steps=n, rest_length=rest)
        N = geometry.node_positions(model, out.q)[0]
        return float(np.sqrt(np.mean(np.sum((N - target) ** 2, axis=-1))))

    ref = integrate.step(model, st, DT, "semi_implicit_euler", n_steps=n, rest_length=hidden)
    target = geometry.node_positions(model, ref.q)[0]
    tm = torch_model(model, dev, torch.float64)
    prm = torch_params(tm, None, 1)
    q0 = torch.as_tensor(st.q, device=dev)
    qd0 = torch.as_tensor(st.qd, device=dev)
    tgt = torch.as_tensor(target, device=dev)
    rest = torch.tensor(l0, device=dev, requires_grad=True)
    opt = torch.optim.Adam([rest], lr=args.lr)
    before = shape_error_numpy(l0)
    print(f"prism, 1 s rollout ({n} steps of {DT * 1e3:g} ms), 9 rest lengths fitted to a target shape")
    print(f"before: RMS node error {before:.3e} m (nominal rest lengths)")
    t0 = time.perf_counter()
    for it in range(args.iters):
        opt.zero_grad()
        q, qd = driver.step(model, q0, qd0, DT, "semi_implicit_euler", n, rest_length=rest)
        N = equations.node_positions(tm, q, prm)[0]
        loss = ((N - tgt) ** 2).sum(-1).mean()
        loss.backward()
        opt.step()
        if it % 10 == 0 or it == args.iters - 1:
            print(f"  iter {it:3d}: RMS node error {float(loss.detach()) ** 0.5:.3e} m  "
                  f"({time.perf_counter() - t0:.1f} s)", flush=True)
    fitted = rest.detach().cpu().numpy()
    after = shape_error_numpy(fitted)
    print(f"after {args.iters} iterations: RMS node error {after:.3e} m (checked with the numba kernels); "
          f"{before / max(after, 1e-300):.0f}x smaller")
    print(f"rest lengths: largest distance from the hidden ones {np.abs(fitted - hidden).max():.2e} m "
          f"(was {np.abs(l0 - hidden).max():.2e} m)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
