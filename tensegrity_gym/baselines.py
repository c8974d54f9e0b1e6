"""Old import path of :mod:`tensegrity_gym.tools.baselines` (scripted baseline controllers); it re-exports that module's names."""
from .tools.baselines import *  # noqa: F401,F403
from .tools.baselines import __all__  # noqa: F401
