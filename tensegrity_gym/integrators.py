"""Re-exports: the integrator registry (:mod:`tensegrity_gym.core.integrators`), the errors
(:mod:`tensegrity_gym.core.errors`), the steps (:mod:`tensegrity_gym.physics.step`), recorded
runs (:mod:`tensegrity_gym.physics.simulate`) and the stability checks
(:mod:`tensegrity_gym.physics.stability`), under the module name they had before."""
from .core.errors import EvaluationBudgetExceeded, SimulationDiverged, StabilityWarning
from .core.integrators import INTEGRATORS, NUMPY_REMOVED, IntegratorInfo, numba_backend, resolve
from .physics.evaluate import accelerations
from .physics.rollout import Schedule, simulate
from .physics.stability import stability_limit
from .physics.integrate import AXIS_TOLERANCE, rk4_update, step, step_inplace

_numba_backend = numba_backend   # the name the envs used for the backend-name check

__all__ = ["INTEGRATORS", "step", "step_inplace", "simulate", "accelerations", "Schedule", "IntegratorInfo",
           "SimulationDiverged", "StabilityWarning", "EvaluationBudgetExceeded", "stability_limit", "resolve",
           "rk4_update", "NUMPY_REMOVED", "numba_backend", "AXIS_TOLERANCE"]
