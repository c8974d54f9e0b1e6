"""tensegrity_gym: fast, physically exact Gymnasium environments for class-1 tensegrity structures.

Physics (NumPy/numba only, no gymnasium): :mod:`~tensegrity_gym.structure`,
:mod:`~tensegrity_gym.builders`, :mod:`~tensegrity_gym.dynamics`, :mod:`~tensegrity_gym.integrators`.
Environments (registered on import): ``TensegrityShape-v0``, ``TensegrityRoll-v0``.
File input and output: :mod:`~tensegrity_gym.io`; command line, system identification, rendering
and baselines: :mod:`~tensegrity_gym.tools`; Stable-Baselines3 and rl_zoo3:
:mod:`~tensegrity_gym.integrations` (for rl_zoo3 name ``tensegrity_gym.integrations.zoo`` in
``--gym-packages``).
All quantities in SI units.
"""
# first: the numba cache guard goes in before any module that compiles (backends/numba/cache_guard.py)
from .backends.numba import cache_guard as _cache_guard  # noqa: F401
from .structure import Structure, StructureError, load_json, save_json, from_dict
from .builders import prism, pinned_rod, constrained_prism, icosahedron, tower, build, load_structure
from .dynamics import Model, State, compile_model, initial_state
from .integrators import step, simulate, INTEGRATORS, SimulationDiverged

__version__ = "0.1.0"

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
