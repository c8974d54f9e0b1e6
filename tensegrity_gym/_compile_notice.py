"""Re-exports: the compile notice of the numba backend (:mod:`tensegrity_gym.backends.numba.compile`)."""
from .backends.numba.compile import cached, compile_with_notice, say

__all__ = ["cached", "compile_with_notice", "say"]
