"""``tensegrity_gym.sizing`` is :mod:`tensegrity_gym.core.sizing` (the same module object, so imports,
pickles and attribute patches made through either name agree)."""
import sys

from .core import sizing as _module

sys.modules[__name__] = _module
