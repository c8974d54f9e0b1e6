"""Cold compile: gym.make + reset + first step of one env id in a process with an empty numba cache."""
import sys, time
t0 = time.perf_counter()
import gymnasium as gym
import tensegrity_gym  # noqa: F401
env = gym.make(sys.argv[1])
env.reset(seed=0)
t1 = time.perf_counter()
env.step(env.action_space.sample())
t2 = time.perf_counter()
print(f"{sys.argv[1]} import+make+reset {t1 - t0:.1f} s first step {t2 - t1:.1f} s total {t2 - t0:.1f} s")
