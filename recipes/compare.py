"""Compare the classical controllers and any saved policies on the same seeded scenarios.

    python recipes/compare.py                                            # every controller, arena/warehouse/maze, 1000 episodes each
    python recipes/compare.py checkpoints/td3_arena_actor.pt --out runs/compare
    python recipes/compare.py CKPT_A CKPT_B --maps arena --episodes 200 --controllers astar reactive

Every method runs the same episodes: one env per episode, built from the same config
and seed, so starts, goals and random boxes are identical (checked before running;
a checkpoint trained with a different robot or reset setting is refused). Goals are
drawn anywhere on the map (curriculum off). The controllers use the task settings of
the first checkpoint given (its max_steps, goal tolerance, robot and lidar), or the
defaults of ``NavConfig`` without one.

Writes to ``--out``: ``results.json`` (every summary, config, planner statistics),
``results.md`` (one table: method x map, rates with 95% Wilson intervals, mean steps to
goal and path-length ratio over successful episodes with 95% intervals) and
``trajectories.png`` (one row per map, one panel per method, the same few scenarios).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

import builders as B

from torchnav.config import to_dict
from torchnav.controllers import CONTROLLERS, make_controller
from torchnav.envs import NavEnv
from torchnav.evaluation import (FINAL_EVAL_SEED, bind_policy, eval_config, outcome_letter, outcome_letters, run_episodes, summarize,
                                 time_efficiency)
from torchnav.maps import MapError, load_map
from torchnav.policy import load_policy
from torchnav.tasks import NavConfig
from torchnav.tasks.robots import override_config

DEFAULT_MAPS = ("arena", "warehouse", "maze")


def load_methods(checkpoints: list[str], controllers: list[str], task_set: Mapping[str, Any] | None = None
                 ) -> tuple[list[tuple[str, Any, NavConfig | None]], NavConfig]:
    """``[(name, policy, own config or None)]`` and the config the controllers use (the first
    checkpoint's, else the defaults); ``task_set`` (nested task keys, ``--set``) is laid over each."""
    methods, base, task_set = [], None, dict(task_set or {})
    for path in checkpoints:
        sp = load_policy(path)
        if sp.task != "nav":
            raise ValueError(f"{path}: a {sp.task!r} policy, not a navigation policy")
        cfg = NavConfig.from_dict(override_config(sp.task_config, task_set), where=f"--set on {path}") if task_set else sp.config()
        base = base or cfg
        name = Path(path).stem if Path(path).stem not in ("actor", "checkpoint") else f"{sp.algorithm}:{Path(path).parent.name}"
        methods.append((name, sp.policy, cfg))
    base = base or NavConfig.from_dict(task_set, where="--set")
    for name in controllers:
        methods.append((name, make_controller(name, nav=base), None))
    names = [m[0] for m in methods]
    if len(set(names)) != len(names):
        raise ValueError(f"two methods share a name: {names}")
    return methods, base


def scenarios(cfg: NavConfig, n: int, seed: int) -> dict[str, torch.Tensor]:
    """Starts, goals and worlds of the first ``n`` episodes that ``run_episodes`` plays for ``cfg``."""
    env = NavEnv(cfg, num_envs=n, seed=seed)
    env.reset()
    s = env.state
    w = env.task.full_world(s.world)
    return {"start": s.start, "goal": s.goal, "segments": w.segments, "boxes": w.boxes, "circles": w.circles}


def same_scenarios(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return all(a[k].shape == b[k].shape and torch.equal(a[k], b[k]) for k in a)


def method_configs(methods: list[tuple[str, Any, NavConfig | None]], base: NavConfig, cell: Callable[[NavConfig], NavConfig],
                   n: int, seed: int, where: str) -> list[NavConfig]:
    """Each method's config for one cell of a comparison: ``cell(own)`` for a checkpoint,
    ``cell(base)`` for a controller. A checkpoint whose cell config gives other scenarios
    than ``cell(base)`` over the first ``n`` episodes at ``seed`` is refused (``ValueError``)."""
    cfg, ref, out = cell(base), None, []
    for name, _, own in methods:
        mcfg = cfg if own is None else cell(own)
        if mcfg != cfg:
            ref = scenarios(cfg, n, seed) if ref is None else ref
            if not same_scenarios(ref, scenarios(mcfg, n, seed)):
                raise ValueError(f"{name}: its task config gives other scenarios than the first checkpoint's on {where} "
                                 "(robot radius, reset or map settings differ); compare it in a separate run")
        out.append(mcfg)
    return out


def evaluate_method(name: str, policy: Any, cfg: NavConfig, episodes: int, seed: int, device: str,
                    where: str, shortest: torch.Tensor | None = None) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """``summarize`` of ``episodes`` episodes of ``policy`` on ``cfg`` (with ``shortest``, the episodes'
    shortest paths, also ``time_efficiency``) and, for a planner, its statistics (plans, paths not found,
    ms per plan); prints one progress line."""
    if hasattr(policy, "stats"):
        policy.stats = {"plans": 0, "no_path": 0, "seconds": 0.0}
    t0 = time.perf_counter()
    res = run_episodes(policy, cfg, episodes, seed=seed, device=device)
    s = summarize(res)
    timing = ""
    if shortest is not None:
        s.update(time_efficiency(res, shortest, cfg))
        timing = f"time x{s['time_ratio']['mean']:<6.2f} score {s['time_score']['mean']:.2f}  "
    # each episode's outcome (S success, C collision, T timeout), for paired comparisons of methods
    s["outcomes"] = outcome_letters(res)
    stats = getattr(policy, "stats", None)
    if stats is not None:
        stats = {**stats, "ms_per_plan": 1e3 * stats["seconds"] / max(stats["plans"], 1)}
    print(f"[{where}] {name:<22} success {_pct(s, 'success'):<20} collision {_pct(s, 'collision'):<20} "
          f"timeout {_pct(s, 'timeout'):<20} steps {_mean(s, 'steps_to_goal', 1):<20} {timing}({time.perf_counter() - t0:.1f} s)", flush=True)
    return s, stats


@torch.no_grad()
def trajectories(policy, cfg: NavConfig, n: int, seed: int, device: str = "cpu") -> dict[str, Any]:
    """Poses ``(n, T, 3)`` of ``n`` episodes (held at the final pose after ``done``), the step each
    ended at ``(n,)``, outcome letters (S success, C collision, T timeout), the worlds and goals."""
    env = NavEnv(cfg, num_envs=n, device=device, seed=seed)
    bind_policy(policy, env)
    td = env.reset()
    world, goal = env.task.full_world(env.state.world).clone(), env.state.goal.clone()
    poses, end = [td["pose"].clone()], torch.full((n,), cfg.max_steps, dtype=torch.long)
    finished = torch.zeros(n, dtype=torch.bool, device=env.device)
    outcome = ["T"] * n
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for t in range(cfg.max_steps):
            td = env.step(policy(td))
            nxt = td["next"]
            new = nxt["done"].reshape(-1) & ~finished
            pose = torch.where(finished[:, None], poses[-1], nxt["pose"])
            poses.append(pose.clone())
            for e in new.nonzero().squeeze(-1).tolist():
                end[e] = t + 1
                outcome[e] = outcome_letter(nxt["success"][e].item(), nxt["collision"][e].item())
            finished |= new
            if finished.all():
                break
            td = nxt.exclude("reward", "done", "terminated", "truncated")
    return {"pose": torch.stack(poses, 1).cpu(), "end": end, "outcome": outcome, "world": world.to("cpu"), "goal": goal.cpu()}


def plot(runs: dict[str, dict[str, dict[str, Any]]], specs: dict[str, Any]):
    """One row per map, one panel per method: the map, each scenario's random objects and path in its colour."""
    from torchnav.render import _grid, draw_obstacles, plot_trajectories

    maps = list(runs)
    methods = list(next(iter(runs.values())))
    fig, axes = _grid(len(maps) * len(methods), len(methods), panel=3.0)
    for r, m in enumerate(maps):
        spec = specs[m]
        for c, name in enumerate(methods):
            ax, tr = axes[r * len(methods) + c], runs[m][name]
            draw_obstacles(ax, spec.segments, spec.circles, spec.boxes)
            n, T = tr["pose"].shape[:2]
            w = tr["world"]
            for e in range(n):  # this scenario's random objects, in its colour
                nb, nc = spec.n_fixed_boxes, spec.n_fixed_circles
                boxes = w.boxes[e, nb:][w.box_mask[e, nb:]].numpy()
                circles = w.circles[e, nc:][w.circle_mask[e, nc:]].numpy()
                draw_obstacles(ax, (), circles, boxes, color=f"C{e % 10}", edgecolor=f"C{e % 10}", alpha=0.45)
            done = np.zeros((n, T), bool)
            for e in range(n):
                done[e, min(int(tr["end"][e]), T - 1)] = True
            plot_trajectories(tr["pose"], envs=range(n), done=done, goal=tr["goal"], ax=ax)
            xmin, ymin, xmax, ymax = spec.bounds
            ax.set_xlim(xmin - 0.2, xmax + 0.2)
            ax.set_ylim(ymin - 0.2, ymax + 0.2)
            ax.set_title(f"{name} on {m}: {' '.join(tr['outcome'])}", fontsize=8)
            ax.set_xlabel("")
            ax.set_ylabel("")
            ax.tick_params(labelsize=6)
    fig.suptitle("Same scenarios for every method (S success, C collision, T timeout; o start, x end, * goal)", fontsize=9)
    fig.tight_layout()
    return fig


def _pct(s: dict[str, Any], k: str) -> str:
    r = s[k]
    return f"{100 * r['rate']:.1f} [{100 * r['ci95'][0]:.1f}, {100 * r['ci95'][1]:.1f}]"


def _mean(s: dict[str, Any], k: str, digits: int) -> str:
    r = s[k]
    if r["mean"] != r["mean"]:  # nan: no successful episode
        return "–"
    return f"{r['mean']:.{digits}f} [{r['ci95'][0]:.{digits}f}, {r['ci95'][1]:.{digits}f}]"


def markdown(results: dict[str, dict[str, Any]], episodes: int, seed: int) -> str:
    """One Markdown table, method x map."""
    lines = [
        f"{episodes} episodes per method and map, seed {seed}, goals anywhere; 95% intervals in brackets "
        "(Wilson for rates; normal for means, over successful episodes).",
        "",
        "| method | map | success % | collision % | timeout % | steps to goal | path ratio |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for name, per_map in results.items():
        for m, s in per_map.items():
            lines.append(f"| {name} | {m} | {_pct(s, 'success')} | {_pct(s, 'collision')} | {_pct(s, 'timeout')} | "
                         f"{_mean(s, 'steps_to_goal', 1)} | {_mean(s, 'path_ratio', 2)} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoints", nargs="*", help="actor.pt / checkpoint.pt files of navigation policies")
    p.add_argument("--maps", nargs="+", default=list(DEFAULT_MAPS), help=f"maps (default: {' '.join(DEFAULT_MAPS)})")
    p.add_argument("--episodes", type=int, default=1000, help="episodes per method and map (default 1000)")
    p.add_argument("--seed", type=int, default=FINAL_EVAL_SEED, help="scenario seed (default 20000, as recipes/evaluate.py)")
    p.add_argument("--controllers", nargs="*", default=None, help=f"controllers (default all: {' '.join(CONTROLLERS)}; none: --controllers)")
    p.add_argument("--scenarios", type=int, default=3, help="scenarios per map drawn in trajectories.png (default 3; 0: no picture)")
    p.add_argument("--out", default="runs/compare", help="output directory (default runs/compare)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--threads", type=B.threads_arg, default="auto", help="torch CPU threads: auto (the cores other processes leave free) or a number")
    a = p.parse_args(argv)
    if a.episodes < 1:
        p.error("--episodes must be >= 1")
    controllers = list(CONTROLLERS) if a.controllers is None else a.controllers
    for name in controllers:
        if name not in CONTROLLERS:
            p.error(f"unknown controller {name!r}; available: {', '.join(CONTROLLERS)}")
    if not controllers and not a.checkpoints:
        p.error("nothing to compare: give checkpoints or controllers")
    B.ThreadGovernor(a.threads)
    specs = {}
    for m in a.maps:
        try:
            specs[m] = load_map(m)
        except MapError as e:
            p.error(f"--maps: {e}")
    methods, base = load_methods(a.checkpoints, controllers)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, dict[str, Any]] = {name: {} for name, _, _ in methods}
    planning: dict[str, dict[str, Any]] = {}
    runs: dict[str, dict[str, Any]] = {}
    first_chunk = min(a.episodes, 4096)  # run_episodes' first batch
    for m in a.maps:
        cfgs = method_configs(methods, base, lambda c: eval_config(c, map=m), first_chunk, a.seed, m)
        runs[m] = {}
        for (name, policy, _), mcfg in zip(methods, cfgs):
            results[name][m], stats = evaluate_method(name, policy, mcfg, a.episodes, a.seed, a.device, m)
            if stats is not None:
                planning.setdefault(name, {})[m] = stats
            if a.scenarios > 0:
                runs[m][name] = trajectories(policy, mcfg, a.scenarios, a.seed, a.device)
    md = markdown(results, a.episodes, a.seed)
    doc = {"episodes": a.episodes, "seed": a.seed, "maps": a.maps, "methods": [n for n, _, _ in methods],
           "checkpoints": a.checkpoints, "config": to_dict(base), "results": results, "planning": planning}
    (out / "results.json").write_text(json.dumps(doc, indent=2))
    (out / "results.md").write_text(md)
    print("\n" + md)
    if a.scenarios > 0:
        plot(runs, specs).savefig(out / "trajectories.png", dpi=110)
    print(f"wrote {out / 'results.json'}, {out / 'results.md'}" + (f", {out / 'trajectories.png'}" if a.scenarios > 0 else ""))
    return doc


if __name__ == "__main__":
    B.main_guard(main)
