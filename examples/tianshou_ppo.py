"""tianshou's PPO on a tensegrity vector env through the package's small adapter
(:mod:`tensegrity_gym.integrations.tianshou`: the batched env as a ``tianshou.env.BaseVectorEnv``,
autoreset disabled so that tianshou's ``Collector`` resets ended envs itself).

    python examples/tianshou_ppo.py --env-id TensegrityShape-v0 --num-envs 16 --steps 32768
    python examples/tianshou_ppo.py --backend torch       # the torch device env (device="cpu")

tianshou's standard route works too: ``DummyVectorEnv([lambda: gymnasium.make(id) for _ in
range(n)])`` steps n single envs one by one. Prints the mean reward per env step of the trained
policy's mean action over ``--eval-steps`` more steps (the env's reward units).
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.integrations.torch_threads import num_threads_arg, set_torch_threads


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env-id", default="TensegrityShape-v0")
    p.add_argument("--num-envs", type=int, default=16)
    p.add_argument("--steps", type=int, default=32768, help="env steps in all")
    p.add_argument("--steps-per-collect", type=int, default=1024, help="env steps per PPO update")
    p.add_argument("--backend", choices=["numpy", "torch"], default="numpy")
    p.add_argument("--max-episode-steps", type=int, default=None, help="episode length, control steps "
                   "(default: the registered 1000)")
    p.add_argument("--eval-steps", type=int, default=200, help="vector steps of the trained policy's mean action")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--num-threads", type=num_threads_arg, default=1,
                   help="torch CPU threads (default 1, as agents.train)")
    a = p.parse_args(argv)
    set_torch_threads(a.num_threads)

    from torch import nn
    from torch.distributions import Independent, Normal
    from tianshou.algorithm import PPO
    from tianshou.algorithm.modelfree.reinforce import ProbabilisticActorPolicy
    from tianshou.algorithm.optim import AdamOptimizerFactory
    from tianshou.data import Collector, CollectStats, VectorReplayBuffer
    from tianshou.trainer import OnPolicyTrainerParams
    from tianshou.utils.net.common import Net
    from tianshou.utils.net.continuous import ContinuousActorProbabilistic, ContinuousCritic
    from tensegrity_gym.integrations.tianshou import make_tianshou_env

    np.random.seed(a.seed)
    torch.manual_seed(a.seed)
    kw = {"device": "cpu", "dtype": "float32"} if a.backend == "torch" else {}
    if a.max_episode_steps is not None:
        kw["max_episode_steps"] = a.max_episode_steps
    envs = make_tianshou_env(a.env_id, a.num_envs, a.backend, **kw)
    envs.seed(a.seed)
    obs_space, act_space = envs.observation_space[0], envs.action_space[0]
    actor = ContinuousActorProbabilistic(
        preprocess_net=Net(state_shape=obs_space.shape, hidden_sizes=[64, 64], activation=nn.Tanh),
        action_shape=act_space.shape, unbounded=True)
    critic = ContinuousCritic(preprocess_net=Net(state_shape=obs_space.shape, hidden_sizes=[64, 64],
                                                 activation=nn.Tanh))

    def dist(loc_scale):
        loc, scale = loc_scale
        return Independent(Normal(loc, scale), 1)

    policy = ProbabilisticActorPolicy(actor=actor, dist_fn=dist, action_space=act_space, deterministic_eval=True,
                                      action_scaling=True, action_bound_method="clip")
    algorithm = PPO(policy=policy, critic=critic, optim=AdamOptimizerFactory(lr=3e-4), gamma=0.99,
                    gae_lambda=0.95, max_grad_norm=0.5, vf_coef=0.25, ent_coef=0.0)
    collector = Collector[CollectStats](algorithm, envs, VectorReplayBuffer(a.steps_per_collect, len(envs)))
    collector.reset()
    result = algorithm.run_training(OnPolicyTrainerParams(
        training_collector=collector, max_epochs=1, epoch_num_steps=a.steps,
        collection_step_num_env_steps=a.steps_per_collect, update_step_num_repetitions=5, batch_size=256,
        test_in_training=False, verbose=False, show_progress=False))
    steps = collector.collect_step
    # the trained policy's mean action (deterministic_eval outside training) for eval_steps more steps
    collector.reset_buffer()
    collector.collect(n_step=a.eval_steps * a.num_envs)
    rew = collector.buffer.rew[: len(collector.buffer)]
    out = {"env_steps": int(steps), "mean_reward_per_step": float(np.mean(rew)), "result": result}
    print(f"tianshou PPO on {a.env_id} ({a.backend}, cpu): {out['env_steps']} env steps, mean reward per step "
          f"of the trained policy (mean action, {a.eval_steps} steps) {out['mean_reward_per_step']:.4f}")
    envs.close()
    return out


if __name__ == "__main__":
    main()
