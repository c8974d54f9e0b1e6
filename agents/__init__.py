"""Training and evaluation of Stable-Baselines3 agents on tensegrity_gym (and any Gymnasium) envs.

* ``python -m agents.train --algo ppo --env TensegrityShape-v0`` -- see :mod:`agents.train`;
* ``python -m agents.evaluate RUN_DIR`` -- see :mod:`agents.evaluate`;
* ``python -m agents.export RUN_DIR --format onnx|torchscript|npz`` -- one policy file for a robot, see
  :mod:`agents.export` and ``docs/deployment.md``;
* ``python -m agents.tune CONFIG.yml`` -- sweeps and multi-seed repeats on Ray Tune, see :mod:`agents.tune`;
* ``python -m agents.zoo record_video ...`` -- rl_zoo3 commands with the envs registered;
* hyperparameters: ``agents/hyperparams/<algo>.yml`` (rl-baselines3-zoo format), sweep configs
  ``agents/sweeps/*.yml``; both ship inside the installed package.
"""
