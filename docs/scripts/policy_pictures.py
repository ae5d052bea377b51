"""Pictures of the shipped arena policy for the docs.

    python docs/scripts/policy_pictures.py

Writes docs/img/arena_batch.png (8 envs of a batch after a reset: map, robots,
lidar rays, goals) and docs/img/arena_trajectories.png (one episode of each of 4
envs driven by checkpoints/td3_arena_actor.pt).
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "recipes"))
from evaluate import DEFAULT_CHECKPOINT, load_actor  # noqa: E402

from torchnav.envs import NavEnv  # noqa: E402
from torchnav.evaluation import eval_config  # noqa: E402
from torchnav.record import record_rollout  # noqa: E402
from torchnav.render import plot_env, plot_trajectories  # noqa: E402


def main() -> None:
    out = ROOT / "docs" / "img"
    out.mkdir(parents=True, exist_ok=True)
    actor, nav = load_actor(DEFAULT_CHECKPOINT)
    env = NavEnv(eval_config(nav), num_envs=8, seed=3)
    td0 = env.reset()
    fig = plot_env(env, envs=range(8), ncols=4)
    fig.savefig(out / "arena_batch.png", dpi=80)
    plt.close(fig)
    world = env.state.world.clone()  # the first episode's obstacles (boxes move at every reset)
    with torch.no_grad():
        td = record_rollout(env, actor, max_steps=200, tensordict=td0)
    fig, axes = plt.subplots(1, 4, figsize=(13, 3.6))
    for i, ax in enumerate(axes):
        done = td["next", "done"][i].reshape(-1)
        t = int(done.nonzero()[0]) + 1 if done.any() else done.numel()  # first episode only
        plot_trajectories(td["next", "pose"][i : i + 1, :t], world=world, env_world=i, goal=td["goal"][i : i + 1, :t], ax=ax)
        outcome = "success" if td["next", "success"][i, t - 1].item() else ("collision" if td["next", "collision"][i, t - 1].item() else "timeout")
        ax.set_title(f"env {i}: {outcome} in {t} steps", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "arena_trajectories.png", dpi=80)
    plt.close(fig)
    print(f"wrote {out / 'arena_batch.png'} and {out / 'arena_trajectories.png'}")


if __name__ == "__main__":
    main()
