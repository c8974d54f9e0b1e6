"""Old import path of :mod:`tensegrity_gym.integrations.zoo` (the rl_zoo3 registration (importing it installs the zoo defaults)); it re-exports that module's names."""
from .integrations.zoo import *  # noqa: F401,F403
from .integrations.zoo import __all__  # noqa: F401
