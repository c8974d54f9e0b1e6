"""Device-resident vector envs of ``TensegrityRoll-v0``, ``TensegrityClimb-v0``, ``TensegrityNavigate-v0`` and
``TensegrityShape-v0`` on the torch backend (SI units).

``gymnasium.make_vec("TensegrityRoll-v0", num_envs=N, vectorization_mode="vector_entry_point",
backend="torch", device="cuda", dtype="float32")`` returns a :class:`TorchRollVectorEnv`: a
``gymnasium.vector.VectorEnv`` whose ``step`` takes an action tensor (N, na) and returns
``(obs, reward, terminated, truncated, info)`` as torch tensors on ``device`` (obs (N, obs_size)
and reward (N,) in ``dtype``, terminated / truncated (N,) bool; ``info`` a dict of (N, ...)
tensors with Gymnasium's ``"_key"`` masks as bool tensors), as ManiSkill / Isaac Lab do. Without
``backend="torch"`` the registered id builds the NumPy/numba
:class:`~tensegrity_gym.envs.roll.TensegrityRollVectorEnv`, unchanged.

One task, two backends
----------------------
The task is :class:`~tensegrity_gym.envs.roll.RollTask`'s: this env builds a ``RollTask`` with
the same keyword arguments (robot, actuation, contact, rewards, limits, ``params=`` /
``randomize=`` / ``action_delay`` / ``start_rest_length_offset``) and uses it

* as the configuration (model, contact, actuation, weights, divergence limit), and
* **on the host at reset only** (``reset_sampling="host"``, the default): ``RollTask.reset``
  draws each reset env's robot parameters, initial-state noise and goal from that env's own
  NumPy generator (exactly the numbers the NumPy vector env draws: env i seeded ``seed + i``);
  the reset rows are then copied to the device once (state, control, goal, start, and the
  per-copy parameters when randomised).

With ``reset_sampling="device"`` (``TensegrityRoll-v0``, its terrains included, and
``TensegrityClimb-v0``, the slope its first draw) the reset runs on the device too: the
same draws (noise, goal, randomised parameters; same distributions, same order) from per-env
counter-based streams keyed by the same seeding rule, applied to the device tensors with no host
loop and no copy (:mod:`tensegrity_gym.envs.torch_reset`: what the numbers depend on, and the
test that a host reset fed them gives the same state). An autoreset then reads nothing from the
host but the 3 flags of every step. ``TensegrityShape-v0`` refuses it (its targets are Newton
equilibria with rejection, solved on the host), and so does ``TensegrityNavigate-v0`` (its
courses are planned on the host).

The step loop runs on the device: the cable motor / control update
(:func:`tensegrity_gym.backends.torch.actuation.update_motor` / :func:`~tensegrity_gym.backends.torch.actuation.update_rate`),
the physics inputs, ``frame_skip`` physics steps with ground contact
(:func:`tensegrity_gym.backends.torch.contact.contact_step`: per-copy ``Params`` and contact
parameters), the divergence check and restore, the observation, the reward terms and the time
limit. Per ``step`` the host reads ONE small tensor (3 bools: an action entry non-finite, one
out of the box with ``clip_actions=False``, an env to autoreset) to raise a clear error and to
know whether to reset; when an env finished, with host resets its mask (N bools) is read and its
reset drawn on the host as above (with device resets, nothing more). Nothing else crosses
between host and device in a step.

Matching the NumPy env: in float64 on CPU the observations, reward terms and infos equal the
NumPy vector env's to round-off (``tests/test_torch_env.py``: 50 control steps, autoreset,
``randomize``, ``params``, ``action_delay``, force-density mode). The NumPy env's observation
is float32; this env returns ``dtype`` (float64 gives the float64 numbers before that cast).

``TensegrityShape-v0`` (:class:`TorchShapeVectorEnv`) works the same way on
:class:`~tensegrity_gym.envs.shape.ShapeTask`: targets and initial states drawn on the host at
reset, the control update, the physics (with the model's node drag), the divergence check, the
tracking errors, the ``tracking`` / ``proximity`` / ``ctrl`` reward terms and the observation on
the device; it equals the NumPy vector env to round-off in the same tests.

``observation_mode="robot"`` (what a lab robot senses, :mod:`tensegrity_gym.envs.sensors`) is
computed on the device by :class:`~tensegrity_gym.envs.torch_sensors.TorchSensors`; its
``sensor_noise`` comes from per-env counter-based streams on the device keyed by ``reset(seed=...)`` (that module's doc).
Not supported here (``ValueError`` at construction): ``render_mode`` (use the NumPy env to
render), the implicit integrators (the torch backend has ``semi_implicit_euler`` and ``rk4``).

``TensegrityNavigate-v0`` (:class:`~tensegrity_gym.envs.torch_tasks.TorchNavigateVectorEnv`): each
reset env's course drawn and planned on the host, its goals and path-distance fields copied to
the device; the goals reached, the planner's guidance, the ``goal`` term, success (which ends
the episode) and the observation on the device (:mod:`tensegrity_gym.tasks.navigate`, the NumPy
env's functions on tensors).

``terrain=`` / ``terrain_difficulty`` (``TensegrityRoll-v0``, :mod:`tensegrity_gym.tasks.terrain`)
as the NumPy env takes them: at a host reset ``RollTask`` draws each reset env's terrain from
its generator, lifts the start clear of it and releases its contact state; those rows go to the
device and the steps run the torch terrain contact (:mod:`tensegrity_gym.envs.torch_terrain`;
the curriculum's ``env.task.set_terrain_difficulty(d)`` acts from the next resets). It equals
the NumPy vector env to round-off in float64 on CPU (``tests/test_torch_terrain.py``). With
``reset_sampling="device"`` a generator's terrains are drawn on the device from each env's
stream (:func:`tensegrity_gym.tasks.terrain.drawn_values`, the host's draw; the host task's
``terrains`` list is then not updated). ``compile=True`` compiles the terrain's physics step
(:func:`tensegrity_gym.backends.torch.terrain.terrain_substep`; 5-60 s on a 2-core CPU, longest
with boxes).

``compile=True`` wraps the physics step (roll: with contact,
:func:`tensegrity_gym.backends.torch.contact.contact_substep`; shape:
:func:`tensegrity_gym.backends.torch.driver.step_once`) in ``torch.compile``: the first steps
compile (10-35 s on a 2-core CPU, 7-17 s on an H100), then a control step ran 2-8x faster than
eager on CPU, and 4.5-6.1x on an H100 at N = 65,536 (roll: 74-123M physics env-steps/s), in
``scripts/bench/bench_gpu.py --env --env-compile`` (``docs/bench_gpu.md``). With ``compile=True`` on a
CUDA device, ``cuda_graph=True`` captures a control step's physics (``frame_skip`` compiled
sub-steps, hundreds of kernels) once as a CUDA graph and replays it at each step
(:mod:`tensegrity_gym.backends.torch.graphs`): one launch instead of hundreds, where launches,
not the device, set the pace (on an H200, a control step of 1,024 / 8,192 envs took 4.6 / 3.4 ms
against 17.2 / 24.7 ms compiled, ``scripts/bench/profile_torch_env.py --cuda-graph``). The graph
holds its own compile of the physics: float32 results can differ from ``compile=True``'s alone
in the last bits. Reset sampling on the host
costs a Python loop over the reset envs (14-35 us per env on a 2-core CPU, the same as the
NumPy env's reset), paid when envs finish; ``reset_sampling="device"`` took 1.7-1.9 us per env
on the same CPU at B = 1,024-16,384 (``scripts/bench/bench_gpu.py --env-reset``, ``docs/bench_gpu.md``).

Autoreset and seeding are those of :class:`~tensegrity_gym.envs.common.TaskVectorEnv`:
``autoreset_mode`` ``"next_step"`` (default), ``"same_step"`` or ``"disabled"``; ``reset(seed=s)`` seeds env i with ``s + i`` (with device resets:
keys env i's stream with ``s + i``; ``np_random_list`` then holds host generators the env does
not read); ``reset(options=
{"reset_mask": mask})`` resets the envs where the (N,) bool mask (NumPy or tensor) is true,
``reset(options={"env_idx": idx})`` the envs ``idx`` (the device-env convention of ManiSkill,
Isaac Lab and skrl); :mod:`tensegrity_gym.envs.torch_wrappers` has episode statistics and
normalisation wrappers that accept its tensors;
``max_episode_steps`` (``make_vec`` passes the registered 1000) truncates every env.
"""
from __future__ import annotations

