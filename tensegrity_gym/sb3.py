"""Old import path of :mod:`tensegrity_gym.integrations.sb3` (the Stable-Baselines3 adapter); it re-exports that module's names."""
from .integrations.sb3 import *  # noqa: F401,F403
from .integrations.sb3 import __all__  # noqa: F401
