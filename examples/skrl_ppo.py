"""skrl's PPO on a tensegrity vector env, with no adapter: ``skrl.envs.wrappers.torch.wrap_env``
recognises the env as a Gymnasium vector env by itself (auto-detection), and skrl's
``SequentialTrainer`` runs with its defaults (it renders through the env's ``call``).

    python examples/skrl_ppo.py --env-id TensegrityShape-v0 --num-envs 16 --timesteps 2000
    python examples/skrl_ppo.py --backend torch       # the torch device env (device="cpu")

``--autoreset-mode same_step`` (default) gives skrl the true last transition of each episode
(with ``next_step`` the step after an episode's end is the reset step, reward 0, which skrl would
record as a transition). Prints the mean reward per env step of the trained policy's mean action
over ``--eval-steps`` more steps (reward units of the env).
"""
from __future__ import annotations

import argparse

import gymnasium as gym
import torch

import tensegrity_gym  # noqa: F401  (registers the envs)


def make_env(env_id: str, num_envs: int, backend: str, autoreset_mode: str, seed: int, max_episode_steps=None):
    kw = {"backend": "torch", "device": "cpu", "dtype": "float32"} if backend == "torch" else {}
    if max_episode_steps is not None:
        kw["max_episode_steps"] = max_episode_steps
    return gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point",
                        autoreset_mode=autoreset_mode, **kw)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env-id", default="TensegrityShape-v0")
    p.add_argument("--num-envs", type=int, default=16)
    p.add_argument("--timesteps", type=int, default=2000, help="vector steps (env steps = timesteps * num_envs)")
    p.add_argument("--rollouts", type=int, default=32, help="vector steps per PPO update")
    p.add_argument("--backend", choices=["numpy", "torch"], default="numpy")
    p.add_argument("--autoreset-mode", default="same_step")
    p.add_argument("--max-episode-steps", type=int, default=None, help="episode length, control steps "
                   "(default: the registered 1000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-steps", type=int, default=200, help="vector steps of the trained policy's mean action")
    p.add_argument("--directory", default="runs/skrl", help="skrl's experiment folder (TensorBoard, checkpoints)")
    a = p.parse_args(argv)

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
           "observation_preprocessor": RunningStandardScaler,
           "observation_preprocessor_kwargs": {"size": env.observation_space, "device": dev},
           "value_preprocessor": RunningStandardScaler, "value_preprocessor_kwargs": {"size": 1, "device": dev},
           "experiment": {"directory": a.directory, "write_interval": 0, "checkpoint_interval": 0}}
    agent = PPO(models=models, memory=memory, observation_space=env.observation_space,
                action_space=env.action_space, device=dev, cfg=cfg)
    trainer = SequentialTrainer(env=env, agents=agent, cfg={"timesteps": a.timesteps, "disable_progressbar": True,
                                                            "close_environment_at_exit": False})
    trainer.train()
    # the trained policy's mean action for eval_steps more steps of every env
    agent.enable_training_mode(False)
    obs, _ = env.reset()
    total = 0.0
    with torch.no_grad():
        for t in range(a.eval_steps):
            _, outputs = agent.act(obs, None, timestep=t, timesteps=a.eval_steps)
            obs, rew, _, _, _ = env.step(outputs["mean_actions"])
            total += float(rew.mean())
    out = {"env_steps": a.timesteps * a.num_envs, "mean_reward_per_step": total / a.eval_steps}
    print(f"skrl PPO on {a.env_id} ({a.backend}, cpu): {out['env_steps']} env steps, mean reward per step "
          f"of the trained policy (mean action, {a.eval_steps} steps) {out['mean_reward_per_step']:.4f}")
    env.close()
    return out


if __name__ == "__main__":
    main()
