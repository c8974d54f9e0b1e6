"""Adapters to other libraries: Stable-Baselines3 (:mod:`.sb3`) and rl-baselines3-zoo (:mod:`.zoo`,
the module to name in ``rl_zoo3 ... --gym-packages tensegrity_gym.integrations.zoo``)."""
