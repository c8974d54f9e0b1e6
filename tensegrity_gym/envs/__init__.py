"""Gymnasium environments (this subpackage imports gymnasium; the physics modules do not).

Registration happens in :func:`register_envs`, called when ``tensegrity_gym`` is imported.
Time limits are set here at registration, not inside the envs.
"""
from __future__ import annotations

from gymnasium.envs.registration import load_env_creator, register, registry

ENV_IDS = ("TensegrityShape-v0", "TensegrityRoll-v0", "TensegrityClimb-v0", "TensegrityNavigate-v0",
           "TensegrityRollMuJoCo-v0", "TensegrityNavigateMuJoCo-v0", "TensegrityClimbMuJoCo-v0")


#: (id, module:class of the single env, of the NumPy vector env or None, max_episode_steps); the
#: vector entry point builds that vector env, or with backend="torch" the task's device env
_REGISTRY = (
    ("TensegrityShape-v0", "shape:TensegrityShapeEnv", "shape:TensegrityShapeVectorEnv", 200),
    ("TensegrityRoll-v0", "roll:TensegrityRollEnv", "roll:TensegrityRollVectorEnv", 1000),
    ("TensegrityClimb-v0", "climb:TensegrityClimbEnv", "climb:TensegrityClimbVectorEnv", 1000),
    ("TensegrityNavigate-v0", "navigate:TensegrityNavigateEnv", "navigate:TensegrityNavigateVectorEnv", 3000),  # 60 s
    # MuJoCo twins of TensegrityRoll-v0, TensegrityNavigate-v0 and TensegrityClimb-v0 (need the mujoco extra)
    ("TensegrityRollMuJoCo-v0", "roll_mujoco:TensegrityRollMuJoCoEnv", None, 1000),
    ("TensegrityNavigateMuJoCo-v0", "navigate_mujoco:TensegrityNavigateMuJoCoEnv", None, 3000),
    ("TensegrityClimbMuJoCo-v0", "climb_mujoco:TensegrityClimbMuJoCoEnv", None, 1000),
)


class VectorEntry:
    """The ``vector_entry_point`` of a task's id: ``make_vec(id, num_envs=N,
    vectorization_mode="vector_entry_point", **kwargs)`` builds the NumPy vector env
    ``numpy_env`` (``"package.module:Class"``), or with
    ``backend="torch"`` the task's device env (:func:`tensegrity_gym.envs.torch_vec.vector_env`).
    Both are imported on the first call, as Gymnasium imports a string entry point."""

    def __init__(self, numpy_env: str):
        self.numpy_env = numpy_env

    def __call__(self, num_envs: int = 1, **kwargs):
        return load_env_creator(f"{__name__}.torch_vec:vector_env")(self.numpy_env, num_envs, kwargs)

    def __repr__(self) -> str:
        return f"VectorEntry({self.numpy_env!r})"


def register_task(env_id: str, entry_point: str, vector_env: str | None, max_episode_steps: int | None) -> None:
    """Register a task's id (once): its single env ``entry_point`` and NumPy vector env
    ``vector_env`` (``"package.module:Class"`` each; ``vector_env`` None: Gymnasium's own
    vectorisation only), its time limit ``max_episode_steps`` in control steps. The vector
    entry point builds the device env too, with ``backend="torch"`` (:class:`VectorEntry`)."""
    if env_id in registry:
        return
    kw = {} if vector_env is None else {"vector_entry_point": VectorEntry(vector_env)}
    register(id=env_id, entry_point=entry_point, max_episode_steps=max_episode_steps, **kw)


def register_envs() -> None:
    for env_id, entry, vector_entry, max_steps in _REGISTRY:
        register_task(env_id, f"{__name__}.{entry}", None if vector_entry is None else f"{__name__}.{vector_entry}",
                      max_steps)
