"""One training segment of :mod:`agents.train`: the run's settings (a new run, or ``--resume``
from its ``config.yaml``), its envs, model, callbacks and files, the learning loop, and the
record of how it ended in ``state.json``.
"""
from __future__ import annotations

import glob
import os
import socket
import time
from pathlib import Path

import numpy as np

from . import common, envs, heldout, hyperparameters, warm_start
from .interrupts import DeferInterrupts, install_interrupt_handlers
from .parsing import parse_kv_list, read_yaml, to_yaml_safe
from .progress import progress_callback
from .run_dir import RunState, clear_failed_start, has_saved_model, read_state, resume_files, save_final
from tensegrity_gym.integrations.torch_threads import set_torch_threads
from tensegrity_gym.io.claim import Claim

#: the evaluation env's seeds during training: ``seed + EVAL_SEED_OFFSET + i`` (the held-out rule
#: of :mod:`agents.heldout` counts them)
EVAL_SEED_OFFSET = heldout.EVAL_SEED_OFFSET


def _claim_run_dir(run_dir: Path, args, flag: str, resume: bool):
    """Claim ``run_dir`` for this training (``--resume`` takes over the lock of a killed run)."""
    return Claim(run_dir, folder=True, label=flag, steal=args.steal_lock, take_over_dead=resume)


