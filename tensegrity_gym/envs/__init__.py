"""Gymnasium environments (this subpackage imports gymnasium; the physics modules do not).

Registration happens in :func:`register_envs`, called when ``tensegrity_gym`` is imported.
Time limits are set here at registration, not inside the envs.
"""
from __future__ import annotations

ENV_IDS = ("TensegrityShape-v0", "TensegrityRoll-v0", "TensegrityClimb-v0", "TensegrityNavigate-v0",
           "TensegrityRollMuJoCo-v0", "TensegrityNavigateMuJoCo-v0", "TensegrityClimbMuJoCo-v0")


#: (id, module:class of the single env, of the vector env or None, max_episode_steps)
_REGISTRY = (
    # vector entry points: dispatchers that build the NumPy/numba vector env, or with backend="torch"
    # the device-resident torch one (envs/torch_vec.py)
    ("TensegrityShape-v0", "shape:TensegrityShapeEnv", "torch_vec:shape_vector_env", 200),
    ("TensegrityRoll-v0", "roll:TensegrityRollEnv", "torch_vec:roll_vector_env", 1000),
    ("TensegrityClimb-v0", "climb:TensegrityClimbEnv", "torch_vec:climb_vector_env", 1000),
    ("TensegrityNavigate-v0", "navigate:TensegrityNavigateEnv", "torch_vec:navigate_vector_env", 3000),   # 60 s
    # MuJoCo twins of TensegrityRoll-v0, TensegrityNavigate-v0 and TensegrityClimb-v0 (need the mujoco extra)
    ("TensegrityRollMuJoCo-v0", "roll_mujoco:TensegrityRollMuJoCoEnv", None, 1000),
    ("TensegrityNavigateMuJoCo-v0", "navigate_mujoco:TensegrityNavigateMuJoCoEnv", None, 3000),
    ("TensegrityClimbMuJoCo-v0", "climb_mujoco:TensegrityClimbMuJoCoEnv", None, 1000),
)


def register_envs() -> None:
    from gymnasium.envs.registration import register, registry

    for env_id, entry, vector_entry, max_steps in _REGISTRY:
        if env_id in registry:
            continue
        kw = {} if vector_entry is None else {"vector_entry_point": f"tensegrity_gym.envs.{vector_entry}"}
        register(id=env_id, entry_point=f"tensegrity_gym.envs.{entry}", max_episode_steps=max_steps, **kw)
