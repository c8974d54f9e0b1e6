"""skrl's PPO on a tensegrity vector env, with no adapter: ``skrl.envs.wrappers.torch.wrap_env``
recognises the env as a Gymnasium vector env by itself (auto-detection), and skrl's
``SequentialTrainer`` runs with its defaults (it renders through the env's ``call``).

    python examples/skrl_ppo.py --env-id TensegrityShape-v0 --num-envs 16 --timesteps 2000
    python examples/skrl_ppo.py --backend torch       # the torch device env (device="cpu")

``--autoreset-mode same_step`` (default) gives skrl the true last transition of each episode
(with ``next_step`` the step after an episode's end is the reset step, reward 0, which skrl would
record as a transition). Prints the mean reward per env step of the trained policy's mean action
and of uniformly random actions (reward units of the env): each on a separate vector env reset
with ``--seed``, so both start from the same states and targets, for ``--eval-steps`` steps (by
default one whole episode).

The horizon is set for the task: ``discount_factor`` 0.95. With skrl's default 0.99 the policy
ended below random actions on ``TensegrityShape-v0``: its reward is the current tracking error, a
long horizon only adds variance (the tuned SB3 entry of that env uses 0.95 too).
"""
from __future__ import annotations

import argparse

import gymnasium as gym
import torch

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.integrations.torch_threads import num_threads_arg, set_torch_threads


def make_env(env_id: str, num_envs: int, backend: str, autoreset_mode: str, seed: int, max_episode_steps=None):
    kw = {"backend": "torch", "device": "cpu", "dtype": "float32"} if backend == "torch" else {}
    if max_episode_steps is not None:
        kw["max_episode_steps"] = max_episode_steps
    return gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
                        autoreset_mode=autoreset_mode, **kw)


def evaluate(a, policy) -> float:
    """Mean reward per env step of ``policy(observations) -> actions`` (torch tensors) over
    ``a.eval_steps`` steps (default one episode) of a fresh vector env reset with ``a.seed``."""
    venv = make_env(a.env_id, a.num_envs, a.backend, a.autoreset_mode, a.seed, a.max_episode_steps)
    steps = a.eval_steps or a.max_episode_steps or venv.spec.max_episode_steps
    obs, _ = venv.reset(seed=a.seed)
    total = 0.0
    for _ in range(steps):
        act = policy(obs)
        obs, rew, _, _, _ = venv.step(act if a.backend == "torch" else act.cpu().numpy())
        total += float(rew.mean())
    venv.close()
    return total / steps


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env-id", default="TensegrityShape-v0")
    p.add_argument("--num-envs", type=int, default=16)
    p.add_argument("--timesteps", type=int, default=2000, help="vector steps (env steps = timesteps * num_envs)")
    p.add_argument("--rollouts", type=int, default=32, help="vector steps per PPO update")
    p.add_argument("--backend", choices=["numpy", "torch"], default="numpy")
    p.add_argument("--autoreset-mode", default="same_step")
    p.add_argument("--max-episode-steps", type=int, default=None, help="episode length, control steps "
                   "(default: the env's registered length)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-steps", type=int, default=None, help="vector steps of each evaluation from a reset "
                   "(default: one episode, the env's registered length or --max-episode-steps)")
    p.add_argument("--directory", default="runs/skrl", help="skrl's experiment folder (TensorBoard, checkpoints)")
    p.add_argument("--num-threads", type=num_threads_arg, default=1,
                   help="torch CPU threads (default 1, as agents.train)")
    a = p.parse_args(argv)
    set_torch_threads(a.num_threads)

    from skrl.agents.torch.ppo import PPO
    from skrl.envs.wrappers.torch import wrap_env
    from skrl.memories.torch import RandomMemory
    from skrl.resources.preprocessors.torch import RunningStandardScaler
    from skrl.trainers.torch import SequentialTrainer
    from skrl.utils import set_seed
    from skrl.utils.model_instantiators.torch import deterministic_model, gaussian_model

    set_seed(a.seed)
    env = wrap_env(make_env(a.env_id, a.num_envs, a.backend, a.autoreset_mode, a.seed, a.max_episode_steps))   # wrapper="auto"
    dev = env.device
    net = [{"name": "net", "input": "OBSERVATIONS", "layers": [64, 64], "activations": "elu"}]
    models = {
        "policy": gaussian_model(observation_space=env.observation_space, action_space=env.action_space, device=dev,
                                 clip_actions=True, initial_log_std=-0.5, network=net, output="ACTIONS"),
        "value": deterministic_model(observation_space=env.observation_space, action_space=env.action_space,
                                     device=dev, network=net, output="ONE"),
    }
    memory = RandomMemory(memory_size=a.rollouts, num_envs=env.num_envs, device=dev)
    # observations and values standardised by running statistics, as skrl's own continuous-control examples
    cfg = {"rollouts": a.rollouts, "learning_epochs": 5, "mini_batches": 4, "learning_rate": 3e-4,
           "discount_factor": 0.95,
           "observation_preprocessor": RunningStandardScaler,
           "observation_preprocessor_kwargs": {"size": env.observation_space, "device": dev},
           "value_preprocessor": RunningStandardScaler, "value_preprocessor_kwargs": {"size": 1, "device": dev},
           "experiment": {"directory": a.directory, "write_interval": 0, "checkpoint_interval": 0}}
    agent = PPO(models=models, memory=memory, observation_space=env.observation_space,
                action_space=env.action_space, device=dev, cfg=cfg)
    trainer = SequentialTrainer(env=env, agents=agent, cfg={"timesteps": a.timesteps, "disable_progressbar": True,
                                                            "close_environment_at_exit": False})
    trainer.train()
    env.close()
    agent.enable_training_mode(False)

    def trained(obs):
        with torch.no_grad():
            _, outputs = agent.act(torch.as_tensor(obs, dtype=torch.float32, device=dev), None, timestep=0,
                                   timesteps=1)
        return outputs["mean_actions"]

    def uniform(obs):
        return low + (high - low) * torch.rand((a.num_envs, *space.shape), generator=gen, device=dev)

    space = env.action_space
    low, high = (torch.as_tensor(b, dtype=torch.float32, device=dev) for b in (space.low, space.high))
    gen = torch.Generator(device=dev).manual_seed(a.seed)
    total = evaluate(a, trained)
    random_total = evaluate(a, uniform)
    out = {"env_steps": a.timesteps * a.num_envs, "mean_reward_per_step": total,
           "random_reward_per_step": random_total}
    print(f"skrl PPO on {a.env_id} ({a.backend}, cpu): {out['env_steps']} env steps; mean reward per env step "
          f"from the same {a.num_envs} resets: trained policy (mean action) {out['mean_reward_per_step']:.4f}, "
          f"uniformly random actions {out['random_reward_per_step']:.4f}")
    return out


if __name__ == "__main__":
    main()
