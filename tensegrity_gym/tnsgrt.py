"""Old import path of :mod:`tensegrity_gym.io.tnsgrt` (tnsgrt import); it re-exports that module's names."""
from .io.tnsgrt import *  # noqa: F401,F403
from .io.tnsgrt import __all__  # noqa: F401
