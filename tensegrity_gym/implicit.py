"""``tensegrity_gym.implicit`` is :mod:`tensegrity_gym.physics.implicit` (the same module object, so imports,
pickles and attribute patches made through either name agree)."""
import sys

from .physics import implicit as _module

sys.modules[__name__] = _module
