"""The torch backend: batched, differentiable physics (float64 / float32, CPU / CUDA).

The same equations as the numba backend and the NumPy oracle (``tests/oracle_numpy.py``; the
contact of :mod:`tensegrity_gym.physics.contact`, the cable motor of
:class:`tensegrity_gym.physics.actuation.Actuation`), written once in torch and batched over a
leading axis B. Modules, named as the numba backend's: ``model`` (device, dtype, the model and
parameters as tensors), ``equations``, ``driver`` (steps, ``step_state`` / ``simulate``),
``contact``, ``actuation``, ``divergence``, and ``graphs`` (CUDA graphs of the physics loops).
torch is imported lazily: the core install never needs it (``pip install tensegrity_gym[torch]``).
SI units throughout (m, kg, s, N).

Entry points
------------
* :func:`accelerations` ``(model, q, qd, ...) -> (B, k, 6)`` ``[r'', b'']`` (m/s^2, 1/s^2);
* :func:`step` ``(model, q, qd, dt, integrator, n_steps, ...) -> (q, qd)`` on torch tensors
  (``"semi_implicit_euler"`` with the great-circle drift when ``project=True``, or ``"rk4"``,
  projection after each step as :func:`tensegrity_gym.physics.step`);
* :func:`contact_forces`, :func:`contact_step`, :func:`contact_substep`: ground contact with
  Coulomb friction and a stick phase (as :mod:`tensegrity_gym.physics.contact`, the anchors and contact
  flags as tensors; per-copy contact parameters as a (P, 9) tensor ``prm`` / ``contact_prm``);
* ``rod_contact.rod_contact_forces``: rod-rod contact (as :mod:`tensegrity_gym.physics.rod_contact`),
  and the sub-steps that add it (``rod_contact_substep``, ``rod_terrain_substep``);
* :func:`update_motor`: the cable motor (``Actuation.update_motor``), :func:`update_rate`: the
  control update without a motor (``Actuation.update_rate``), both with optional per-copy
  limits, and :func:`physics_inputs`;
* :func:`step_state` / :func:`simulate`: numpy :class:`~tensegrity_gym.core.model.State` in
  and out, what ``physics.step(..., backend="torch", device=..., dtype=...)`` and
  ``python -m tensegrity_gym simulate --backend torch --device cpu`` call.

Per-copy parameters
-------------------
``params``: None (the model's own numbers), a :class:`tensegrity_gym.core.params.Params`, or a dict
(or any object) with the attributes/keys ``mass`` (P, k) kg,
``f`` (P, k) kg m, ``J`` (P, k) kg m^2, ``stiffness`` / ``damping`` / ``rest_length`` (P, m)
N/m, N s/m, m, ``node_damping`` (P, n) N s/m, ``gravity`` (P, 3) m/s^2, ``anchor_pos``
(P, na, 3) m (missing ones come from the model), with P = 1 (shared) or B (one row per copy).
``mass`` given without ``f`` and ``J`` keeps each rod's mass distribution: ``f`` and ``J`` scale
with it (as ``Params.replace(mass=...)``). A damping, gravity or node-drag term that the model
lacks runs when ``params`` give it (a NumPy value that is not all zero, or any tensor). Values may be NumPy
arrays or torch tensors; a tensor with ``requires_grad`` makes the rollout differentiable with
respect to it. The gravity nodal loads are derived here from ``mass`` and ``gravity`` (a rod's
weight split between its nodes by its centre-of-mass fraction), so a gradient with respect to
``mass`` includes its weight. A tensor on another device than the state is a ValueError
naming the field.

Differentiability and the gradient at a switch
----------------------------------------------
Everything is built from out-of-place torch operations (no in-place writes on tensors that
carry gradients, no ``.item()``), so ``loss.backward()`` through any number of steps gives the
gradient with respect to the initial state, the controls (``rest_length``, ``force_density``,
motor actions) and the parameters. The model is piecewise smooth; autograd returns the
derivative of the branch that the forward pass took (``torch.where`` / ``clamp``):

* slack/taut string: at ``|s| = l0`` exactly the string counts as slack (``|s| > l0`` is
  taut, as in NumPy), so the gradient there is that of a slack string (zero force). The
  elastic force ``k (|s| - l0)`` is continuous there, so the one-sided gradients differ only
  by the jump of the force *slope* (``k``), and the damping term ``c d|s|/dt`` jumps: the
  force itself is discontinuous when the string goes taut while lengthening.
* the tension clip ``max(0, tension)`` (damping pulling a string slack faster than the
  spring) and the control clip ``max(0, gamma + u)``: gradient of the active branch,
  zero on the clipped side (torch's ``clamp`` passes the gradient when the value is
  exactly at the bound).
* contact on/off (``delta > 0``): off gives zero gradient; the normal force ``k delta`` is
  continuous at touch-down, its damping part ``min(k delta d, c_max) delta'`` too (it
  vanishes with ``delta``), the friction is not (the anchor is set at touch-down), so a
  rollout's gradient is the gradient along the sequence of contact modes that the forward
  pass visited; it does not see a mode change that a finite perturbation would cause.
* friction stick/slip: stick differentiates the spring-damper ``-k_t xi - c_t v``, slip the
  scaled force ``mu F_n F*/|F*|`` (continuous at the switch, the derivative is not); the
  anchor is state and its gradient is carried through the steps.
* the motor's clips (rate change, bounds, end stop) likewise: gradient of the branch taken,
  zero through an active bound.
* the great-circle drift at a rod with ``b' = 0`` exactly: the rotation angle is computed
  without a square root of zero (``sin(x)/x`` by its series below 1e-4 rad), so the gradient
  is finite (the exact one).

Finite differences across a switch therefore disagree with autograd by design; the tests
compare the two on smooth stretches only (``tests/test_torch_backend.py``).

Numbers (``scripts/bench/bench_gpu.py --agreement``, ``docs/bench_gpu.md``): over 1 s of RK4 at
dt = 1e-4 (10,000 steps) float64 on CPU agrees with the numba path to round-off (largest node
error 9e-15 m on the prism, 1e-15 m on the icosahedron, 4e-15 m on the constrained prism);
float32 stays within 1.4e-6 .. 3.7e-6 m of it on the same runs.
"""
from __future__ import annotations
