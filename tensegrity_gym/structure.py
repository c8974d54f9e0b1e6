"""``tensegrity_gym.structure`` is :mod:`tensegrity_gym.core.structure` (the same module object, so imports,
pickles and attribute patches made through either name agree)."""
import sys

from .core import structure as _module

sys.modules[__name__] = _module
