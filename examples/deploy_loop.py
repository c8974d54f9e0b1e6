"""The loop a robot runs with an exported policy: read the sensors at the control rate, act,
write the motor commands, sleep to the next tick.

    python -m agents.export RUN_DIR --format npz            # RUN_DIR/policy.npz + policy.npz.json
    python examples/deploy_loop.py RUN_DIR/policy.npz --steps 500
    python examples/deploy_loop.py RUN_DIR/policy.npz --steps 20 --no-sleep

The policy runs through :class:`tensegrity_gym.integrations.policy_runner.PolicyRunner`, which
needs NumPy alone for an ``.npz`` export (onnxruntime for ``.onnx``, torch for ``.pt``). Here the
robot is simulated: :class:`SimulatedRobot` reads the sensors from the env the policy was trained
on (the spec's env id and arguments: with ``observation_mode="robot"`` the robot's own sensors,
cable lengths, motor positions and speeds, IMUs and contact switches; otherwise the simulator's
state) and writes the motor commands by stepping that env (which also applies the action delay
the policy was trained with). On a robot, replace it with the drivers: ``read_sensors()``
returns the observation in the layout and units of the spec's ``observation`` section (with the
``history`` of past readings stacked, newest first), ``write_motors(action)`` sends the commands
as its ``action`` section describes (``meaning``, ``actuated``).
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from tensegrity_gym.integrations.policy_runner import PolicyRunner


class SimulatedRobot:
    """The robot's drivers, simulated by the env of the policy's spec (reset with ``seed``; a new
    episode, seed + 1, ..., when one ends)."""

    def __init__(self, spec: dict, seed: int = 0):
        import gymnasium as gym
        import tensegrity_gym

        gym.register_envs(tensegrity_gym)      # the env ids (importing the package registers them)
        self.env = gym.make(spec["env"]["id"], **spec["env"]["kwargs"])
        self.seed = seed
        self.obs, _ = self.env.reset(seed=seed)
        self.episode_return, self.returns = 0.0, []

    def read_sensors(self) -> np.ndarray:
        """The observation the policy expects (float32, SI units, the spec's layout)."""
        return self.obs

    def write_motors(self, action: np.ndarray) -> None:
        """Send the commands: here one control step of the simulated robot."""
        self.obs, reward, terminated, truncated, _ = self.env.step(action)
        self.episode_return += float(reward)
        if terminated or truncated:
            self.returns.append(self.episode_return)
            self.episode_return = 0.0
            self.seed += 1
            self.obs, _ = self.env.reset(seed=self.seed)

    def close(self) -> None:
        self.env.close()


def control_loop(runner: PolicyRunner, robot, steps: int, sleep: bool = True) -> dict:
    """Run ``steps`` control steps at the spec's control rate: read, act, write, then sleep to the
    next tick (``sleep=False``: at once, for tests and benchmarks). A step that overruns its tick
    is counted and the schedule restarts from now (ticks are never made up in a burst).
    Returns the timing: policy time per step (s, mean and max), overruns, wall time (s)."""
    period = runner.control_dt or 0.0
    for _ in range(3):      # the first calls of a TorchScript module or an ONNX session optimise and allocate
        runner(robot.read_sensors())
    act_times = []
    overruns = 0
    start = next_tick = time.monotonic()
    for _ in range(steps):
        obs = robot.read_sensors()
        t0 = time.perf_counter()
        action = runner(obs)
        act_times.append(time.perf_counter() - t0)
        robot.write_motors(action)
        if not sleep:
            continue
        next_tick += period
        wait = next_tick - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        else:
            overruns += 1
            next_tick = time.monotonic()
    return {"steps": steps, "act_mean_s": float(np.mean(act_times)) if act_times else 0.0,
            "act_max_s": float(np.max(act_times)) if act_times else 0.0, "overruns": overruns,
            "wall_s": time.monotonic() - start}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("policy", help="the exported policy (.npz, .pt or .onnx) or its spec (.json)")
    p.add_argument("--steps", type=int, default=250, help="control steps to run (default 250)")
    p.add_argument("--seed", type=int, default=0, help="the simulated robot's first episode seed")
    p.add_argument("--no-sleep", action="store_true", help="do not wait for the control rate's ticks")
    args = p.parse_args(argv)
    if args.steps < 1:
        print(f"error: --steps: must be >= 1, got {args.steps}", file=sys.stderr)
        return 2
    try:
        runner = PolicyRunner(args.policy)
    except (OSError, ValueError, ImportError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    spec = runner.spec
    robot = SimulatedRobot(spec, args.seed)
    try:
        stats = control_loop(runner, robot, args.steps, sleep=not args.no_sleep)
    finally:
        robot.close()
    rate = spec["control"]["rate_hz"]
    print(f"{spec['env']['id']} ({spec['observation'].get('mode', 'state')} observations, "
          f"{spec['latency']['action_delay_steps']} steps action delay): {stats['steps']} control steps at "
          f"{'' if rate is None else f'{rate:g} Hz '}in {stats['wall_s']:.2f} s"
          f"{' (no sleep)' if args.no_sleep else ''}; policy ({runner.backend}) {stats['act_mean_s'] * 1e3:.3f} ms "
          f"mean, {stats['act_max_s'] * 1e3:.3f} ms max per step; {stats['overruns']} overruns; "
          f"episodes finished {len(robot.returns)}, return so far {robot.episode_return:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
