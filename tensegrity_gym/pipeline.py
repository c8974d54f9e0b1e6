"""Re-exports: the physics pipeline (:mod:`tensegrity_gym.physics.pipeline`), the compiled
actuation updates (:mod:`tensegrity_gym.backends.numba.actuation`), divergence checks
(:mod:`tensegrity_gym.backends.numba.divergence`) and fused plans, under the module name they
had before. ``advance`` is :func:`~tensegrity_gym.physics.pipeline.run_steps`."""
from .backends.numba.actuation import apply_controls, apply_motor
from .backends.numba.plans import Plan
from .backends.numba.divergence import bad_copies, state_ok, state_ok_local
from .backends.numba.entries import run_plan, run_plan_simd
from .physics.pipeline import (ControlStep, compiled_physics, compiled_plan, contact_step, control_step, diverged,
                               run_steps, step)

advance = run_steps

__all__ = ["step", "control_step", "ControlStep", "advance", "run_steps", "contact_step", "diverged",
           "compiled_physics", "apply_controls", "apply_motor", "state_ok", "state_ok_local", "bad_copies", "Plan",
           "compiled_plan", "run_plan", "run_plan_simd"]
