"""The backend-neutral physics API: :func:`step` (allocating) and :func:`step_inplace` (into the
state's own arrays), :func:`simulate`, :func:`accelerations`, :func:`project`,
:func:`string_forces`, :func:`control_step` and :func:`diverged`, each dispatching to a backend
of :mod:`tensegrity_gym.backends`.

Modules: ``geometry`` (nodes, strings, energies, momenta), ``evaluate`` (accelerations, forces,
projection: no step), ``integrate`` (fixed steps, implicit and adaptive dispatch), ``rollout``
(recorded runs, schedules), ``adaptive`` (``solve_ivp`` methods), ``implicit`` (backward Euler),
``jacobian`` (finite-difference Jacobians), ``stability`` (stable-step estimates and checks),
``reduced_coordinates`` (the local chart of the configuration space), ``generalized_forces``
(equilibrium residual, equilibrium matrix, tangent stiffness), ``statics`` (equilibria),
``contact`` (ground-contact parameters and forces), ``actuation`` (actions -> controls) and
``pipeline`` (actuation -> contact -> integration of a batch).
"""
from .evaluate import accelerations, project, string_forces
from .pipeline import ControlStep, control_step, diverged, run_steps
from .rollout import simulate
from .integrate import step, step_inplace

__all__ = ["step", "step_inplace", "simulate", "accelerations", "project", "string_forces", "control_step",
           "ControlStep", "diverged", "run_steps"]
