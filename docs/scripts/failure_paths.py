"""Where a policy's episodes in one cell of the benchmark suite go, measured along the shortest free
path to the goal (docs/results.md, "Why the walled worlds fail" and "Why warehouse fails").

    python docs/scripts/failure_paths.py CHECKPOINT --family corridors --difficulty 0.5 --seed 2170819
    python docs/scripts/failure_paths.py CHECKPOINT --map warehouse --picture runs/warehouse_timeouts.png
    python docs/scripts/failure_paths.py CHECKPOINT --map warehouse --probe

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

``--probe`` (``warehouse`` only) plays the gap probe of docs/results.md ("Why: a 0.65 m gap read as a
wall") instead of the cell's episodes: 168 episodes of the cell's config whose starts and goals are
given (``gap_probe``), the robot in the aisle under the rack row with the pillars (y = 0.9 m), under
each of the row's six 0.65 m gaps and two 0.9 m end gaps, at 0, +-0.5, +-1 and +-2 m along the aisle,
facing along it (0), up at the row (pi/2) or back (pi), the goal straight across the row in the next
aisle (y = 3.7 m). It prints how many reached their goal and one line per gap.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "recipes"))
import builders as B  # noqa: E402
from benchmark import DEFAULT_LEVELS, MAP_INDEX, SEED_BASE, Cell, parse_levels, suite  # noqa: E402

from torchnav.config import merge, to_dict  # noqa: E402
from torchnav.envs.nav_env import NavEnv  # noqa: E402
from torchnav.evaluation import outcome_letter  # noqa: E402
from torchnav.policy import load_policy  # noqa: E402
from torchnav.sim import World  # noqa: E402
from torchnav.tasks.config import NavConfig  # noqa: E402
from torchnav.worlds import FAMILIES  # noqa: E402

BACKTRACKS = (0.5, 1.0, 2.0)  # m of path

# The warehouse gap probe (module docstring): x (m) of the gaps in the rack row above the aisle at y = 0.9 m.
PROBE_GAPS = (-5.575, -4.425, -0.575, 0.575, 4.425, 5.575)  # the 0.65 m gaps beside the row's three pillars
PROBE_END_GAPS = (-9.55, 9.55)  # the 0.9 m gaps at the row's ends
PROBE_OFFSETS = (0.0, 0.5, 1.0, 2.0, -0.5, -1.0, -2.0)  # m along the aisle from the gap
PROBE_HEADINGS = (0.0, math.pi / 2, math.pi)  # rad
PROBE_START_Y, PROBE_GOAL_Y, PROBE_X_LIMIT = 0.9, 3.7, 9.7  # m; starts past +-9.7 m are moved in to it


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


def gap_probe() -> tuple[torch.Tensor, torch.Tensor, list[tuple[float, float, float]]]:
    """The probe's starts ``(168, 3)`` ``[x, y, heading]``, goals ``(168, 2)`` and, per episode, its
    ``(gap x, offset, heading)`` (module docstring)."""
    rows = [(g, o, h) for g in PROBE_GAPS + PROBE_END_GAPS for o in PROBE_OFFSETS for h in PROBE_HEADINGS]
    starts = torch.tensor([[max(-PROBE_X_LIMIT, min(PROBE_X_LIMIT, g + o)), PROBE_START_Y, h] for g, o, h in rows])
    goals = torch.tensor([[g, PROBE_GOAL_Y] for g, _, _ in rows])
    return starts, goals, rows


@torch.no_grad()
def play(checkpoint: str, cell: Cell, episodes: int, given: tuple[torch.Tensor, torch.Tensor] | None = None) -> Episodes:
    """``episodes`` episodes of ``cell`` (a generated-world cell: path distances from the goal grid;
    a map: straight-line distances). ``given`` ``(starts (E, 3), goals (E, 2))`` fixes each episode's
    start and goal (a map cell only; ``NavEnv.reset_to``)."""
    sp = load_policy(checkpoint)
    if sp.task != "nav":
        raise SystemExit(f"{checkpoint}: a {sp.task} policy; this script plays navigation policies")
    cfg = cell.config(sp.config())  # the benchmark's own cell config
    geodesic = cell.kind == "world"
    if geodesic:
        cfg = NavConfig.from_dict(merge(to_dict(cfg), {"reward": {"progress_distance": "geodesic"}}))
    if given is not None and cell.kind != "map":
        raise ValueError("play: given starts and goals need a map cell")
    env = NavEnv(cfg, num_envs=episodes, device="cpu", seed=cell.seed)
    td = env.reset() if given is None else env.reset_to(*given)  # reset_to checks the shapes
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
                outcome[i] = outcome_letter(bool(nxt["success"].reshape(-1)[i]), bool(nxt["collision"].reshape(-1)[i]))
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
    p.add_argument("--episodes", type=int, default=None, help="episodes of the cell (default 200; --probe plays its own 168)")
    p.add_argument("--picture", type=Path, default=None, help="PNG of the first six episodes ending as --draw")
    p.add_argument("--draw", default="timeout", choices=("collision", "timeout"), help="which failures --picture draws")
    p.add_argument("--threads", type=B.threads_arg, default=1)
    p.add_argument("--probe", action="store_true", help="play the warehouse gap probe (module docstring) instead of the cell's episodes")
    a = p.parse_args(argv)
    if a.probe and a.map != "warehouse":
        p.error("--probe is the warehouse gap probe: give --map warehouse")
    if a.probe and a.episodes is not None:
        p.error("--probe plays its own 168 episodes: drop --episodes")
    a.episodes = 200 if a.episodes is None else a.episodes
    if not 0.0 <= a.difficulty <= 1.0:
        p.error(f"--difficulty must be in [0, 1], got {a.difficulty}")
    if a.episodes < 1:
        p.error("--episodes must be >= 1")
    B.ThreadGovernor(a.threads)
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
    if a.probe:
        starts, goals, rows = gap_probe()
        ep = play(a.checkpoint, cell, len(rows), given=(starts, goals))
        where = "the warehouse gap probe"
        print(f"{Path(a.checkpoint).name}, warehouse gap probe, seed {cell.seed}: {ep.outcomes.count('S')} of {len(rows)} reached their goal")
        print("per gap, per offset along the aisle: outcomes facing along it, up at the row, back (S, C, T)")
        for g in PROBE_GAPS + PROBE_END_GAPS:
            cols = ["".join(o for o, r in zip(ep.outcomes, rows) if r[0] == g and r[1] == off) for off in PROBE_OFFSETS]
            print(f"  gap x = {g:+7.3f} m  " + "  ".join(f"{off:+.1f}: {c}" for off, c in zip(PROBE_OFFSETS, cols)))
    else:
        ep = play(a.checkpoint, cell, a.episodes)
        print(f"{Path(a.checkpoint).name} on {where}, seed {cell.seed}, {a.episodes} episodes "
              f"({'path' if cell.kind == 'world' else 'straight-line'} distances to the goal)")
        print(f"outcomes {ep.outcomes}")
        report(ep, "path" if cell.kind == "world" else "straight line")
    if a.picture is not None:
        n = picture(ep, a.draw[0].upper(), f"{Path(a.checkpoint).name} on {where}: {a.draw}s (last 100 steps red)", a.picture)
        print(f"wrote {a.picture} ({n} episodes)")


if __name__ == "__main__":
    B.main_guard(main)
