"""Old import path of :mod:`tensegrity_gym.tools.rendering` (rendering and viewers); it re-exports that module's names."""
from .tools.rendering import *  # noqa: F401,F403
from .tools.rendering import __all__  # noqa: F401
