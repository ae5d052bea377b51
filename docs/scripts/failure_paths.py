"""Where a policy's episodes in one cell of the benchmark suite go, measured along the shortest free
path to the goal (docs/results.md, "Why the walled worlds fail" and "Why warehouse fails").

    python docs/scripts/failure_paths.py CHECKPOINT --family corridors --difficulty 0.5 --seed 2170819
    python docs/scripts/failure_paths.py CHECKPOINT --map warehouse --picture runs/warehouse_timeouts.png

It plays the same episodes as that cell of ``recipes/benchmark.py`` (the cell's seed, episodes and
config: ``Cell.config``; the suite's seed of the cell unless ``--seed`` is given).
In a generated-world cell it keeps the episode's goal-distance grid (``reward.progress_distance:
geodesic``, which changes no episode) and reads after every step the robot's path distance to the
goal; a shipped map has no such grid, so there the distance is the straight line. Per outcome
(success, collision, timeout) it prints how many episodes backtracked, that is were at some step
more than 0.5 / 1 / 2 m farther from the goal than the closest they had been before; how close they
got; and, for timeouts, how many had stalled (drove less than 1 m in their last 100 steps) or never
got 1 m closer than their start. The outcome string it prints equals the benchmark's ``outcomes``
for the cell. ``--picture`` draws the first six failed episodes of the given outcome (``--draw``,
timeouts by default), their last 100 steps in red.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "recipes"))
import _common as C  # noqa: E402
from benchmark import DEFAULT_LEVELS, MAP_INDEX, SEED_BASE, Cell, parse_levels, suite  # noqa: E402

from torchnav.config import merge, to_dict  # noqa: E402
from torchnav.envs.nav_env import NavEnv  # noqa: E402
from torchnav.policy import load_policy  # noqa: E402
from torchnav.sim import World  # noqa: E402
from torchnav.tasks.config import NavConfig  # noqa: E402
from torchnav.worlds import FAMILIES  # noqa: E402

BACKTRACKS = (0.5, 1.0, 2.0)  # m of path


@dataclass
class Episodes:
    """A cell's episodes as played: outcome letters, distance to the goal ``(E, T + 1)`` (start
    first, then after each step; past an episode's end its values are not used), positions
    ``(E, T, 2)``, each episode's number of steps ``(E,)``, goals ``(E, 2)`` and worlds."""

    outcomes: str
    path: torch.Tensor
    xy: torch.Tensor
    steps: torch.Tensor
    goal: torch.Tensor
    world: World


@torch.no_grad()
def play(checkpoint: str, cell: Cell, episodes: int) -> Episodes:
    """``episodes`` episodes of ``cell`` (a generated-world cell: path distances from the goal grid;
    a map: straight-line distances)."""
    sp = load_policy(checkpoint)
    if sp.task != "nav":
        raise SystemExit(f"{checkpoint}: a {sp.task} policy; this script plays navigation policies")
    cfg = cell.config(sp.config())  # the benchmark's own cell config
    geodesic = cell.kind == "world"
    if geodesic:
        cfg = NavConfig.from_dict(merge(to_dict(cfg), {"reward": {"progress_distance": "geodesic"}}))
    env = NavEnv(cfg, num_envs=episodes, device="cpu", seed=cell.seed)
    td = env.reset()
    goal = env.state.goal.clone()
    distance = (lambda: env.state.goal_path.clone()) if geodesic else (lambda: (env.state.sim.pose[:, :2] - goal).norm(dim=-1))
    path, xy = [distance()], []
    steps = torch.zeros(episodes, dtype=torch.long)
    outcome = ["?"] * episodes
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for t in range(cfg.max_steps):
            td = env.step(sp.policy(td))
            nxt = td["next"]
            path.append(distance())
            xy.append(env.state.sim.pose[:, :2].clone())
            ended = nxt["done"].reshape(-1) & (steps == 0)
            for i in torch.nonzero(ended).flatten().tolist():
                steps[i] = t + 1
                outcome[i] = "S" if nxt["success"].reshape(-1)[i] else "C" if nxt["collision"].reshape(-1)[i] else "T"
            if (steps > 0).all():
                break
            td = nxt.exclude("reward", "done", "terminated", "truncated")
    return Episodes("".join(outcome), torch.stack(path, 1), torch.stack(xy, 1), steps, goal, env.state.world)


