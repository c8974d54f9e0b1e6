"""Start a training from a trained policy (``python -m agents.train --warm-start RUN_DIR``).

The new model takes every weight of the source run's final model (``RUN_DIR/model.zip``), its
entropy coefficient where the algorithm learns one, and its observation normalisation
(``vecnormalize.pkl``). The new env may observe more than the source env did: a policy trained
to roll on level ground (``TensegrityRoll-v0``) starts the climbing task
(``TensegrityClimb-v0``, which also observes the slope's gravity direction). The observation
blocks are matched by name (``task.observation_layout()`` of both envs); the input weights of a
block the source never observed start at zero, so the new policy acts as the source policy did
until training gives that block weight, and its normalisation statistics are measured on 64
resets of the new env. Optimiser state and replay buffer start empty. Off-policy algorithms act
at random for their first ``learning_starts`` steps and learn from those transitions first: set
it to 0 so that the buffer fills with the started policy's own actions (2000 random steps made
the icosahedron's rolling policy forget to roll within 25k steps of SAC on its own env).

Refused, with the name of what differs: another algorithm, another action space, a network of
another shape, a source block the new env does not observe, normalisation in one run and not in
the other.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from . import common, envs
from .evaluate import resolve_model

__all__ = ["check_source", "observation_map", "warm_start"]

PROBE_RESETS = 64
PROBE_SEED_OFFSET = 7919   # the probe's reset seeds: seed + this, ...: none of training's or evaluation's


def check_source(run_dir: str | Path, algo: str) -> dict:
    """The source run of ``--warm-start``: its config, final model and statistics paths. Raises
    with the flag's name when the folder is not a finished run of ``algo``."""
    run_dir = Path(run_dir)
    cfg_path = run_dir / "config.yaml"
    if not cfg_path.exists():
        raise FileNotFoundError(f"--warm-start {run_dir}: no config.yaml there (not a run directory)")
    cfg = common.read_run_config(cfg_path)
    if cfg["algo"] != algo:
        raise ValueError(f"--warm-start {run_dir}: trained with {cfg['algo']}, this training uses {algo}")
    model_path, vn_path = resolve_model(run_dir, "final")
    return {"run": str(run_dir), "model": str(model_path), "vecnormalize": None if vn_path is None else str(vn_path),
            "env": cfg["env"], "env_kwargs": dict(cfg.get("env_kwargs") or {})}


def _layout(env_id: str, env_kwargs: dict):
    env = envs.make_registered_env(env_id, **env_kwargs)
    try:
        size = int(np.prod(env.observation_space.shape))
        task = getattr(env.unwrapped, "task", None)
        lay = task.observation_layout() if task is not None and hasattr(task, "observation_layout") else None
        return size, lay
    finally:
        env.close()


def observation_map(src: tuple[int, list | None], dst: tuple[int, list | None], names=("source", "target")):
    """(n_src,) the target observation index of each source observation entry, from the two
    envs' (size, observation layout) pairs: blocks matched by name, identity where neither env
    names its blocks and the sizes agree."""
    (n_src, lay_s), (n_dst, lay_d) = src, dst
    if lay_s is None or lay_d is None:
        if n_src != n_dst:
            raise ValueError(f"--warm-start: the {names[0]} env observes {n_src} values and the {names[1]} env "
                             f"{n_dst}, and they do not name their observation blocks to match")
        return np.arange(n_src)
    dst_blocks = {name: sl for name, sl, _ in lay_d}
    out = np.full(n_src, -1)
    for name, sl, _ in lay_s:
        if name not in dst_blocks:
            raise ValueError(f"--warm-start: the source policy observes {name!r}, which the {names[1]} env does "
                             f"not observe (its blocks: {', '.join(dst_blocks)})")
        d = dst_blocks[name]
        ns, nd = sl.stop - sl.start, d.stop - d.start
        if ns != nd:
            raise ValueError(f"--warm-start: observation block {name!r} has {ns} values in the source env and {nd} "
                             "in the target env")
        out[sl] = np.arange(d.start, d.stop)
    if (out < 0).any():
        raise ValueError(f"--warm-start: the source env's observation layout leaves entries "
                         f"{np.flatnonzero(out < 0).tolist()[:8]} unnamed")
    return out


