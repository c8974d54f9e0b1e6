"""TorchRL's PPO on a tensegrity vector env, with no adapter: ``torchrl.envs.GymWrapper`` wraps
the vector env directly (it reads ``autoreset_mode``; ``"disabled"`` is TorchRL's preferred
mode: TorchRL resets ended envs through ``reset(options={"reset_mask": ...})``), and
``torchrl.envs.utils.check_env_specs`` passes.

    python examples/torchrl_ppo.py --env-id TensegrityShape-v0 --num-envs 16 --frames 32768
    python examples/torchrl_ppo.py --backend torch       # the torch device env (device="cpu")

Clipped PPO with GAE, a tanh-Gaussian actor and an MLP critic, as TorchRL's PPO tutorial. Prints
the mean reward per env step of the trained policy's mean action over ``--eval-steps`` more steps
(the env's reward units).
"""
from __future__ import annotations

import argparse

import gymnasium as gym
import torch

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.integrations.torch_threads import num_threads_arg, set_torch_threads


def make_env(env_id: str, num_envs: int, backend: str, autoreset_mode: str = "disabled", max_episode_steps=None):
    """The vector env in TorchRL's ``GymWrapper`` with observations and rewards as float32."""
    from torchrl.envs import DoubleToFloat, GymWrapper, TransformedEnv
    kw = {"backend": "torch", "device": "cpu", "dtype": "float32"} if backend == "torch" else {}
    if max_episode_steps is not None:
        kw["max_episode_steps"] = max_episode_steps
    venv = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
                        autoreset_mode=autoreset_mode, **kw)
    env = GymWrapper(venv, device="cpu")
    return TransformedEnv(env, DoubleToFloat())


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env-id", default="TensegrityShape-v0")
    p.add_argument("--num-envs", type=int, default=16)
    p.add_argument("--frames", type=int, default=32768, help="env steps in all")
    p.add_argument("--frames-per-batch", type=int, default=1024, help="env steps per PPO update")
    p.add_argument("--backend", choices=["numpy", "torch"], default="numpy")
    p.add_argument("--autoreset-mode", default="disabled", choices=["disabled", "same_step"])
    p.add_argument("--max-episode-steps", type=int, default=None, help="episode length, control steps "
                   "(default: the registered 1000)")
    p.add_argument("--eval-steps", type=int, default=200, help="vector steps of the trained policy's mean action")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--num-threads", type=num_threads_arg, default=1,
                   help="torch CPU threads (default 1, as agents.train)")
    a = p.parse_args(argv)
    set_torch_threads(a.num_threads)

    from tensordict.nn import NormalParamExtractor, TensorDictModule
    from torch import nn
    from torchrl.collectors import Collector
    from torchrl.data import LazyTensorStorage, ReplayBuffer, SamplerWithoutReplacement
    from torchrl.envs.utils import check_env_specs
    from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
    from torchrl.objectives import ClipPPOLoss
    from torchrl.objectives.value import GAE

    torch.manual_seed(a.seed)
    env = make_env(a.env_id, a.num_envs, a.backend, a.autoreset_mode, a.max_episode_steps)
    env.set_seed(a.seed)
    check_env_specs(env)
    n_obs = env.observation_spec["observation"].shape[-1]
    spec = env.action_spec_unbatched if hasattr(env, "action_spec_unbatched") else env.action_spec
    n_act = spec.shape[-1]
    actor_net = nn.Sequential(nn.Linear(n_obs, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(),
                              nn.Linear(64, 2 * n_act), NormalParamExtractor())
    actor = ProbabilisticActor(TensorDictModule(actor_net, in_keys=["observation"], out_keys=["loc", "scale"]),
                               spec=spec, in_keys=["loc", "scale"], distribution_class=TanhNormal,
                               distribution_kwargs={"low": spec.space.low, "high": spec.space.high},
                               return_log_prob=True)
    critic = ValueOperator(nn.Sequential(nn.Linear(n_obs, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(),
                                         nn.Linear(64, 1)), in_keys=["observation"])
    collector = Collector(env, actor, frames_per_batch=a.frames_per_batch, total_frames=a.frames)
    gae = GAE(gamma=0.99, lmbda=0.95, value_network=critic, average_gae=True)
    loss = ClipPPOLoss(actor, critic, clip_epsilon=0.2, entropy_coeff=0.0, critic_coeff=1.0)
    optim = torch.optim.Adam(loss.parameters(), lr=3e-4)
    buffer = ReplayBuffer(storage=LazyTensorStorage(a.frames_per_batch), sampler=SamplerWithoutReplacement())
    last = float("nan")
    for data in collector:
        for _ in range(5):                                          # PPO epochs
            with torch.no_grad():
                gae(data)
            buffer.extend(data.reshape(-1))
            for _ in range(4):                                      # minibatches
                batch = buffer.sample(a.frames_per_batch // 4)
                out = loss(batch)
                total = out["loss_objective"] + out["loss_critic"] + out.get("loss_entropy", 0.0)
                optim.zero_grad()
                total.backward()
                nn.utils.clip_grad_norm_(loss.parameters(), 0.5)
                optim.step()
        last = float(data["next", "reward"].mean())
    collector.shutdown()
    from torchrl.envs.utils import ExplorationType, set_exploration_type
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():   # the mean action
        td = env.rollout(a.eval_steps, actor, break_when_any_done=False)
    out = {"env_steps": a.frames, "mean_reward_per_step": float(td["next", "reward"].mean()),
           "last_batch_reward_per_step": last}
    print(f"TorchRL PPO on {a.env_id} ({a.backend}, cpu): {a.frames} env steps, mean reward per step of the "
          f"trained policy (mean action, {a.eval_steps} steps) {out['mean_reward_per_step']:.4f}")
    env.close()
    return out


if __name__ == "__main__":
    main()
