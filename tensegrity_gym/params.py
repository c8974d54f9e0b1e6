"""``tensegrity_gym.params`` is :mod:`tensegrity_gym.core.params` (the same module object, so imports,
pickles and attribute patches made through either name agree)."""
import sys

from .core import params as _module

sys.modules[__name__] = _module
