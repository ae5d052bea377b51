"""Stable-Baselines3 PPO on torchnav's batched navigation task, through the Gymnasium interface.

    pip install -e ".[sb3]"
    python examples/sb3_ppo.py                       # arena, 3M steps, then 1,000 evaluation episodes
    python examples/sb3_ppo.py --steps 20000 --eval-episodes 100   # a quick look

Training uses the task's defaults (the bootstrapped goal curriculum) with
observations and returns normalised by ``VecNormalize``; evaluation
uses a separately seeded env with the goal radius fixed at the map's full size
(``curriculum.mode: off``), the deterministic policy, and counts successes over
the first ``--eval-episodes`` episodes to end.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

import torchnav.gym as tg


def evaluate(model: PPO, normalizer: VecNormalize, map_name: str, episodes: int, seed: int) -> float:
    envs = tg.navigation_vector_env(num_envs=min(episodes, 256), seed=seed, map=map_name, curriculum={"mode": "off"})
    obs, _ = envs.reset(seed=seed)
    outcomes: list[bool] = []
    while len(outcomes) < episodes:
        action, _ = model.predict(normalizer.normalize_obs(obs), deterministic=True)
        obs, _, terminated, truncated, info = envs.step(action)
        done = terminated | truncated
        if done.any():
            outcomes.extend(info["final_info"]["success"][done].tolist())
    return float(np.mean(outcomes[:episodes]))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--map", default="arena")
    p.add_argument("--steps", type=int, default=3_000_000)
    p.add_argument("--num-envs", type=int, default=256)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eval-episodes", type=int, default=1000)
    args = p.parse_args()
    torch.manual_seed(args.seed)
    envs = VecMonitor(tg.sb3_vec_env(tg.navigation_vector_env(num_envs=args.num_envs, seed=args.seed, map=args.map)))
    envs = VecNormalize(envs, gamma=0.99)  # running mean/std of observations and returns, as SB3 recommends for PPO
    model = PPO("MlpPolicy", envs, n_steps=64, batch_size=4096, n_epochs=4, learning_rate=1e-3, gamma=0.99,
                policy_kwargs={"net_arch": [64, 64]}, seed=args.seed, device="cpu", verbose=1)
    t0 = time.perf_counter()
    model.learn(total_timesteps=args.steps)
    train_s = time.perf_counter() - t0
    envs.training = False  # freeze the observation statistics for evaluation
    rate = evaluate(model, envs, args.map, args.eval_episodes, seed=10_000 + args.seed)
    print(f"trained {model.num_timesteps:,} steps in {train_s:.0f} s ({model.num_timesteps / train_s:,.0f} steps/s); "
          f"success on {args.map}: {rate:.1%} over {args.eval_episodes} episodes")


if __name__ == "__main__":
    main()
