"""How often a navigation policy drives at (nearly) full speed, and how often it collides there.

    python bench/apg_saturation.py runs/tune/*/actor.pt --episodes 500

For each ``actor.pt`` (any continuous navigation policy, e.g. of recipes/apg_lidar.py):
run ``--episodes`` episodes of its own map, goals anywhere, deterministic policy, one per
env (seed ``--seed``), and report the share of steps whose speed command exceeds 95% of
the top speed (the policy's ``tanh`` output ``a`` above 0.9, where ``tanh' = 1 - a^2 < 0.19`` lets little
gradient through: ``train.action_reg`` in docs/training.md), and the collisions, all of
them and those at more than 95% of the top speed. One Markdown row per policy.
"""

from __future__ import annotations

import argparse
import sys

import torch


def measure(path: str, episodes: int, seed: int) -> dict:
    from torchnav.envs import NavEnv
    from torchnav.policy import load_policy

    sp = load_policy(path)
    cfg = sp.config()
    if not cfg.action.forward_only:
        raise SystemExit(f"{path}: a policy with reverse driving (action.forward_only false) is not measured here")
    env = NavEnv(cfg, num_envs=episodes, seed=seed)
    env.reset()
    alive = torch.ones(episodes, dtype=torch.bool)
    fast_steps, steps, collisions, fast_collisions, successes = 0, 0, 0, 0, 0
    with torch.no_grad():
        for _ in range(cfg.max_steps):
            action = sp.actor(env.observation())
            fast = action[:, 0] > 0.9  # forward_only: v = (a + 1) / 2 * v_max > 0.95 v_max
            fast_steps, steps = fast_steps + int((fast & alive).sum()), steps + int(alive.sum())
            _, out = env.advance(action)
            ended = (out["terminated"] | out["truncated"]) & alive
            hit = ended & out["collision"]
            collisions, fast_collisions = collisions + int(hit.sum()), fast_collisions + int((hit & fast).sum())
            successes += int((ended & out["success"]).sum())
            alive &= ~ended
            if not alive.any():
                break
    return {"policy": path, "episodes": episodes, "success": successes / episodes, "fast_steps": fast_steps / max(steps, 1),
            "collisions": collisions, "fast_collisions": fast_collisions}


def main(argv: list[str]) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policies", nargs="+", help="actor.pt files")
    p.add_argument("--episodes", type=int, default=500)
    p.add_argument("--seed", type=int, default=20_000, help="env seed (the final evaluation's by default)")
    a = p.parse_args(argv)
    if a.episodes < 1:
        raise SystemExit(f"--episodes must be >= 1, got {a.episodes}")
    torch.set_num_threads(1)
    rows = [measure(path, a.episodes, a.seed) for path in a.policies]
    print("| policy | episodes | success | steps above 95% of top speed | collisions | of which above 95% of top speed |")
    print("|---|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['policy']} | {r['episodes']} | {100 * r['success']:.1f}% | {100 * r['fast_steps']:.1f}% | "
              f"{r['collisions']} | {r['fast_collisions']} |")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
