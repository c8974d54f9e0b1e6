"""Adapters to other libraries, each importing its library only when used: Stable-Baselines3
(:mod:`.sb3`), rl-baselines3-zoo (:mod:`.zoo`, the module to name in ``rl_zoo3 ...
--gym-packages tensegrity_gym.integrations.zoo``), rsl_rl (:mod:`.rsl_rl`: the ``VecEnv`` of its
``OnPolicyRunner``) and tianshou (:mod:`.tianshou`: a ``BaseVectorEnv``). skrl, TorchRL and
CleanRL-style scripts take the vector envs as they are (``docs/integrations.md``).
:mod:`.policy_runner` runs a policy exported by ``python -m agents.export`` (NumPy, onnxruntime or
torch; ``docs/deployment.md``)."""
