"""Old import path of :mod:`tensegrity_gym.tools.cli` (the command line); it re-exports that module's names."""
from .tools.cli import *  # noqa: F401,F403
from .tools.cli import __all__  # noqa: F401
from .tools.cli_common import (EXIT_DIVERGED, EXIT_INTERRUPTED, EXIT_OK, EXIT_OUTPUT, EXIT_PIPE,  # noqa: F401
                               EXIT_STRUCTURE, EXIT_TERMINATED, EXIT_TOO_LARGE, EXIT_USAGE, _Terminated)
