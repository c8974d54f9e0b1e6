"""``tensegrity_gym.jacobian`` is :mod:`tensegrity_gym.physics.jacobian` (the same module object, so imports,
pickles and attribute patches made through either name agree)."""
import sys

from .physics import jacobian as _module

sys.modules[__name__] = _module
