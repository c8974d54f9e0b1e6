"""``tensegrity_gym.builders`` is :mod:`tensegrity_gym.core.builders` (the same module object, so imports,
pickles and attribute patches made through either name agree)."""
import sys

from .core import builders as _module

sys.modules[__name__] = _module
