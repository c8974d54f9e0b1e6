"""CleanRL-style single-file PPO (``ppo_continuous_action``) on Gymnasium 1.x, for the tensegrity
envs on three backends:

* ``--backend single``: ``SyncVectorEnv`` of single ``gymnasium.make`` envs (CleanRL's own route);
* ``--backend numpy``: the batched NumPy vector env (one physics call steps all copies);
* ``--backend torch``: the torch device env (``device="cpu"`` here, ``--device cuda`` on a GPU):
  observations, rewards and actions stay tensors.

Every backend autoresets in ``same_step`` mode (the observation after an episode's end is the
next episode's first, with ``done`` set, as CleanRL's loop expects), records episode returns in
``info["episode"]`` and normalises observations and rewards (Gymnasium's vector wrappers on
NumPy arrays; :mod:`tensegrity_gym.envs.torch_wrappers` on tensors).

    python examples/cleanrl_ppo_continuous.py --env-id TensegrityShape-v0 --backend numpy \\
        --num-envs 16 --total-timesteps 100000
    python examples/cleanrl_ppo_continuous.py --backend torch

Prints the mean return of the training episodes that ended and the mean raw reward per env step
of the trained policy's mean action over ``--eval-steps`` more steps (reward units of the env).
"""
from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch
from torch import nn
from torch.distributions.normal import Normal

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.integrations.torch_threads import num_threads_arg, set_torch_threads


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env-id", default="TensegrityShape-v0")
    p.add_argument("--backend", choices=["single", "numpy", "torch"], default="numpy")
    p.add_argument("--device", default="cpu", help="torch device of the learner (and of the torch env)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--total-timesteps", type=int, default=100_000, help="env steps in all")
    p.add_argument("--num-envs", type=int, default=16)
    p.add_argument("--num-steps", type=int, default=64, help="vector steps per rollout")
    p.add_argument("--max-episode-steps", type=int, default=None, help="control steps (default: registered)")
    p.add_argument("--learning-rate", type=float, default=3e-4)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--gae-lambda", type=float, default=0.95)
    p.add_argument("--num-minibatches", type=int, default=4)
    p.add_argument("--update-epochs", type=int, default=5)
    p.add_argument("--clip-coef", type=float, default=0.2)
    p.add_argument("--ent-coef", type=float, default=0.0)
    p.add_argument("--vf-coef", type=float, default=0.5)
    p.add_argument("--max-grad-norm", type=float, default=0.5)
    p.add_argument("--eval-steps", type=int, default=200, help="vector steps of the trained policy's mean action")
    p.add_argument("--num-threads", type=num_threads_arg, default=1,
                   help="torch CPU threads (default 1, as agents.train)")
    return p.parse_args(argv)