from gymnasium.envs.registration import load_env_creator

from .torch_shell import TorchTaskVectorEnv
from .torch_tasks import (TorchClimbVectorEnv, TorchNavigateVectorEnv, TorchRollVectorEnv, TorchShapeVectorEnv,
                          torch_env_class)

_TorchTaskVectorEnv = TorchTaskVectorEnv   # the shell's former name (class paths in saved objects)

__all__ = ["TorchRollVectorEnv", "TorchShapeVectorEnv", "TorchClimbVectorEnv", "TorchNavigateVectorEnv",
           "vector_env", "device_env"]

#: (task class, env id) -> its device env class, built once
_DEVICE_ENVS: dict = {}


def _no_torch_kwargs(kwargs):
    for name in ("device", "dtype", "compile", "reset_sampling", "cuda_graph"):
        if name in kwargs:
            raise ValueError(f"{name}: only with backend='torch' (got backend={kwargs.get('backend', 'auto')!r})")


def device_env(numpy_env: type) -> type:
    """The torch device env of the NumPy vector env class ``numpy_env`` (a
    :class:`~tensegrity_gym.envs.shells.TaskVectorEnv` of a task): the same task
    (``numpy_env.task_class``) on :func:`~tensegrity_gym.envs.torch_tasks.torch_env_class`."""
    key = (numpy_env.task_class, numpy_env.env_id)
    if key not in _DEVICE_ENVS:
        _DEVICE_ENVS[key] = torch_env_class(*key)
    return _DEVICE_ENVS[key]


def vector_env(numpy_env: str, num_envs: int, kwargs: dict):
    """The vector env of a registered task (``vector_entry_point``: :class:`tensegrity_gym.envs.VectorEntry`):
    its device env (:func:`device_env`) when ``backend="torch"``, else its NumPy vector env
    ``numpy_env`` (``"package.module:Class"``) with the arguments passed through untouched."""
    cls = load_env_creator(numpy_env)
    if kwargs.get("backend") == "torch":
        return device_env(cls)(num_envs=num_envs, **kwargs)
    _no_torch_kwargs(kwargs)
    return cls(num_envs=num_envs, **kwargs)
