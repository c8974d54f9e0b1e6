"""Re-exports: the compile step of the numba backend (:mod:`tensegrity_gym.backends.numba.compile`);
its progress messages come from :mod:`tensegrity_gym.backends.numba.watch`."""
from .backends.numba.compile import compile_with_notice

__all__ = ["compile_with_notice"]
