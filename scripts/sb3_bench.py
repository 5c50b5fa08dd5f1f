#!/usr/bin/env python3
# Usage: .venv/bin/pip install stable-baselines3 && .venv/bin/python scripts/sb3_bench.py THREADS [UPDATES]
# (the project's venv from scripts/setup-torch.sh already holds the same torch)
# SB3 SAC gradient-update rate at the thesis settings (10 features, 3 actions, 2x256, batch 256).
import sys, time, numpy as np, torch, gymnasium as gym
from gymnasium import spaces
from stable_baselines3 import SAC
threads = int(sys.argv[1]) if len(sys.argv) > 1 else 1
torch.set_num_threads(threads)
class Dummy(gym.Env):
    observation_space = spaces.Box(-10, 10, (10,), np.float32)
    action_space = spaces.Box(-1, 1, (3,), np.float32)
    def reset(self, seed=None, options=None): return np.zeros(10, np.float32), {}
    def step(self, a): return np.random.randn(10).astype(np.float32), -1.0, False, False, {}
model = SAC("MlpPolicy", Dummy(), learning_rate=3e-4, buffer_size=20000, learning_starts=0, batch_size=256,
            tau=0.005, gamma=0.99, train_freq=1, gradient_steps=1, ent_coef="auto", target_entropy=-3,
            policy_kwargs=dict(net_arch=[256, 256]), device="cpu", verbose=0, seed=0)
model.learn(3000)  # fill the buffer
n = int(sys.argv[2]) if len(sys.argv) > 2 else 300
model.train(gradient_steps=20, batch_size=256)
# The median over blocks of 100 updates, as `ground dev bench-sac` reports.
blocks = []
for _ in range(max(1, -(-n // 100))):
    t = time.perf_counter(); model.train(gradient_steps=100, batch_size=256); blocks.append((time.perf_counter() - t) / 100)
dt = sorted(blocks)[len(blocks) // 2]
print(f"SB3 threads {threads}: {1/dt:.0f} updates/s ({1e3*dt:.2f} ms each, median of 100-update blocks)")