def make_envs(a):
    """The vector env of ``a.backend`` with ``same_step`` autoreset, episode statistics and
    normalised observations / rewards (the package's normalisation wrappers take NumPy arrays
    and tensors alike, and, unlike Gymnasium's, accept ``same_step`` envs)."""
    from tensegrity_gym.envs.torch_wrappers import (TorchNormalizeObservation, TorchNormalizeReward,
                                                    TorchRecordEpisodeStatistics)
    kw = {} if a.max_episode_steps is None else {"max_episode_steps": a.max_episode_steps}
    if a.backend == "torch":
        env = gym.make_vec(a.env_id, num_envs=a.num_envs, vectorization_mode="vector_entry_point",
                           autoreset_mode="same_step", backend="torch", device=a.device, dtype="float32", **kw)
        env = TorchRecordEpisodeStatistics(env)
    else:
        if a.backend == "single":
            env = gym.vector.SyncVectorEnv([lambda: gym.make(a.env_id, **kw) for _ in range(a.num_envs)],
                                           autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
        else:
            env = gym.make_vec(a.env_id, num_envs=a.num_envs, vectorization_mode="vector_entry_point",
                               autoreset_mode="same_step", **kw)
        env = gym.wrappers.vector.RecordEpisodeStatistics(env)
    return TorchNormalizeReward(TorchNormalizeObservation(env), gamma=a.gamma)


def layer_init(layer, std=np.sqrt(2), bias_const=0.0):
    torch.nn.init.orthogonal_(layer.weight, std)
    torch.nn.init.constant_(layer.bias, bias_const)
    return layer


class Agent(nn.Module):
    """Gaussian actor (state-independent log std) and critic, two tanh layers of 64 each."""

    def __init__(self, n_obs: int, n_act: int):
        super().__init__()
        self.critic = nn.Sequential(layer_init(nn.Linear(n_obs, 64)), nn.Tanh(), layer_init(nn.Linear(64, 64)),
                                    nn.Tanh(), layer_init(nn.Linear(64, 1), std=1.0))
        self.actor_mean = nn.Sequential(layer_init(nn.Linear(n_obs, 64)), nn.Tanh(), layer_init(nn.Linear(64, 64)),
                                        nn.Tanh(), layer_init(nn.Linear(64, n_act), std=0.01))
        self.actor_logstd = nn.Parameter(torch.zeros(1, n_act))

    def get_value(self, x):
        return self.critic(x)

    def get_action_and_value(self, x, action=None):
        mean = self.actor_mean(x)
        probs = Normal(mean, self.actor_logstd.expand_as(mean).exp())
        if action is None:
            action = probs.sample()
        return action, probs.log_prob(action).sum(1), probs.entropy().sum(1), self.critic(x)


def main(argv=None) -> dict:
    a = parse_args(argv)
    set_torch_threads(a.num_threads)
    batch_size = a.num_envs * a.num_steps
    minibatch_size = batch_size // a.num_minibatches
    iterations = max(1, a.total_timesteps // batch_size)
    np.random.seed(a.seed)
    torch.manual_seed(a.seed)
    device = torch.device(a.device)
    on_torch = a.backend == "torch"

    envs = make_envs(a)
    n_obs, n_act = envs.single_observation_space.shape[0], envs.single_action_space.shape[0]
    agent = Agent(n_obs, n_act).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=a.learning_rate, eps=1e-5)

    def T(x):     # env output -> float32 tensor on the learner's device
        return (x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))).to(device, torch.float32)

    obs = torch.zeros((a.num_steps, a.num_envs, n_obs), device=device)
    actions = torch.zeros((a.num_steps, a.num_envs, n_act), device=device)
    logprobs, rewards, dones, values = (torch.zeros((a.num_steps, a.num_envs), device=device) for _ in range(4))
    raw_rewards = torch.zeros((a.num_steps, a.num_envs), device=device)

    next_obs, _ = envs.reset(seed=a.seed)
    next_obs, next_done = T(next_obs), torch.zeros(a.num_envs, device=device)
    returns, start = [], time.time()
    for it in range(1, iterations + 1):
        frac = 1.0 - (it - 1.0) / iterations                   # learning rate annealed to 0
        optimizer.param_groups[0]["lr"] = frac * a.learning_rate
        for step in range(a.num_steps):
            obs[step], dones[step] = next_obs, next_done
            with torch.no_grad():
                action, logprob, _, value = agent.get_action_and_value(next_obs)
            values[step], actions[step], logprobs[step] = value.flatten(), action, logprob
            act = torch.clamp(action, -1.0, 1.0)                 # the action box
            act = act if on_torch else act.cpu().numpy()
            next_obs, reward, term, trunc, info = envs.step(act)
            done = T(term).bool() | T(trunc).bool()
            rewards[step], next_obs, next_done = T(reward), T(next_obs), done.float()
            if "episode" in info:
                mask = np.asarray(info["_episode"].cpu() if on_torch else info["_episode"], bool)
                r = info["episode"]["r"]
                returns.extend(np.asarray(r.cpu() if on_torch else r, float)[mask].tolist())
            raw_rewards[step] = T(_raw_reward(info))
        with torch.no_grad():                                  # GAE
            next_value = agent.get_value(next_obs).reshape(1, -1)
            adv = torch.zeros_like(rewards)
            last = 0
            for t in reversed(range(a.num_steps)):
                nonterminal = 1.0 - (next_done if t == a.num_steps - 1 else dones[t + 1])
                nextv = next_value if t == a.num_steps - 1 else values[t + 1]
                delta = rewards[t] + a.gamma * nextv * nonterminal - values[t]
                adv[t] = last = delta + a.gamma * a.gae_lambda * nonterminal * last
            ret = adv + values
        b_obs, b_act = obs.reshape(-1, n_obs), actions.reshape(-1, n_act)
        b_logp, b_adv, b_ret, b_val = logprobs.reshape(-1), adv.reshape(-1), ret.reshape(-1), values.reshape(-1)
        idx = np.arange(batch_size)
        for _ in range(a.update_epochs):
            np.random.shuffle(idx)
            for s in range(0, batch_size, minibatch_size):
                mb = idx[s:s + minibatch_size]
                _, newlogp, entropy, newv = agent.get_action_and_value(b_obs[mb], b_act[mb])
                ratio = (newlogp - b_logp[mb]).exp()
                mb_adv = (b_adv[mb] - b_adv[mb].mean()) / (b_adv[mb].std() + 1e-8)
                pg = torch.max(-mb_adv * ratio, -mb_adv * torch.clamp(ratio, 1 - a.clip_coef, 1 + a.clip_coef)).mean()
                v_loss = 0.5 * ((newv.view(-1) - b_ret[mb]) ** 2).mean()
                loss = pg - a.ent_coef * entropy.mean() + a.vf_coef * v_loss
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), a.max_grad_norm)
                optimizer.step()
    seconds = time.time() - start
    # the trained policy's mean action for eval_steps more steps (normalisation statistics frozen)
    for w in (envs, envs.env):
        w.update_running_mean = False
    total = 0.0
    with torch.no_grad():
        for _ in range(a.eval_steps):
            act = torch.clamp(agent.actor_mean(next_obs), -1.0, 1.0)
            next_obs, _, _, _, info = envs.step(act if on_torch else act.cpu().numpy())
            next_obs = T(next_obs)
            total += float(T(_raw_reward(info)).mean())
    envs.close()
    out = {"env_steps": iterations * batch_size, "episodes": len(returns),
           "mean_return": float(np.mean(returns)) if returns else float("nan"),
           "mean_reward_per_step": total / a.eval_steps, "seconds": seconds}
    print(f"CleanRL PPO on {a.env_id} ({a.backend}, {a.device}): {out['env_steps']} env steps in "
          f"{seconds:.0f} s, {out['episodes']} episodes (mean return {out['mean_return']:.2f}); mean reward "
          f"per step of the trained policy (mean action, {a.eval_steps} steps) {out['mean_reward_per_step']:.4f}")
    return out


def _raw_reward(info: dict):
    """The env's reward before normalisation (N,): the sum of its ``reward_<term>`` infos; for
    envs that ended in this step (same-step autoreset) they are in ``info["final_info"]``."""
    def total(d):
        terms = [v for k, v in d.items() if k.startswith("reward_") and not isinstance(v, dict)]
        if not terms:              # every env ended: their step infos are all in final_info
            return 0.0
        out = terms[0]
        for v in terms[1:]:
            out = out + v
        return out
    r = total(info)
    if "final_info" in info and info["final_info"]:
        m = info["_final_info"]
        r = torch.where(m, total(info["final_info"]), r) if isinstance(r, torch.Tensor) else \
            np.where(m, total(info["final_info"]), r)
    return r


if __name__ == "__main__":
    main()
