"""Run an rl-baselines3-zoo command with the tensegrity envs registered.

``rl_zoo3.train`` and ``rl_zoo3.enjoy`` take ``--gym-packages tensegrity_gym.integrations.zoo``;
the zoo's ``record_video`` (and ``record_training``) has no such option, so it cannot find the
envs. This module imports :mod:`tensegrity_gym.integrations.zoo` (which registers the envs and
makes the zoo default to the project's hyperparameter files) and runs the zoo command::

    python -m agents.zoo record_video --algo ppo --env TensegrityRoll-v0 -f logs -n 500
    python -m agents.zoo train --algo ppo --env TensegrityRoll-v0     # = rl_zoo3.train --gym-packages ...

The same without this module (one line):
``python -c "import tensegrity_gym.integrations.zoo, runpy; runpy.run_module('rl_zoo3.record_video', run_name='__main__')" ARGS``.
"""
from __future__ import annotations

import runpy
import sys

COMMANDS = ("train", "enjoy", "record_video", "record_training", "plots.all_plots", "plots.plot_train")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in COMMANDS:
        print(f"usage: python -m agents.zoo {{{','.join(COMMANDS)}}} [zoo arguments ...]", file=sys.stderr)
        return 2
    try:
        import rl_zoo3  # noqa: F401
    except ImportError:
        print("error: rl_zoo3 is not installed (pip install 'tensegrity_gym[train]')", file=sys.stderr)
        return 2
    import tensegrity_gym.integrations.zoo  # noqa: F401  (registers the envs and installs the zoo defaults)
    cmd, rest = argv[0], argv[1:]
    sys.argv = [f"rl_zoo3.{cmd}"] + rest
    runpy.run_module(f"rl_zoo3.{cmd}", run_name="__main__", alter_sys=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
