"""Training and evaluation of Stable-Baselines3 agents on tensegrity_gym (and any Gymnasium) envs.

* ``python -m agents.train --algo ppo --env TensegrityShape-v0`` -- see :mod:`agents.train`;
* ``python -m agents.evaluate RUN_DIR`` -- see :mod:`agents.evaluate`;
* hyperparameters: ``agents/hyperparams/<algo>.yml`` (rl-baselines3-zoo format).
"""
