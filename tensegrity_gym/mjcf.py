"""Old import path of :mod:`tensegrity_gym.io.mjcf` (MJCF export); it re-exports that module's names."""
from .io.mjcf import *  # noqa: F401,F403
from .io.mjcf import MJ_INTEGRATORS, __all__, check_mj_integrator  # noqa: F401
