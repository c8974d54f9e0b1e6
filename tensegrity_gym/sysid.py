"""Old import path of :mod:`tensegrity_gym.tools.sysid` (system identification); it re-exports that module's names."""
from .tools.sysid import *  # noqa: F401,F403
from .tools.sysid import __all__, _check_record, _parse_fit  # noqa: F401
from .tools.sysid_problem import _Problem  # noqa: F401
from .tools.sysid_result import _ALIASES, _UNITS  # noqa: F401
