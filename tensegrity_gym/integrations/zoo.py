"""rl-baselines3-zoo (``rl_zoo3``) registration: the tensegrity envs with the project's tuned
hyperparameters by default.

Name this module in the zoo's ``--gym-packages`` (the zoo imports each module named there)::

    python -m rl_zoo3.train --algo ppo --env TensegrityRoll-v0 --gym-packages tensegrity_gym.integrations.zoo

Importing it registers the envs (it imports ``tensegrity_gym``) and calls :func:`install`;
importing ``tensegrity_gym`` alone changes nothing in the zoo (``--gym-packages tensegrity_gym``
registers the envs only, and the zoo then uses its own generic files).

How the zoo finds hyperparameters (rl_zoo3 2.x, ``ExperimentManager``): ``--conf-file`` if
given -- a ``.yml``/``.yaml`` path, a ``.py`` file, or a Python module path with a
``hyperparams`` dict -- else the zoo's OWN ``rl_zoo3/hyperparams/<algo>.yml``. That file has no
entry for the tensegrity envs but a ``default`` one, so without help the zoo silently trains
``TensegrityRoll-v0`` with generic defaults. :func:`install` makes the zoo read the project's
file ``agents/hyperparams/<algo>.yml`` (shipped inside the installed package) for
``Tensegrity*`` env ids when no ``--conf-file`` was given. An algorithm without a project file
or without an entry for the env fails with a ``ValueError`` that says how to proceed
(``--conf-file`` with a file of your own, or the zoo's generic ``default`` entry via
``--conf-file <rl_zoo3>/hyperparams/<algo>.yml``), instead of using defaults silently. Other env
ids, and any run with ``--conf-file``, are left to the zoo unchanged.

To name the project's file explicitly, from any directory:
``--conf-file "$(python -c 'import tensegrity_gym.integrations.zoo as z; print(z.hyperparams_file("ppo"))')"``.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["install", "hyperparams_dir", "hyperparams_file", "ENV_PREFIX"]

ENV_PREFIX = "Tensegrity"
_INSTALLED = False


def hyperparams_dir() -> Path:
    """The folder of the project's hyperparameter files: ``agents/hyperparams`` in the repository,
    ``tensegrity_gym_agents/hyperparams`` in an installed package."""
    try:
        import tensegrity_gym_agents as agents   # installed (editable or not)
    except ImportError:
        import agents                            # a checkout that is only on sys.path
    return Path(agents.__file__).resolve().parent / "hyperparams"


def hyperparams_file(algo: str) -> Path:
    """The project's zoo-format hyperparameter file of ``algo`` (may not exist for every algorithm)."""
    return hyperparams_dir() / f"{algo.lower()}.yml"


def install() -> bool:
    """Make rl_zoo3's ``ExperimentManager`` default to the project's hyperparameter files for the
    tensegrity envs (see the module docstring). Idempotent; returns False if rl_zoo3 is absent."""
    global _INSTALLED
    if _INSTALLED:
        return True
    try:
        from rl_zoo3.exp_manager import ExperimentManager
    except ImportError:
        return False
    import inspect
    original = ExperimentManager.__init__
    signature = inspect.signature(original)
    zoo_file = Path(__import__("rl_zoo3").__file__).resolve().parent / "hyperparams"

    def __init__(self, *args, **kwargs):
        bound = signature.bind(self, *args, **kwargs)
        env_id, algo = str(bound.arguments.get("env_id", "")), str(bound.arguments.get("algo", ""))
        if bound.arguments.get("config") is None and env_id.startswith(ENV_PREFIX):
            ours = hyperparams_file(algo)
            import yaml
            entries = (yaml.safe_load(ours.read_text()) or {}) if ours.exists() else {}
            if env_id not in entries:
                raise ValueError(
                    f"tensegrity_gym has no tuned {algo} hyperparameters for {env_id} "
                    f"({'no entry in ' + str(ours) if ours.exists() else 'no file ' + str(ours)}). "
                    f"Pass --conf-file with a zoo-format file of your own, or --conf-file "
                    f"{zoo_file / (algo + '.yml')} to use the zoo's generic 'default' entry; tuned files "
                    f"exist for: {sorted(p.stem for p in hyperparams_dir().glob('*.yml'))}")
            bound.arguments["config"] = str(ours)
        original(*bound.args, **bound.kwargs)

    __init__.__wrapped__ = original
    ExperimentManager.__init__ = __init__
    _INSTALLED = True
    return True


install()   # importing this module is the registration (rl_zoo3 --gym-packages imports it)
