"""``tensegrity_gym.checks`` is :mod:`tensegrity_gym.core.checks` (the same module object, so imports,
pickles and attribute patches made through either name agree)."""
import sys

from .core import checks as _module

sys.modules[__name__] = _module
