"""Re-exports: the numba backend's entry points (:mod:`tensegrity_gym.backends.numba.api`) under
the module name they had before."""
import numba  # noqa: F401  (scripts read _kernels.numba.get_num_threads())

from .backends.numba.api import accelerations, clear_cache, project, step, step_inplace, string_forces
from .backends.numba.compile import PARALLEL_MIN_WORK
from .backends.numba.divergence import finite_pair

__all__ = ["step", "step_inplace", "accelerations", "string_forces", "project", "PARALLEL_MIN_WORK", "clear_cache",
           "finite_pair"]
