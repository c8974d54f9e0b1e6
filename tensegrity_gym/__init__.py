"""tensegrity_gym: fast, physically exact Gymnasium environments for class-1 tensegrity structures.

Data and rules (structures, models, parameters): :mod:`~tensegrity_gym.core`; the backend-neutral
physics (steps, rollouts, geometry, contact, statics): :mod:`~tensegrity_gym.physics`; the numba
and torch implementations: :mod:`~tensegrity_gym.backends`; what a robot is asked to do:
:mod:`~tensegrity_gym.tasks` (none of these imports gymnasium).
Gymnasium environments (registered on import; their ids: ``tensegrity_gym.envs.ENV_IDS``): :mod:`~tensegrity_gym.envs`.
File input and output: :mod:`~tensegrity_gym.io`; command line, system identification, rendering
and baselines: :mod:`~tensegrity_gym.tools`; Stable-Baselines3 and rl_zoo3:
:mod:`~tensegrity_gym.integrations` (for rl_zoo3 name ``tensegrity_gym.integrations.zoo`` in
``--gym-packages``).
All quantities in SI units.
"""
# first: the numba cache guard goes in before any module that compiles (backends/numba/cache_guard.py)
from .backends.numba import cache_guard as _cache_guard  # noqa: F401
from .core.structure import Structure, StructureError, from_dict, load_json, save_json
from .core.builders import build, constrained_prism, icosahedron, load_structure, pinned_rod, prism, tower
from .core.model import Model, State, compile_model, initial_state
from .physics.integrate import step
from .physics.rollout import simulate
from .core.integrators import INTEGRATORS
from .core.errors import SimulationDiverged

__version__ = "0.2.0"

__all__ = ["Structure", "StructureError", "load_json", "save_json", "from_dict", "prism", "pinned_rod",
           "constrained_prism", "icosahedron", "tower", "build", "Model", "State", "compile_model",
           "initial_state", "step", "simulate", "INTEGRATORS", "SimulationDiverged", "load_structure"]


def _register() -> None:
    try:
        from .envs import register_envs
    except ImportError:  # pragma: no cover - gymnasium missing
        return
    register_envs()


_register()
