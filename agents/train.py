"""Train a Stable-Baselines3 agent on a tensegrity_gym (or any Gymnasium) env.

Usage (from any directory once the package is installed; from the repository root otherwise)::

    python -m agents.train --algo ppo --env TensegrityShape-v0 --env-kwargs action_mode:rest_length \\
        --n-timesteps 1e6 --seed 0 --log-dir results/ppo_shape_rest_length
    python -m agents.train --algo sac --env TensegrityRoll-v0 --hyperparams learning_rate=1e-3 batch_size=512
    python -m agents.train --resume results/ppo_shape_rest_length            # continue an interrupted run
    python -m agents.train --resume results/ppo_shape_rest_length --n-timesteps 2e6   # or extend it

Hyperparameters come from ``agents/hyperparams/<algo>.yml`` keyed by env id, in
rl-baselines3-zoo's format, so the zoo uses the same file:
``python -m rl_zoo3.train --gym-packages tensegrity_gym.integrations.zoo --algo ppo --env TensegrityShape-v0``
reads it without ``--conf-file`` (:mod:`tensegrity_gym.integrations.zoo`). ``--hyperparams key=value ...`` overrides entries;
``--env-kwargs key:value ...`` (or one JSON object) are merged over the file's ``env_kwargs``.
Values are parsed as JSON / Python literals (never ``eval``).

Environments: when the env id has a ``vector_entry_point`` (the tensegrity envs do), the
``n_envs`` copies are ONE batched vector env (one physics call per step) wrapped for SB3 by
:func:`tensegrity_gym.integrations.sb3.make_sb3_vec_env`; otherwise SB3's ``make_vec_env``
(``--vec-env dummy|subproc`` forces one). Env i of the training env is seeded ``seed + i``;
the evaluation env used during training is seeded ``seed + 10_000 + i`` (the final evaluation
in :mod:`agents.evaluate` uses other, held-out seeds).

Run directory (``--log-dir``, default ``runs/<algo>_<env>_s<seed>``, git-ignored)::

    model.zip, vecnormalize.pkl        final (or interrupted) model and normalisation statistics
    best_model.zip, best_vecnormalize.pkl   best model on the evaluation env (EvalCallback)
    checkpoints/                        rl_model_<steps>_steps.zip (+ vecnormalize / replay buffer)
    eval/evaluations.npz                EvalCallback results (timesteps, returns, lengths, successes)
    monitor/train_<segment>.monitor.csv episodes of the training env (return, length, info keys)
    tb/                                 TensorBoard: SB3 scalars + info/reward_* means + episode_end/*
    config.yaml, command.txt, versions.json, state.json
    .lock                               while a training runs in it: its pid, host and start time

Every file is written atomically (temporary file in the same folder, fsync, rename), so no
interrupt, crash or kill destroys the last good model; a crash is recorded in ``state.json`` as
``crashed`` with the error; a run that failed before saving any model can be started again in the
same folder; checkpoints and evaluations follow the run's step count, so ``--resume`` keeps their
schedule. Ctrl-C (KeyboardInterrupt) saves ``model.zip``, ``vecnormalize.pkl`` (and the replay buffer of
off-policy algorithms) before exiting (a second Ctrl-C waits for the save); ``--resume RUN_DIR`` reloads the latest of the
interrupted model and the checkpoints, the VecNormalize statistics and the replay buffer, and
continues with ``reset_num_timesteps=False`` up to the total ``n_timesteps`` (steps count on).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from . import common, hyperparameters, trainer
from .interrupts import exit_with, interrupted_exit_code
from .parsing import arg_type
from tensegrity_gym.core.checks import check_count, check_positive
from tensegrity_gym.integrations.torch_threads import num_threads_arg, passive_openmp_wait
from tensegrity_gym.io.atomic import OutputError

passive_openmp_wait()     # before torch loads its OpenMP runtime (see the function)


# ---------------------------------------------------------------------- argument parsing
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"python -m {common.PACKAGE}.train", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--algo", default="ppo", help=f"algorithm: {', '.join(hyperparameters.algo_names())} (default ppo)")
    p.add_argument("--env", default="TensegrityShape-v0", help="registered Gymnasium env id")
    p.add_argument("--env-kwargs", nargs="*", metavar="KEY:VALUE",
                   help="env constructor arguments as key:value pairs or one JSON object")
    p.add_argument("--n-timesteps", "-n", type=arg_type(lambda v: check_count(v, "--n-timesteps", 1)), default=None,
                   help="total env steps (default: the hyperparameter file's n_timesteps)")
    p.add_argument("--n-envs", type=int, default=None, help="parallel envs (default: the file's n_envs)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--log-dir", "-f", default=None, help="run directory (default runs/<algo>_<env>_s<seed>)")
    p.add_argument("--hyperparams", "-params", nargs="*", metavar="KEY=VALUE",
                   help="hyperparameter overrides, e.g. learning_rate=3e-4 n_steps=512 "
                        "policy_kwargs='dict(net_arch=[64, 64])'")
    p.add_argument("--conf-file", "-conf", default=None,
                   help="hyperparameter file: a shipped one named relative to the package's hyperparams folder (time_to_policy/ppo.yml), or a path to a file of your own (default: the shipped <algo>.yml)")
    p.add_argument("--resume", metavar="RUN_DIR", default=None,
                   help="continue the run in RUN_DIR from its latest checkpoint / interrupted model")
    p.add_argument("--warm-start", metavar="RUN_DIR", default=None,
                   help="start from that run's final policy and normalisation (same algorithm and network; "
                        "observation blocks matched by name, new ones start with zero weight: agents/warm_start.py)")
    p.add_argument("--vec-env", default="auto", choices=["auto", "batched", "torch", "dummy", "subproc"],
                   help="torch: the device-resident torch vector env (--env-device, --env-dtype) for training; "
                        "the evaluation env stays the NumPy/numba one")
    p.add_argument("--env-device", default=None, help="--vec-env torch: env device (default cuda if available, "
                                                      "else cpu)")
    p.add_argument("--env-dtype", default=None, choices=["float32", "float64"],
                   help="--vec-env torch: env dtype (default float32)")
    p.add_argument("--env-reset-sampling", default=None, choices=["host", "device"],
                   help="--vec-env torch: draw resets on the host (default; the NumPy env's numbers) or on the "
                        "device (per-env counter-based streams, no host loop; TensegrityRoll-v0)")
    p.add_argument("--eval-freq", type=int, default=None,
                   help="evaluate every this many env steps (default n_timesteps/20; <= 0 disables)")
    p.add_argument("--eval-episodes", type=arg_type(lambda v: check_count(v, "--eval-episodes", 1)), default=20)
    p.add_argument("--n-eval-envs", type=int, default=None, help="default min(eval episodes, 10)")
    p.add_argument("--save-freq", type=int, default=None,
                   help="checkpoint every this many env steps (default n_timesteps/10; <= 0 disables)")
    p.add_argument("--save-replay-buffer", action="store_true",
                   help="also checkpoint the replay buffer of off-policy algorithms (large)")
    p.add_argument("--num-threads", type=num_threads_arg, default=1, help="torch threads (default 1)")
    p.add_argument("--device", default="cpu", help="torch device (default cpu; MLP policies gain nothing on GPU)")
    p.add_argument("--no-progress-bar", action="store_true",
                   help="no progress lines (by default one every 10 s: steps, speed, ETA, last evaluation)")
    p.add_argument("--gym-packages", nargs="*", default=[],
                   help="extra modules to import (to register their envs); tensegrity_gym always is")
    p.add_argument("--steal-lock", action="store_true",
                   help="take over the run folder's lock left by a training that no longer runs here (or "
                        "runs on another host); --resume takes over a killed run's lock by itself")
    p.add_argument("--max-wall-time", type=arg_type(lambda v: check_positive(v, "--max-wall-time", "s")),
                   default=None, metavar="SECONDS",
                   help="stop training after this many seconds (saved as usual; status time_limit)")
    p.add_argument("--verbose", type=int, default=0)
    return p


# ---------------------------------------------------------------------- training
def train(argv: list[str] | None = None, extra_callbacks: list | None = None, report=None) -> Path:
    """Run training from command-line arguments; returns the run directory.

    ``extra_callbacks``: additional SB3 callbacks (tests use one to emulate Ctrl-C).
    ``report``: called with :func:`agents.run_dir.evaluation_metrics` and ``wall_time_s`` (the run's wall time so
    far, s, earlier segments included) after every evaluation (``agents.tune`` passes Ray Tune's
    ``tune.report``).

    The run folder is claimed before anything is written into it (its ``.lock`` names this
    process: :class:`tensegrity_gym.io.claim.Claim`); a second training into it is refused at once
    (``FileExistsError`` naming the holder's pid, host and start time) and the lock is removed when
    the training ends.
    """
    claims = []
    try:
        return trainer.run(build_parser().parse_args(argv), argv, extra_callbacks, report, claims)
    finally:
        for c in claims:
            c.release()


def main(argv: list[str] | None = None) -> int:
    try:
        run_dir = train(argv)
    except (ValueError, OSError, OutputError) as e:   # OSError: a read-only --log-dir, ... (FileNotFound/Exists included)
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:   # Ctrl-C / SIGTERM before the first step: state.json says interrupted
        print("interrupted during start-up (no model saved)", file=sys.stderr)
        return interrupted_exit_code()
    state = json.loads((run_dir / "state.json").read_text())
    return interrupted_exit_code() if state.get("status") == "interrupted" else 0


if __name__ == "__main__":
    exit_with(main())