def _copy_weights(src_sd: dict, dst_sd: dict, col_map: np.ndarray, n_src: int, n_dst: int, n_act: int) -> list[str]:
    """Copy ``src_sd`` into ``dst_sd`` (torch state dicts, in place); a first layer (input
    ``n_src`` observations, or those and ``n_act`` actions, as a critic's) has its observation
    columns moved by ``col_map``, columns of new observations zero. Returns the names of the
    remapped layers."""
    import torch
    identity = n_src == n_dst and np.array_equal(col_map, np.arange(n_src))
    remapped = []
    for name, t in dst_sd.items():
        s = src_sd.get(name)
        if s is None:
            raise ValueError(f"--warm-start: the source policy has no parameter {name!r}: another network")
        first = (not identity and s.ndim == 2 and s.shape[0] == t.shape[0] and s.shape[1] in (n_src, n_src + n_act)
                 and t.shape[1] == s.shape[1] - n_src + n_dst)
        if first:
            cols = np.concatenate([col_map, n_dst + np.arange(s.shape[1] - n_src)])
            new = torch.zeros_like(t)
            new[:, torch.as_tensor(cols)] = s.to(t.dtype)
            t.copy_(new)
            remapped.append(name)
        elif s.shape == t.shape:
            t.copy_(s)
        else:
            raise ValueError(f"--warm-start: parameter {name!r} is {tuple(s.shape)} in the source policy and "
                             f"{tuple(t.shape)} here: another network (net_arch) or observation")
    return remapped


def warm_start(model, env, source: dict, env_id: str, env_kwargs: dict, seed: int) -> dict:
    """Load ``source`` (:func:`check_source`) into ``model`` (an SB3 model just built on ``env``,
    a VecNormalize when the run normalises). Returns what was done (for the run's config)."""
    import torch
    from stable_baselines3.common.vec_env import VecNormalize

    Algo = type(model)
    src_model = common.load_model_file(Algo, source["model"], device=model.device)
    if src_model.action_space.shape != model.action_space.shape:
        raise ValueError(f"--warm-start: the source policy acts on {src_model.action_space.shape} and this env "
                         f"on {model.action_space.shape}")
    src = _layout(source["env"], source["env_kwargs"])
    dst = _layout(env_id, env_kwargs)
    col_map = observation_map(src, dst)
    n_src, n_dst = src[0], dst[0]
    with torch.no_grad():
        dst_sd = model.policy.state_dict()
        remapped = _copy_weights(src_model.policy.state_dict(), dst_sd, col_map, n_src, n_dst,
                                  int(np.prod(model.action_space.shape)))
        model.policy.load_state_dict(dst_sd)
        if getattr(model, "log_ent_coef", None) is not None and getattr(src_model, "log_ent_coef", None) is not None:
            model.log_ent_coef.copy_(src_model.log_ent_coef)
    new = np.setdiff1d(np.arange(n_dst), col_map)
    out = {**{k: source[k] for k in ("run", "model", "env", "env_kwargs")},
           "model_num_timesteps": int(src_model.num_timesteps), "remapped_layers": remapped,
           "new_observations": new.tolist()}
    normed = isinstance(env, VecNormalize)
    if normed != (source["vecnormalize"] is not None):
        raise ValueError("--warm-start: " + ("this run normalises observations and the source run did not" if normed
                                             else "the source run normalised observations and this run does not"))
    if normed:
        src_vn = common.load_vecnormalize_file(source["vecnormalize"])
        mean, var = np.zeros(n_dst), np.ones(n_dst)
        mean[col_map], var[col_map] = src_vn.obs_rms.mean, src_vn.obs_rms.var
        if new.size:           # the blocks the source never saw: measured on resets of this env
            probe, _ = envs.make_vec(env_id, PROBE_RESETS, seed + PROBE_SEED_OFFSET, env_kwargs, "batched")
            try:
                obs = np.asarray(probe.reset(), dtype=float)
            finally:
                probe.close()
            mean[new], var[new] = obs[:, new].mean(axis=0), np.maximum(obs[:, new].var(axis=0), 1e-8)
        env.obs_rms.mean, env.obs_rms.var, env.obs_rms.count = mean, var, float(src_vn.obs_rms.count)
        if env.norm_reward and src_vn.norm_reward:
            env.ret_rms = src_vn.ret_rms
        out["vecnormalize"] = source["vecnormalize"]
    del src_model
    return out
