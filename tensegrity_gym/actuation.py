"""``tensegrity_gym.actuation`` is :mod:`tensegrity_gym.physics.actuation` (the same module object, so imports,
pickles and attribute patches made through either name agree)."""
import sys

from .physics import actuation as _module

sys.modules[__name__] = _module
