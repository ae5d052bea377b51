"""Where a policy's episodes in one generated-world cell of the benchmark suite go, measured along
the shortest free path to the goal (docs/results.md, "Why the walled worlds fail").

    python docs/scripts/failure_paths.py CHECKPOINT --family corridors --difficulty 0.5 --seed 2170819

It plays the same episodes as that cell of ``recipes/benchmark.py`` (the cell's seed, episodes and
config: ``Cell.config``), with the episode's goal-distance grid kept (``reward.progress_distance:
geodesic``, which changes no episode), and reads after every step the robot's path distance to the
goal. Per outcome (success, collision, timeout) it prints how many episodes backtracked, that is
were at some step more than 0.5 / 1 / 2 m of path farther from the goal than the closest they had
been before; how close they got; and, for timeouts, how many had stalled (drove less than 1 m in
their last 100 steps) or never got 1 m closer than their start. The outcome string it prints
equals the benchmark's ``outcomes`` for the cell.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "recipes"))
import _common as C  # noqa: E402
from benchmark import Cell  # noqa: E402

from torchnav.config import merge, to_dict  # noqa: E402
from torchnav.envs.nav_env import NavEnv  # noqa: E402
from torchnav.policy import load_policy  # noqa: E402
from torchnav.tasks.config import NavConfig  # noqa: E402
from torchnav.worlds import FAMILIES  # noqa: E402

BACKTRACKS = (0.5, 1.0, 2.0)  # m of path


@torch.no_grad()
def play(checkpoint: str, family: str, difficulty: float, seed: int, episodes: int) -> tuple[str, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The cell's episodes: outcome letters, path distance to the goal ``(E, T + 1)`` (start first,
    then after each step; past an episode's end its values are not used), positions ``(E, T, 2)``
    and each episode's number of steps ``(E,)``."""
    sp = load_policy(checkpoint)
    if sp.task != "nav":
        raise SystemExit(f"{checkpoint}: a {sp.task} policy; this script plays navigation policies")
    cfg = Cell(family, "world", family, None, difficulty, seed).config(sp.config())  # the benchmark's own cell config
    cfg = NavConfig.from_dict(merge(to_dict(cfg), {"reward": {"progress_distance": "geodesic"}}))
    env = NavEnv(cfg, num_envs=episodes, device="cpu", seed=seed)
    td = env.reset()
    path, xy = [env.state.goal_path.clone()], []
    steps = torch.zeros(episodes, dtype=torch.long)
    outcome = ["?"] * episodes
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for t in range(cfg.max_steps):
            td = env.step(sp.policy(td))
            nxt = td["next"]
            path.append(env.state.goal_path.clone())
            xy.append(env.state.sim.pose[:, :2].clone())
            ended = nxt["done"].reshape(-1) & (steps == 0)
            for i in torch.nonzero(ended).flatten().tolist():
                steps[i] = t + 1
                outcome[i] = "S" if nxt["success"].reshape(-1)[i] else "C" if nxt["collision"].reshape(-1)[i] else "T"
            if (steps > 0).all():
                break
            td = nxt.exclude("reward", "done", "terminated", "truncated")
    return "".join(outcome), torch.stack(path, 1), torch.stack(xy, 1), steps


def report(outcomes: str, path: torch.Tensor, xy: torch.Tensor, steps: torch.Tensor) -> None:
    names = {"S": "successes", "C": "collisions", "T": "timeouts"}
    for letter, name in names.items():
        idx = [i for i, o in enumerate(outcomes) if o == letter]
        if not idx:
            continue
        back, start, closest, end, stalled = [], [], [], [], 0
        for i in idx:
            g = path[i, : int(steps[i]) + 1]
            back.append(float((g - torch.cummin(g, 0).values).max()))
            start.append(float(g[0]))
            closest.append(float(g.min()))
            end.append(float(g[-1]))
            last = xy[i, max(0, int(steps[i]) - 100) : int(steps[i])]
            stalled += bool(last.diff(dim=0).norm(dim=-1).sum() < 1.0)
        n = len(idx)
        mean = lambda v: sum(v) / n  # noqa: E731
        print(f"{name}: {n} episodes, path to the goal at the start {mean(start):.1f} m, closest {mean(closest):.1f} m, "
              f"at the end {mean(end):.1f} m (means)")
        print("   backtracked " + ", ".join(f"more than {b:g} m: {sum(x > b for x in back)}" for b in BACKTRACKS))
        if letter == "T":
            never = sum(s - c < 1.0 for s, c in zip(start, closest))
            print(f"   stalled (under 1 m driven in the last 100 steps): {stalled}; never 1 m closer than the start: {never}")


def main(argv: list[str]) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", help="actor.pt or checkpoint.pt of a navigation policy")
    p.add_argument("--family", default="corridors", choices=FAMILIES)
    p.add_argument("--difficulty", type=float, default=0.5)
    p.add_argument("--seed", type=int, default=2170819, help="the cell's seed (results.json of the benchmark; default corridors/medium's)")
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--threads", type=C.threads_arg, default=1)
    a = p.parse_args(argv)
    if not 0.0 <= a.difficulty <= 1.0:
        p.error(f"--difficulty must be in [0, 1], got {a.difficulty}")
    if a.episodes < 1:
        p.error("--episodes must be >= 1")
    C.ThreadGovernor(a.threads)
    outcomes, path, xy, steps = play(a.checkpoint, a.family, a.difficulty, a.seed, a.episodes)
    print(f"{Path(a.checkpoint).name} on {a.family} at difficulty {a.difficulty:g}, seed {a.seed}, {a.episodes} episodes")
    print(f"outcomes {outcomes}")
    report(outcomes, path, xy, steps)


if __name__ == "__main__":
    C.main_guard(main)
