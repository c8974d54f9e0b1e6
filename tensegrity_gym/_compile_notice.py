"""Re-exports: the compile step of the numba backend (:mod:`tensegrity_gym.backends.numba.compile`)
under its former module and function name; its progress messages come from
:mod:`tensegrity_gym.backends.numba.watch`."""
from .backends.numba.compile import compile_signatures

compile_with_notice = compile_signatures

__all__ = ["compile_signatures", "compile_with_notice"]
