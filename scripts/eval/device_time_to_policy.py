#!/usr/bin/env python
"""Time to policy on one device: rsl_rl's PPO (``OnPolicyRunner``) trains the rolling prism
(``TensegrityRoll-v0``) on the device-resident torch vector env, env and learner on the same
device (``--device cpu`` or ``cuda``), until the policy's mean forward speed first reaches the
target (default 0.345 m/s) or the wall-clock budget ends.

    python -m scripts.eval.device_time_to_policy --device cpu --budget-s 600 --out results/device_time_to_policy/cpu.json
    python -m scripts.eval.device_time_to_policy --device cuda --compile --cuda-graph --reset-sampling device \
        --num-envs 1024 --entropy-coef 0.005 --budget-s 120 --out gpu.json
    python -m scripts.eval.device_time_to_policy --table results/device_time_to_policy/cpu_search/*.json

``--env-backend numpy`` trains on the NumPy/numba vector env instead (tensors on ``--device``):
on a CPU it runs faster than the torch env, for searching learner settings in iterations and env
steps (the same task). ``--table`` prints a markdown table of result files.

Every ``--eval-every-s`` seconds of training the policy's mean action (no exploration noise) is
run for one full episode (20 s) of ``--eval-envs`` envs of a separate torch env on the same
device, reset with the held-out seeds 1000000, 1000001, ...; its speed is the distance rolled
toward the goal direction over the episode's duration (m/s), averaged over the envs, as
``agents.evaluate`` reports it. Training wall time counts rollout and learner only (the
evaluations are timed apart and reported beside it); the first compile of the env (warm-up
iteration) is not counted either.

The JSON result names the device (CPU model from ``lscpu``, or the GPU's name), torch version,
threads, seed, settings, env steps and wall time at the first evaluation at or above the
target (or null), the training time split into rollouts and updates (``collection_wall_s``,
``update_wall_s``: rsl_rl's own timers, summed; the iterations before the first timed one left
out), and every evaluation (training seconds, env steps, speed). It is written after
every evaluation, so that a run cut short (a time limit, Ctrl-C) keeps what it measured;
``stopped`` says why the run ended: ``target reached``, ``budget``, ``interrupted``, or
``running`` in a file left by a killed run.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import sys
import time
from pathlib import Path

from tensegrity_gym.io.atomic import check_writable, write_atomic
from tensegrity_gym.integrations.torch_threads import passive_openmp_wait
from tensegrity_gym_agents.common import cpu_model, cpus_available

from scripts._bench import sync

HELD_OUT_SEED = 1_000_000


def runner_config(args) -> dict:
    """rsl_rl 5.x ``OnPolicyRunner`` config: PPO with the rolling recipe's discounting (gamma
    0.995, lambda 0.98) and nets (128x128), the learning rate adaptive (to a KL of 0.01) or fixed,
    observation normalisation."""
    from tensegrity_gym.integrations.rsl_rl import train_config
    cfg = train_config(num_steps_per_env=args.steps_per_env, hidden=(128, 128), learning_rate=args.learning_rate,
                       seed=args.seed, gamma=0.995, lam=0.98, num_learning_epochs=args.epochs,
                       num_mini_batches=args.mini_batches, entropy_coef=args.entropy_coef, desired_kl=0.01,
                       schedule=args.schedule)
    cfg["actor"]["distribution_cfg"]["init_std"] = args.init_std
    return cfg


def evaluate_speed(policy, env, steps: int, dt: float, torch) -> float:
    """Mean forward speed (m/s) of ``policy`` over one episode of every env of ``env`` (next-step
    autoreset: an env's final info arrives on the step that ends it)."""
    from tensordict import TensorDict
    # no_grad, not inference_mode: the env's state tensors written here are written again
    # (in place) by the next evaluation's reset, which inference tensors forbid
    with torch.no_grad():
        obs, _ = env.reset(seed=HELD_OUT_SEED)
        n = env.num_envs
        dist = torch.zeros(n, device=obs.device)
        length = torch.zeros(n, device=obs.device)
        active = torch.ones(n, dtype=torch.bool, device=obs.device)
        for k in range(steps):
            last = torch.tensor(k == steps - 1, device=obs.device)   # a shortened episode ends here
            td = TensorDict({"policy": obs, "critic": obs}, batch_size=[n], device=obs.device)
            obs, _, term, trunc, info = env.step(torch.clamp(policy(td), -1.0, 1.0))
            length += active
            ended = active & (term | trunc)
            dist = torch.where(ended | (active & last), info["distance_rolled"].to(dist.dtype), dist)
            active &= ~ended
            if not bool(active.any()):
                break
    return float((dist / (length.clamp(min=1) * dt)).mean())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cpu", help="cpu or cuda (cuda:N): env and learner both run there")
    p.add_argument("--budget-s", type=float, default=600.0, help="training wall-clock budget, s (default 600)")
    p.add_argument("--max-iterations", type=int, default=None, help="stop after this many PPO iterations too")
    p.add_argument("--target", type=float, default=0.345, help="mean forward speed to reach, m/s (default 0.345)")
    p.add_argument("--num-envs", type=int, default=1024, help="training envs (default 1024)")
    p.add_argument("--steps-per-env", type=int, default=32, help="rollout length per PPO iteration (default 32)")
    p.add_argument("--epochs", type=int, default=2, help="PPO epochs per iteration (default 2)")
    p.add_argument("--mini-batches", type=int, default=8, help="minibatches per epoch (default 8)")
    p.add_argument("--learning-rate", type=float, default=1e-3,
                   help="learning rate, the start of an adaptive one (default 1e-3)")
    p.add_argument("--schedule", default="adaptive", choices=["adaptive", "fixed"],
                   help="learning rate: adapted to a KL of 0.01 per update (default) or fixed")
    p.add_argument("--entropy-coef", type=float, default=0.0, help="entropy bonus coefficient (default 0)")
    p.add_argument("--init-std", type=float, default=1.0, help="initial action standard deviation (default 1)")
    p.add_argument("--eval-envs", type=int, default=64, help="envs of each speed evaluation (default 64)")
    p.add_argument("--eval-episode-steps", type=int, default=None,
                   help="control steps of each evaluation episode (default: the env's full episode, 20 s; "
                        "shorter only for quick checks: the target is defined on full episodes)")
    p.add_argument("--eval-every-s", type=float, default=60.0, help="training seconds between evaluations (default 60)")
    p.add_argument("--eval-every-iterations", type=int, default=None,
                   help="evaluate every this many iterations instead (small test runs)")
    p.add_argument("--compile", action="store_true",
                   help="compile=True on the training and evaluation envs (torch.compile of the physics step; "
                        "the training env's compile falls in the uncounted warm-up iteration)")
    p.add_argument("--cuda-graph", action="store_true",
                   help="cuda_graph=True on the training and evaluation envs (needs --compile and a CUDA device: "
                        "each control step's physics replayed as one CUDA graph)")
    p.add_argument("--reset-sampling", default="host", choices=["host", "device"],
                   help="the training env's reset sampling (default host; the evaluation env always resets on "
                        "the host from the held-out seeds)")
    p.add_argument("--env-backend", default="torch", choices=["torch", "numpy"],
                   help="the training env: the torch device env (default), or the NumPy/numba vector env with "
                        "tensors on --device (a CPU search of learner settings: the same task, counted in "
                        "iterations and env steps)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: the CPUs available)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--label", default=None, help="free text stored in the JSON (e.g. the machine's load)")
    p.add_argument("--out", help="JSON result file (required unless --table)")
    p.add_argument("--table", nargs="+", metavar="JSON", help="print a markdown table of these results and exit")
    args = p.parse_args(argv)
    if args.table:
        try:
            print(results_table(args.table))
        except ValueError as e:
            p.error(str(e))
        return 0
    if not args.out:
        p.error("--out is required (or --table)")
    if args.cuda_graph and not args.compile:
        p.error("--cuda-graph needs --compile")
    if args.cuda_graph and args.env_backend != "torch":
        p.error("--cuda-graph needs --env-backend torch")
    out = check_writable(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    passive_openmp_wait()          # before torch loads its OpenMP runtime

    import gymnasium as gym
    import torch
    from rsl_rl.runners import OnPolicyRunner

    import tensegrity_gym
    from tensegrity_gym.integrations.rsl_rl import make_rsl_rl_env

    cpus = cpus_available()
    torch.set_num_threads(args.threads or cpus)
    torch.manual_seed(args.seed)
    device = torch.device(args.device)
    if args.env_backend == "torch":
        env = make_rsl_rl_env("TensegrityRoll-v0", num_envs=args.num_envs, backend="torch", device=args.device,
                              seed=args.seed, compile=args.compile, reset_sampling=args.reset_sampling,
                              cuda_graph=args.cuda_graph)
    else:
        env = make_rsl_rl_env("TensegrityRoll-v0", num_envs=args.num_envs, backend="numpy", device=args.device,
                              seed=args.seed)
    eval_env = gym.make_vec("TensegrityRoll-v0", num_envs=args.eval_envs, vectorization_mode="vector_entry_point",
                            backend="torch", device=args.device, dtype="float32", compile=args.compile,
                            cuda_graph=args.cuda_graph)
    dt = float(eval_env.unwrapped.dt)
    episode_steps = int(args.eval_episode_steps or eval_env.unwrapped.max_episode_steps)
    cfg = runner_config(args)
    runner = OnPolicyRunner(env, cfg, log_dir=None, device=args.device)
    samples_per_iteration = args.num_envs * args.steps_per_env
    # rsl_rl times each iteration's rollout (collection) and update for its logger: summed here
    split = {"collection": 0.0, "update": 0.0}
    log = runner.logger.log

    def log_times(*a, **kw):
        split["collection"] += kw["collect_time"]
        split["update"] += kw["learn_time"]
        return log(*a, **kw)
    runner.logger.log = log_times

    # warm-up: one iteration (first kernel launches / compiles), not counted; then restart the
    # counters so the timed run starts from the same kind of state as the budget assumes
    t = time.perf_counter()
    runner.learn(1, init_at_random_ep_len=True)
    runner.current_learning_iteration += 1
    sync(device)
    warmup_s = time.perf_counter() - t
    split.update(collection=0.0, update=0.0)      # the timed iterations only

    def result(stopped: str) -> dict:
        """The JSON result so far; ``stopped`` says why the run ended (or ``"running"``)."""
        return {
            "task": "TensegrityRoll-v0, rsl_rl PPO (OnPolicyRunner), torch device env, env and learner on one device",
            "device": str(device),
            "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else cpu_model(),
            "cpu_model": cpu_model(), "cpus_available": cpus, "torch_num_threads": torch.get_num_threads(),
            "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
            "torch": torch.__version__, "tensegrity_gym": getattr(tensegrity_gym, "__version__", None),
            "rsl_rl": _version("rsl-rl-lib"), "python": platform.python_version(), "platform": platform.platform(),
            "seed": args.seed, "target_speed_m_s": args.target, "budget_s": args.budget_s,
            "settings": {"num_envs": args.num_envs, "steps_per_env": args.steps_per_env, "epochs": args.epochs,
                         "mini_batches": args.mini_batches, "learning_rate": args.learning_rate,
                         "schedule": args.schedule, "entropy_coef": args.entropy_coef,
                         "init_std": args.init_std, "env_backend": args.env_backend,
                         "compile": args.compile, "cuda_graph": args.cuda_graph,
                         "reset_sampling": args.reset_sampling,
                         "eval_envs": args.eval_envs, "eval_episode_s": episode_steps * dt,
                         "runner_config": cfg},
            "reached": reached is not None,
            "time_to_target_s": reached["training_wall_s"] if reached else None,
            "env_steps_to_target": reached["env_steps"] if reached else None,
            "training_wall_s": round(train_s, 2), "env_steps": iterations * samples_per_iteration,
            "iterations": iterations, "warmup_s": round(warmup_s, 2), "evaluation_wall_s": round(eval_s, 2),
            "collection_wall_s": round(split["collection"], 2), "update_wall_s": round(split["update"], 2),
            "best_speed_m_s": max(e["speed_m_s"] for e in evals) if evals else None,
            "evaluations": evals, "label": args.label, "stopped": stopped,
            "command": shlex.join(["python", "-m", "scripts.eval.device_time_to_policy"] + (argv if argv is not None else
                                                                                    sys.argv[1:])),
        }

    iterations, train_s, eval_s = 1, 0.0, 0.0
    evals, reached = [], None
    next_eval, next_beat = args.eval_every_s, 10.0
    policy = runner.get_inference_policy(args.device)
    stopped = "target reached"
    try:
        while True:
            t = time.perf_counter()
            runner.learn(1)
            runner.current_learning_iteration += 1
            sync(device)
            train_s += time.perf_counter() - t
            iterations += 1
            if train_s >= next_beat:        # a line every 10 s of training, also in a log
                print(f"{train_s:7.1f} s training, {iterations * samples_per_iteration:>10} env steps "
                      f"({iterations * samples_per_iteration / train_s:.0f} env-steps/s; rollouts "
                      f"{split['collection']:.1f} s, updates {split['update']:.1f} s)", flush=True)
                next_beat += 10.0
            last = train_s >= args.budget_s or (args.max_iterations is not None and iterations >= args.max_iterations)
            due = (iterations % args.eval_every_iterations == 0) if args.eval_every_iterations else train_s >= next_eval
            if due or last:
                t = time.perf_counter()
                runner.alg.eval_mode()      # frozen observation normalisation (learn() switches back)
                speed = evaluate_speed(policy, eval_env, episode_steps, dt, torch)
                sync(device)
                eval_s += time.perf_counter() - t
                evals.append({"training_wall_s": round(train_s, 2), "env_steps": iterations * samples_per_iteration,
                              "iterations": iterations, "speed_m_s": round(speed, 4)})
                print(f"{train_s:7.1f} s training, {iterations * samples_per_iteration:>10} env steps: "
                      f"speed {speed:.3f} m/s (evaluations so far {eval_s:.1f} s)", flush=True)
                while next_eval <= train_s:
                    next_eval += args.eval_every_s
                if reached is None and speed >= args.target:
                    reached = evals[-1]
                _write_json(out, result("running"))        # kept if the run is cut short
                if reached is not None:
                    break
            if last:
                break
    except KeyboardInterrupt:
        stopped = "interrupted"
    if stopped != "interrupted" and reached is None:
        stopped = "budget"
    final = result(stopped)
    _write_json(out, final)
    print(("reached" if reached else "did not reach") + f" {args.target} m/s: " +
          (f"{reached['training_wall_s']} s of training, {reached['env_steps']} env steps" if reached else
           f"best {final['best_speed_m_s']} m/s in {final['training_wall_s']} s, {final['env_steps']} env steps") +
          f" on {final['device_name']} -> {out}")
    env.close()
    eval_env.close()
    return 0


def results_table(paths, at=(80, 160, 240)) -> str:
    """A markdown table of result files: settings, seed, iterations, env steps, the speeds at the
    evaluations of iterations ``at`` (where evaluated), the best speed, whether it reached the
    target and why the run stopped."""
    head = ("| run | device | envs x steps | epochs x minibatches | std | lr schedule | entropy | seed | iterations "
            "| env steps | " + " | ".join(f"speed at it. {k} (m/s)" for k in at)
            + " | best (m/s) | reached | stopped |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for path in paths:
        try:
            r = json.loads(Path(path).read_text())
            st = r["settings"]
            speed = {e["iterations"]: e["speed_m_s"] for e in r["evaluations"]}
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise ValueError(f"--table {path!r}: not a result file of this script ({type(e).__name__}: {e})") from None
        cells = [os.path.basename(path), f"{r['device_name']} ({st.get('env_backend', 'torch')} env)",
                 f"{st['num_envs']} x {st['steps_per_env']}", f"{st['epochs']} x {st['mini_batches']}",
                 f"{st['init_std']}", st.get("schedule", "adaptive"), f"{st.get('entropy_coef', 0.0)}", f"{r['seed']}",
                 f"{r['iterations']}", f"{r['env_steps'] / 1e6:.2f}M"]
        cells += [f"{speed[k]:.3f}" if k in speed else "-" for k in at]
        cells += [f"{r['best_speed_m_s']:.3f}", "yes" if r["reached"] else "no", r.get("stopped", "-")]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _write_json(path, data: dict) -> None:
    text = json.dumps(data, indent=2) + "\n"
    write_atomic(path, lambda f: f.write(text.encode()))


def _version(dist: str) -> str | None:
    from importlib import metadata
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


if __name__ == "__main__":
    raise SystemExit(main())
