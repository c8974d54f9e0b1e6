"""Gymnasium environments (this subpackage imports gymnasium; the physics modules do not).

Registration happens in :func:`register_envs`, called when ``tensegrity_gym`` is imported.
Time limits are set here at registration, not inside the envs.
"""
from __future__ import annotations

ENV_IDS = ("TensegrityShape-v0", "TensegrityRoll-v0", "TensegrityRollMuJoCo-v0")


def register_envs() -> None:
    from gymnasium.envs.registration import register, registry

    if "TensegrityShape-v0" not in registry:
        register(
            id="TensegrityShape-v0",
            entry_point="tensegrity_gym.envs.shape:TensegrityShapeEnv",
            vector_entry_point="tensegrity_gym.envs.torch_vec:shape_vector_env",   # backend="torch": device-resident
            max_episode_steps=200,
        )
    if "TensegrityRoll-v0" not in registry:
        register(
            id="TensegrityRoll-v0",
            entry_point="tensegrity_gym.envs.roll:TensegrityRollEnv",
            vector_entry_point="tensegrity_gym.envs.torch_vec:roll_vector_env",   # backend="torch": device-resident
            max_episode_steps=1000,
        )
    if "TensegrityRollMuJoCo-v0" not in registry:   # MuJoCo twin of TensegrityRoll-v0 (needs the mujoco extra)
        register(
            id="TensegrityRollMuJoCo-v0",
            entry_point="tensegrity_gym.envs.roll_mujoco:TensegrityRollMuJoCoEnv",
            max_episode_steps=1000,
        )
