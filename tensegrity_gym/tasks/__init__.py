"""What the robot is asked to do, written once for NumPy arrays and torch tensors.

A task module holds the task's reward terms, infos, observation, reset draws and sensors as
functions of arrays whose library (:mod:`tensegrity_gym.tasks.xp`) is taken from the inputs: the
NumPy envs and the torch device envs of :mod:`tensegrity_gym.envs` call the same functions.

* :mod:`~tensegrity_gym.tasks.roll`: rolling locomotion (``TensegrityRoll-v0``);
* :mod:`~tensegrity_gym.tasks.shape`: shape tracking (``TensegrityShape-v0``);
* :mod:`~tensegrity_gym.tasks.sensors`: the robot's sensor reading (``observation_mode="robot"``);
* :mod:`~tensegrity_gym.tasks.randomization`: per-copy robot parameters from uniform draws.
"""
