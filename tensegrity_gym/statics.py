"""``tensegrity_gym.statics`` is :mod:`tensegrity_gym.physics.statics` (the same module object, so imports,
pickles and attribute patches made through either name agree)."""
import sys

from .physics import statics as _module

sys.modules[__name__] = _module