def run(args, argv: list[str] | None, extra_callbacks, report, claims: list) -> Path:
    """Train as the parsed command line ``args`` (``argv``: as given, recorded in ``command.txt``)
    says; the run folder's claims are appended to ``claims`` (released by the caller). Returns
    the run directory. SB3 and torch are imported here, after :func:`tensegrity_gym.integrations.torch_threads.passive_openmp_wait`."""
    import yaml
    import torch

    envs.import_env_packages(["tensegrity_gym"] + list(args.gym_packages))
    set_torch_threads(args.num_threads)

    resume_dir = Path(args.resume) if args.resume else None
    if resume_dir is not None and args.warm_start:
        raise ValueError("--warm-start: a new run only; --resume continues a run from its own model")
    warm = None
    fresh_restart = False  # a run directory whose first attempt failed before saving any model
    if resume_dir is not None:
        cfg_path = resume_dir / "config.yaml"
        if not cfg_path.exists():
            raise FileNotFoundError(f"--resume {resume_dir}: no config.yaml there (not a run directory)")
        claims.append(_claim_run_dir(resume_dir, args, "--resume", resume=True))
        read_state(resume_dir)          # a damaged state.json is named before anything else
        cfg = common.read_run_config(cfg_path)
        run_dir = resume_dir
        fresh_restart = not has_saved_model(run_dir)
        algo, env_id, seed = cfg["algo"], cfg["env"], int(cfg["seed"])
        env_kwargs = cfg["env_kwargs"]
        raw_hp = cfg["hyperparams_raw"]
        source = cfg.get("hyperparams_source", "config.yaml")
        n_envs = int(cfg["n_envs"])
        n_timesteps = int(args.n_timesteps) if args.n_timesteps is not None else int(cfg["n_timesteps"])
        vec_mode = cfg.get("vec_env", "auto")
        env_device, env_dtype = cfg.get("env_device"), cfg.get("env_dtype", "float32")
        env_reset_sampling = cfg.get("env_reset_sampling", "host")
        eval_freq, save_freq = cfg["eval_freq"], cfg["save_freq"]
        eval_episodes, n_eval_envs = cfg["eval_episodes"], cfg["n_eval_envs"]
    else:
        algo = args.algo.lower()
        hyperparameters.get_algo(algo)
        env_id = args.env
        envs.check_env_id(env_id)
        file_hp, source = hyperparameters.hyperparams_for(algo, env_id, args.conf_file)
        overrides = parse_kv_list(args.hyperparams, "=", "--hyperparams")
        raw_hp = {**file_hp, **overrides}
        cli_env_kwargs = parse_kv_list(args.env_kwargs, ":", "--env-kwargs")
        env_kwargs = {**dict(raw_hp.get("env_kwargs") or {}), **cli_env_kwargs}
        raw_hp["env_kwargs"] = env_kwargs
        seed = envs.check_seed(args.seed)
        n_timesteps = int(args.n_timesteps) if args.n_timesteps is not None else \
            hyperparameters.check_hp_count(raw_hp.get("n_timesteps", 1e5), "n_timesteps", 1)
        n_envs = args.n_envs if args.n_envs is not None else int(raw_hp.get("n_envs", 1))
        if n_envs < 1:
            raise ValueError(f"--n-envs: must be >= 1, got {n_envs}")
        vec_mode = args.vec_env
        env_device, env_dtype, env_reset_sampling = args.env_device, args.env_dtype, args.env_reset_sampling
        for flag, value in (("--env-device", env_device), ("--env-dtype", env_dtype),
                            ("--env-reset-sampling", env_reset_sampling)):
            if vec_mode != "torch" and value is not None:
                raise ValueError(f"{flag}: only with --vec-env torch")
        if vec_mode == "torch":
            env_device = env_device or ("cuda" if torch.cuda.is_available() else "cpu")
            env_dtype = env_dtype or "float32"
            env_reset_sampling = env_reset_sampling or "host"
        eval_freq = args.eval_freq if args.eval_freq is not None else max(n_timesteps // 20, 1)
        save_freq = args.save_freq if args.save_freq is not None else max(n_timesteps // 10, 1)
        eval_episodes = args.eval_episodes
        n_eval_envs = args.n_eval_envs or max(1, min(eval_episodes, 10))
        run_dir = Path(args.log_dir) if args.log_dir else Path("runs") / f"{algo}_{env_id}_s{seed}"
        warm = warm_start.check_source(args.warm_start, algo) if args.warm_start else None
        claims.append(_claim_run_dir(run_dir, args, "--log-dir", resume=False))
        if (run_dir / "config.yaml").exists():
            st = read_state(run_dir)
            if has_saved_model(run_dir):
                raise FileExistsError(f"--log-dir {run_dir} already holds a run; use --resume {run_dir} to "
                                      "continue it or choose another --log-dir")
            print(f"note: {run_dir} holds a run that stopped before saving any model "
                  f"(status {st.get('status', 'unknown')}): starting it again")
            fresh_restart = True
    if n_timesteps < 1:
        raise ValueError(f"--n-timesteps: must be >= 1, got {n_timesteps}")

    hp = hyperparameters.resolve_hyperparams(algo, raw_hp)
    Algo = hyperparameters.get_algo(algo)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "checkpoints").mkdir(exist_ok=True)
    common.remove_stale_tmp(run_dir)
    if fresh_restart:
        clear_failed_start(run_dir)

    from stable_baselines3.common.vec_env import VecNormalize
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise
    from .callbacks import InfoLoggerCallback, ResumableEvalCallback, ScheduledCheckpoint, StopAfterWallTime, TimeSplit

    state_path = run_dir / "state.json"
    prev_state = read_state(run_dir) if (resume_dir is not None and not fresh_restart) else {}
    run_state = RunState(state_path, {
        **prev_state, "status": "starting", "pid": os.getpid(), "host": socket.gethostname(),
        "machine": common.machine(),     # the CPU of this segment: wall times depend on it
        "num_timesteps": int(prev_state.get("num_timesteps", 0)), "target_timesteps": n_timesteps})
    install_interrupt_handlers()   # a SIGTERM during start-up is recorded (status interrupted), not left "starting"
    t0 = time.time()
    env = eval_env = model = None
    try:
        run_state.update()          # inside: a SIGTERM just after "starting" is written is recorded below
        info_keys, reward_keys = envs.probe_info_keys(env_id, env_kwargs)
        segment = len(glob.glob(str(run_dir / "monitor" / "train_*.monitor.csv")))
        env, vec_used = envs.make_vec(env_id, n_envs, seed, env_kwargs, vec_mode,
                                        monitor_file=str(run_dir / "monitor" / f"train_{segment}"),
                                        info_keywords=tuple(k for k in info_keys if not k.startswith("reward_")),
                                        env_device=env_device, env_dtype=env_dtype, info_keys=info_keys,
                                        env_reset_sampling=env_reset_sampling)
        if eval_freq and eval_freq > 0:
            eval_env, _ = envs.make_vec(env_id, n_eval_envs, seed + EVAL_SEED_OFFSET, env_kwargs,
                                          "batched" if vec_mode == "torch" else vec_mode)
        norm = hp["normalize"]
        if norm is not None:
            env = VecNormalize(env, **norm)
            if eval_env is not None:
                eval_env = VecNormalize(eval_env, training=False, norm_reward=False,
                                        **{k: v for k, v in norm.items() if k not in ("norm_reward", "training")})

        # ------------------------------------------------------------ config + metadata
        config = {
            "algo": algo, "env": env_id, "env_kwargs": env_kwargs, "seed": seed, "n_timesteps": n_timesteps,
            "n_envs": n_envs, "vec_env": vec_used, "eval_freq": eval_freq, "save_freq": save_freq,
            **({"env_device": env_device, "env_dtype": env_dtype, "env_reset_sampling": env_reset_sampling}
               if vec_used == "torch" else {}),
            "eval_episodes": eval_episodes, "n_eval_envs": n_eval_envs, "eval_seed": seed + EVAL_SEED_OFFSET,
            "hyperparams_raw": to_yaml_safe(raw_hp),
            "hyperparams_resolved": to_yaml_safe({**hp["model_kwargs"], "policy": hp["policy"],
                                                         "normalize": hp["normalize"], "noise": hp["noise"]}),
            "info_keys": info_keys,
        }
        if resume_dir is None:
            config["hyperparams_source"] = source
            common.write_text(run_dir / "config.yaml", yaml.safe_dump(to_yaml_safe(config), sort_keys=False))
        else:
            old = read_yaml(run_dir / "config.yaml")
            old["n_timesteps"] = n_timesteps
            common.write_text(run_dir / "config.yaml", yaml.safe_dump(old, sort_keys=False))
        # the time, and the working directory relative to the repository (omitted outside it): no machine path
        head, where = f"# {time.strftime('%Y-%m-%d %H:%M:%S %Z')}", common.repo_cwd()
        with open(run_dir / "command.txt", "a") as f:
            f.write(f"{head}{'' if where is None else ' cwd=' + where}\n{common.command_line(argv)}\n")
        common.write_json(run_dir / "versions.json", common.package_versions())

        # ------------------------------------------------------------ model
        model_kwargs = dict(hp["model_kwargs"])
        if hp["noise"] is not None:
            kind, std = hp["noise"]
            nact = env.action_space.shape[0]
            if kind == "normal":
                model_kwargs["action_noise"] = NormalActionNoise(np.zeros(nact), std * np.ones(nact))
            elif kind == "ornstein-uhlenbeck":
                model_kwargs["action_noise"] = OrnsteinUhlenbeckActionNoise(np.zeros(nact), std * np.ones(nact))
            else:
                raise ValueError(f"noise_type: unknown {kind!r}; choose normal or ornstein-uhlenbeck")
        if resume_dir is not None and not fresh_restart:
            load_path, vn_path, rb_path = resume_files(run_dir, prev_state)
            if norm is not None:
                if not vn_path.exists():
                    raise FileNotFoundError(f"--resume: normalisation statistics {vn_path} are missing")
                env = common.load_vecnormalize_file(vn_path, env.venv)
                env.training = True
            model = common.load_model_file(Algo, load_path, env=env, device=args.device,
                                           tensorboard_log=str(run_dir / "tb"))
            if hasattr(model, "replay_buffer"):
                if rb_path.exists():
                    model.load_replay_buffer(str(rb_path))
                else:
                    print(f"warning: no replay buffer {rb_path.name} (saved on Ctrl-C or --max-wall-time, or in "
                          "checkpoints with --save-replay-buffer): continuing with an empty buffer")
            print(f"resuming {run_dir} from {load_path.name} at {model.num_timesteps} steps "
                  f"(target {n_timesteps})")
        else:
            try:
                model = Algo(hp["policy"], env, seed=seed, device=args.device, verbose=args.verbose,
                             tensorboard_log=str(run_dir / "tb"), **model_kwargs)
            except (AssertionError, TypeError, ValueError, RuntimeError) as e:   # SB3's checks: one line
                raise ValueError(f"--hyperparams: {Algo.__name__} refused them: {type(e).__name__}: "
                                 f"{' '.join(str(e).split())}") from e
            if warm is not None:
                config["warm_start"] = to_yaml_safe(warm_start.warm_start(model, env, warm, env_id,
                                                                                 env_kwargs, seed))
                common.write_text(run_dir / "config.yaml", yaml.safe_dump(to_yaml_safe(config), sort_keys=False))
                print(f"warm start from {warm['model']} ({config['warm_start']['model_num_timesteps']} steps; "
                      f"{len(config['warm_start']['new_observations'])} new observations start at zero weight)")
    except BaseException as e:  # failed before the first step: record it; the folder can be started again
        run_state.update(status="crashed" if not isinstance(e, KeyboardInterrupt) else "interrupted",
                         error=f"{type(e).__name__}: {e}", failed_before_first_step=True,
                         wall_time_s=float(prev_state.get("wall_time_s", 0.0)) + time.time() - t0)
        for v in (env, eval_env):
            if v is not None:
                v.close()
        raise

    # ---------------------------------------------------------------- callbacks
    cbs: list = [InfoLoggerCallback(reward_keys, info_keys)]
    ckpt = None
    if save_freq and save_freq > 0:
        ckpt = ScheduledCheckpoint(save_freq, str(run_dir / "checkpoints"), save_vecnormalize=norm is not None,
                                       save_replay_buffer=bool(args.save_replay_buffer and algo in hyperparameters.OFF_POLICY),
                                       run_state=run_state)
        cbs.append(ckpt)
    ecb = None
    if eval_env is not None:
        report_fn = None
        if report is not None:   # each evaluation's metrics plus the run's wall time so far (earlier segments too)
            wall0 = float(prev_state.get("wall_time_s", 0.0))

            def _report(metrics):
                report({**metrics, "wall_time_s": wall0 + time.time() - t0})
            report_fn = _report
        ecb = ResumableEvalCallback(eval_env, eval_freq, run_dir, run_state=run_state, report=report_fn,
                                    n_eval_episodes=eval_episodes, deterministic=True, verbose=args.verbose,
                                    warn=False)
        if resume_dir is not None and not fresh_restart:
            ecb.load_previous(str(run_dir / "eval" / "evaluations.npz"), prev_state.get("best_mean_reward"))
        cbs.append(ecb)
    if not args.no_progress_bar:   # a line every 10 s: readable on a terminal and in a log alike
        cbs.append(progress_callback(n_timesteps, max_wall_time=args.max_wall_time, eval_callback=ecb))
    stopper = None
    if args.max_wall_time is not None:
        stopper = StopAfterWallTime(args.max_wall_time)
        cbs.append(stopper)
    cbs.extend(extra_callbacks or [])
    timer = TimeSplit([ckpt, ecb])
    cbs.append(timer)

    install_interrupt_handlers()
    remaining = n_timesteps - model.num_timesteps
    status = "finished"
    error = None
    steps0 = model.num_timesteps
    run_state.data.pop("error", None)
    run_state.data.pop("traceback", None)
    run_state.data.pop("failed_before_first_step", None)
    run_state.start_clock(float(prev_state.get("wall_time_s", 0.0)), t0)
    run_state.update(status="running", num_timesteps=int(model.num_timesteps))
    try:
        if remaining > 0:
            model.learn(total_timesteps=remaining, callback=CallbackList(cbs), tb_log_name="run",
                        reset_num_timesteps=resume_dir is None or fresh_restart, progress_bar=False)
        else:
            print(f"nothing to do: {model.num_timesteps} steps >= n_timesteps {n_timesteps}")
    except KeyboardInterrupt:
        status = "interrupted"
        print(f"\ninterrupted at {model.num_timesteps} steps: saving model and statistics to {run_dir}",
              flush=True)
    except SystemExit as e:  # sys.exit from a callback, e.g. Ray Tune stopping a trial: saved, then re-raised
        status, error = ("stopped" if e.code in (0, None) else "crashed"), e
        if status == "crashed":
            run_state.data["error"] = f"SystemExit: {e.code}"
    except BaseException as e:  # noqa: BLE001 -- recorded, then re-raised
        import traceback
        status, error = "crashed", e
        run_state.data["error"] = f"{type(e).__name__}: {e}"
        run_state.data["traceback"] = traceback.format_exc()[-4000:]
    finally:
        with DeferInterrupts():
            if stopper is not None and stopper.hit and status == "finished":
                status = "time_limit"
            save_final(model, run_dir, status, run_state)
            elapsed = time.time() - t0
            best = prev_state.get("best_mean_reward")
            if ecb is not None and np.isfinite(ecb.best_mean_reward):
                best = float(ecb.best_mean_reward)
            split = timer.split()
            run_state.update(status=status, num_timesteps=int(model.num_timesteps), target_timesteps=n_timesteps,
                             best_mean_reward=best,
                             wall_time_s=float(prev_state.get("wall_time_s", 0.0)) + elapsed,
                             steps_per_s_last_segment=(model.num_timesteps - steps0) / max(elapsed, 1e-9),
                             time_split_last_segment_s={k: round(v, 3) for k, v in split.items()})
            scratch = run_dir / "eval" / ".evaluations_scratch.npz"
            if scratch.exists():
                scratch.unlink()
            env.close()
            if eval_env is not None:
                eval_env.close()
    print(f"{status}: {model.num_timesteps} steps in {elapsed:.1f} s -> {run_dir} (" +
          ", ".join(f"{k} {v:.1f} s" for k, v in split.items()) + ")")
    if error is not None:
        raise error
    return run_dir