def picture(ep: Episodes, letter: str, title: str, out: Path) -> int:
    """Draw up to six episodes ending in ``letter`` to ``out``; returns how many were drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from torchnav.render import draw_goal, draw_world

    idx = [i for i, o in enumerate(ep.outcomes) if o == letter][:6]
    if not idx:
        return 0
    fig, axs = plt.subplots(2, 3, figsize=(12, 8), squeeze=False)
    for ax in axs.flat:
        ax.set_axis_off()
    for ax, i in zip(axs.flat, idx):
        ax.set_axis_on()
        draw_world(ax, ep.world, env=i)
        xy = ep.xy[i, : int(ep.steps[i])].numpy()
        ax.plot(xy[:, 0], xy[:, 1], "-", lw=0.8, color="tab:blue")
        ax.plot(xy[-100:, 0], xy[-100:, 1], "-", lw=1.3, color="tab:red")
        ax.plot(*xy[0], "o", color="tab:green", ms=7)
        draw_goal(ax, ep.goal, env=i)
        ax.set_aspect("equal")
        ax.set_title(f"episode {i}", fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80)
    plt.close(fig)
    return len(idx)


def report(ep: Episodes, distance: str = "path") -> None:
    """Per outcome: backtracks, closest approach and, for timeouts, stalls; ``distance`` names what
    ``ep.path`` measures ("path" or "straight line")."""
    outcomes, path, xy, steps = ep.outcomes, ep.path, ep.xy, ep.steps
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
        print(f"{name}: {n} episodes, {distance} to the goal at the start {mean(start):.1f} m, closest {mean(closest):.1f} m, "
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
    p.add_argument("--map", default=None, choices=sorted(MAP_INDEX), help="a shipped map's cell instead of a family's")
    p.add_argument("--seed", type=int, default=None,
                   help="the cell's env seed (default: the benchmark suite's seed of the cell)")
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--picture", type=Path, default=None, help="PNG of the first six episodes ending as --draw")
    p.add_argument("--draw", default="timeout", choices=("collision", "timeout"), help="which failures --picture draws")
    p.add_argument("--threads", type=C.threads_arg, default=1)
    a = p.parse_args(argv)
    if not 0.0 <= a.difficulty <= 1.0:
        p.error(f"--difficulty must be in [0, 1], got {a.difficulty}")
    if a.episodes < 1:
        p.error("--episodes must be >= 1")
    C.ThreadGovernor(a.threads)
    if a.map is not None:
        (cell,) = suite([a.map], [], {}, SEED_BASE)
        where = f"map {a.map}"
    else:
        cells = [c for c in suite([], [a.family], parse_levels(list(DEFAULT_LEVELS)), SEED_BASE) if c.difficulty == a.difficulty]
        if not cells and a.seed is None:
            p.error(f"--difficulty {a.difficulty:g} is no level of the suite ({' '.join(DEFAULT_LEVELS)}): give --seed")
        cell = cells[0] if cells else Cell(a.family, "world", a.family, None, a.difficulty, a.seed)
        where = f"{a.family} at difficulty {a.difficulty:g}"
    if a.seed is not None:
        cell = replace(cell, seed=a.seed)
    ep = play(a.checkpoint, cell, a.episodes)
    print(f"{Path(a.checkpoint).name} on {where}, seed {cell.seed}, {a.episodes} episodes "
          f"({'path' if cell.kind == 'world' else 'straight-line'} distances to the goal)")
    print(f"outcomes {ep.outcomes}")
    report(ep, "path" if cell.kind == "world" else "straight line")
    if a.picture is not None:
        n = picture(ep, a.draw[0].upper(), f"{Path(a.checkpoint).name} on {where}: {a.draw}s (last 100 steps red)", a.picture)
        print(f"wrote {a.picture} ({n} episodes)")


if __name__ == "__main__":
    C.main_guard(main)
