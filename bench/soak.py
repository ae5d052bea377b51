"""Soak: a long run of random and adversarial actions over every map, world family and simulator
option, counting what must never happen (docs/performance.md, "Soak").

Cells (one env each, ``--num-envs`` envs): every shipped map; the procedural worlds (every family
of ``torchnav.worlds.FAMILIES`` mixed in one batch, each env drawing its family) at difficulties
0, 0.5 and 1; options on ``arena``: the exact sector scan, moving discs (recipes/maps/arena_movers.yaml),
domain randomisation, the camera's depth row, the IMU, discrete actions; and several robots per
env (``MultiNavEnv``, 4 robots). The cells are visited ``--rounds`` times in turn, each visit on a
freshly built env, so that memory growth and throughput drift show as differences between rounds.

Each visit drives the env two ways, switching the action kind every ``--window`` steps (random
in [-1, 1], saturated at the corners, alternating full forward-left and full reverse-right, far
outside [-1, 1], and, for the simulator, NaN in some envs):

* through the env's API (``step_and_maybe_reset``, ``--env-share`` of the visit's steps; all of
  a multi-robot visit's, which has only that share): observations, rewards, resets. Once per
  window a NaN and an inf action are stepped: the env must refuse them with a ValueError and stay
  as it was (``check_actions``; an acceptance is counted in ``silent``);
* through the simulator step the env uses (``torch.compile`` of ``torchnav.sim.step`` with
  ``--compile``), on the env's worlds and robots, redrawn by a full reset every ``--reset-every``
  steps: the bulk of the steps. The simulator treats a non-finite command as a stop (docs/sim.md).

Counted at every window: NaN in any floating-point field of the state and the observation; inf
where none is documented (``goal_path`` before it is known, the "no limit" acceleration limits,
an absent robot's clearance may be inf); poses outside their world (the box around its walls,
widened by the robot's radius): in the env phase every such pose counts, in the simulator phase
(where robots drive through what they hit, as documented) only those of robots that never
collided since their reset, which would have passed through a wall; resident memory
(``VmRSS``) after every visit; env-steps/s per window.

    python bench/soak.py                       # 1e9 env-steps, 4,096 envs, compiled, 2 threads
    python bench/soak.py --quick --json        # seconds; a JSON summary on the last line
    python bench/soak.py --steps 2e8 --rounds 2
"""

from __future__ import annotations

import argparse
import gc
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402  (sets TORCHINDUCTOR_COMPILE_THREADS before torch is imported)

import torch  # noqa: E402
from torch._dynamo.utils import counters  # noqa: E402

from torchnav.envs import make_multi_nav_env, make_nav_env  # noqa: E402
from torchnav.maps import available_maps  # noqa: E402
from torchnav.worlds import FAMILIES  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
KINDS = ("random", "saturated", "alternating", "out_of_range", "nan_rows")
# Fields that may hold +inf by design (docs/tasks.md, docs/sim.md); NaN is never allowed anywhere.
INF_OK = ("goal_path", "lin_acc_max", "ang_acc_max", "clearance")
RANDOMIZE = {"v_max": [0.3, 0.5], "omega_max": [0.5, 1.0], "delay": [0, 2], "wheel_noise": [0.0, 0.02], "range_noise": [0.0, 0.02],
             "dropout": [0.0, 0.05], "angle_offset": [-0.05, 0.05], "max_range": [6.0, 10.0], "robot_radius": [0.15, 0.25]}


def cells() -> list[tuple[str, str, dict[str, Any]]]:
    """``(name, "nav" or "multi", make_*_env overrides)`` of every cell."""
    out = [(f"map:{m}", "nav", {"map": m}) for m in available_maps()]
    out += [(f"worlds@{d}", "nav", {"worlds": {"families": {f: 1.0 for f in FAMILIES}, "difficulty": d}}) for d in (0.0, 0.5, 1.0)]
    out += [
        ("arena+sectors", "nav", {"lidar": {"scan": "sectors"}}),
        ("arena+movers", "nav", {"map": str(ROOT / "recipes" / "maps" / "arena_movers.yaml")}),
        ("arena+randomize", "nav", {"randomize": RANDOMIZE}),
        ("arena+camera", "nav", {"camera": {"enabled": True}, "observation": {"camera": True}}),
        ("arena+imu", "nav", {"imu": {"enabled": True}, "observation": {"imu": True}}),
        ("arena+discrete", "nav", {"action": {"mode": "discrete"}}),
        ("multi:arena x4", "multi", {}),
    ]
    return out


def rss_mb() -> float:
    """Resident memory of this process, MB (``VmRSS`` of /proc/self/status; NaN where there is none)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return math.nan


def actions(kind: str, t: int, shape: tuple[int, ...], discrete: bool, g: torch.Generator) -> torch.Tensor:
    """A batch of actions ``shape`` (continuous in [-1, 1] and beyond, or one-hot) of one kind at step ``t``."""
    if discrete:
        n = shape[-1]
        idx = {"random": lambda: torch.randint(0, n, shape[:-1], generator=g), "saturated": lambda: torch.randint(0, 2, shape[:-1], generator=g) * (n - 1),
               "alternating": lambda: torch.full(shape[:-1], (t % 2) * (n - 1))}.get(kind, lambda: torch.randint(0, n, shape[:-1], generator=g))()
        return torch.nn.functional.one_hot(idx, n).float()
    if kind == "saturated":
        return torch.randint(0, 2, shape, generator=g).float() * 2 - 1
    if kind == "alternating":
        s = 1.0 if t % 2 == 0 else -1.0
        return torch.tensor([s, s]).expand(shape).clone()
    a = torch.rand(shape, generator=g) * 2 - 1
    if kind == "out_of_range":
        return a * 1e6
    if kind == "nan_rows":  # the simulator phase only: NaN in about 1 env in 8
        return torch.where(torch.rand(shape[:1], generator=g)[:, None] < 0.125, math.nan, a)
    return a


class Counts:
    """What a cell's windows found, summed (tensors until read, so the steps do not wait on the host)."""

    def __init__(self) -> None:
        self.nan = 0
        self.inf_unexpected = 0
        self.out_of_bounds = 0
        self.tunnelled = 0
        self.nan_rejected = 0
        self.silent = 0
        self.errors: list[str] = []

    def state(self, tree: Any, prefix: str = "") -> None:
        """NaN anywhere and inf outside :data:`INF_OK` in the floating-point leaves of a state or output."""
        items = tree.items() if isinstance(tree, dict) else ()
        for k, v in items:
            key = f"{prefix}{k}"
            if isinstance(v, dict):
                self.state(v, key + ".")
            elif isinstance(v, torch.Tensor) and v.is_floating_point():
                self.nan += int(v.isnan().sum())
                if not any(key.endswith(ok) for ok in INF_OK):
                    self.inf_unexpected += int(v.isinf().sum())


def world_box(world, radius: float) -> torch.Tensor:
    """``(B, 4)`` ``[xmin, ymin, xmax, ymax]`` of each env's walls, widened by ``radius`` (inf where an env has none)."""
    seg, mask = world.segments, world.segment_mask
    x = seg[..., 0::2].masked_fill(~mask[..., None], math.nan)
    y = seg[..., 1::2].masked_fill(~mask[..., None], math.nan)
    flat = lambda v: v.reshape(v.shape[0], -1)  # noqa: E731
    lo = torch.stack((flat(x).nan_to_num(math.inf).amin(1), flat(y).nan_to_num(math.inf).amin(1)), 1) - radius
    hi = torch.stack((flat(x).nan_to_num(-math.inf).amax(1), flat(y).nan_to_num(-math.inf).amax(1)), 1) + radius
    return torch.cat((lo.nan_to_num(-math.inf, posinf=-math.inf), hi.nan_to_num(math.inf, neginf=math.inf)), 1)


def outside(pose: torch.Tensor, box: torch.Tensor) -> torch.Tensor:
    """``(B,)`` bool: the pose's position lies outside its env's box (a NaN position counts as outside)."""
    x, y = pose[..., 0], pose[..., 1]
    if x.dim() == 2:  # several robots per env
        box = box[:, None]
    inside = (x >= box[..., 0]) & (y >= box[..., 1]) & (x <= box[..., 2]) & (y <= box[..., 3])
    return ~inside


def build(kind: str, overrides: dict[str, Any], num_envs: int, seed: int, compile_step: bool):
    if kind == "multi":
        return make_multi_nav_env(num_envs=max(1, num_envs // 4), n_robots=4, seed=seed, **overrides)
    env = make_nav_env(num_envs=num_envs, seed=seed, **overrides)
    if compile_step:
        env.task.compile_step()
    return env


def env_phase(env, kind: str, steps: int, window: int, c: Counts, g: torch.Generator, rates: list[float]) -> int:
    """``steps`` batched steps through the env's API; returns the env-steps done."""
    multi = kind == "multi"
    key = ("agents", "action") if multi else "action"
    spec = env.full_action_spec["agents", "action"] if multi else env.action_spec
    discrete = env.cfg.action.mode == "discrete"
    td = env.reset()
    done = 0
    for w0 in range(0, steps, window):
        n = min(window, steps - w0)
        act_kind = KINDS[(w0 // window) % 4]  # NaN rows are refused by the env: probed below instead
        # the env must refuse a NaN and an inf action, leaving its episodes as they were
        pose = (env.state.sim.robots.pose if multi else env.state.sim.pose).clone()
        for bad in (math.nan, math.inf):
            probe = td.clone(False)
            a = actions("random", 0, tuple(spec.shape), discrete, g)
            a.view(a.shape[0], -1)[0, 0] = bad
            probe.set(key, a)
            try:
                env.step(probe)
                c.silent += 1
            except ValueError:
                c.nan_rejected += 1
        now = env.state.sim.robots.pose if multi else env.state.sim.pose
        if not torch.equal(now, pose):
            c.errors.append("a refused action changed the env's state")
        t0 = time.perf_counter()
        for t in range(n):
            td.set(key, actions(act_kind, t, tuple(spec.shape), discrete, g))
            if t == n - 1:  # the worlds this step's poses are in (a reset may draw new ones)
                box = world_box(env.state.world, 0.0)
            out, td = env.step_and_maybe_reset(td)
            if t == n - 1:
                nxt = out["next"]
                c.state(nxt.to_dict())
                c.out_of_bounds += int(outside(nxt["agents", "pose"] if multi else nxt["pose"], box).sum())
        rates.append(n * env.num_envs / max(time.perf_counter() - t0, 1e-9))
        c.state(env.state.to_dict())
        done += n * env.num_envs
    return done


def sim_phase(env, steps: int, window: int, reset_every: int, c: Counts, g: torch.Generator, rates: list[float]) -> int:
    """``steps`` batched simulator steps on the env's worlds and robots; returns the env-steps done."""
    task, done = env.task, 0
    discrete = env.cfg.action.mode == "discrete"
    radius = max(task.params.robot_radius, 0.25)  # randomised radii go up to 0.25 m
    sim = world = box = hit = None
    for w0 in range(0, steps, window):
        n = min(window, steps - w0)
        act_kind = KINDS[(w0 // window) % len(KINDS)]
        t0 = time.perf_counter()
        with torch.no_grad():
            for t in range(n):
                if sim is None or (w0 + t) % reset_every == 0:
                    env.reset()
                    sim, world, params = env.state.sim, env.state.world, env.state.env_params if task.randomized else None
                    box, hit = world_box(world, radius), sim.collided.clone()
                twist = task.command(actions(act_kind, t, tuple(env.action_spec.shape), discrete, g))
                sim = task._sim_step(sim, twist, world, task.params, generator=env.generator, env_params=params)
                hit |= sim.collided
        rates.append(n * env.num_envs / max(time.perf_counter() - t0, 1e-9))
        c.state(sim.to_dict(), "sim.")
        c.tunnelled += int((outside(sim.pose, box) & ~hit).sum())
        done += n * env.num_envs
    return done


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--steps", type=float, default=1e9, help="env-steps in all (default 1e9)")
    p.add_argument("--num-envs", type=int, default=4096)
    p.add_argument("--rounds", type=int, default=4, help="visits of every cell (default 4)")
    p.add_argument("--window", type=int, default=50, help="batched steps between checks and action-kind switches")
    p.add_argument("--env-share", type=float, default=0.02, help="fraction of each visit through the env's API (default 0.02)")
    p.add_argument("--reset-every", type=int, default=400, help="simulator steps between full resets (new worlds and starts)")
    p.add_argument("--compile", action=argparse.BooleanOptionalAction, default=True, help="compile the simulator step (default on)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--cells", default=None, help="comma-separated cell names (default all; see the table)")
    p.add_argument("--quick", action="store_true", help="seconds-long run: 32 envs, 2 rounds, a few windows per cell, eager")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON line after the table")
    a = p.parse_args(argv)
    if a.quick:
        # windows of 4 steps: each phase meets every action kind (the simulator phase NaN rows too) in its 20 steps
        a.steps, a.num_envs, a.rounds, a.window, a.env_share, a.reset_every, a.compile = 32 * 2 * 15 * 40, 32, 2, 4, 0.5, 40, False
    todo = cells()
    if a.cells:
        names = a.cells.split(",")
        unknown = sorted(set(names) - {n for n, _, _ in todo})
        if unknown:
            p.error(f"--cells: unknown {unknown}; known: {', '.join(n for n, _, _ in todo)}")
        todo = [c for c in todo if c[0] in names]
    common.set_threads(a.threads)
    dyn = torch._dynamo.config
    dyn.recompile_limit = max(dyn.recompile_limit, 4 * len(todo))  # every cell's step stays compiled across the rounds
    # The budget goes to the cells with a simulator phase (a multi-robot visit plays only its env share, on top), each
    # visit rounded up to whole batched steps: the run does at least --steps env-steps.
    stepped = sum(1 for _, kind, _ in todo if kind != "multi") or len(todo)
    per_visit = -(-int(a.steps) // (a.rounds * stepped))
    g = torch.Generator().manual_seed(a.seed)
    stats = {name: {"counts": Counts(), "env_steps": 0, "rates": [], "rss_mb": []} for name, _, _ in todo}
    rss_rounds, t_start = [], time.perf_counter()
    print(f"# soak: {int(a.steps):,} env-steps, {len(todo)} cells x {a.rounds} rounds, {a.num_envs} envs, "
          f"{'compiled' if a.compile else 'eager'}, {a.threads} threads; {common.machine_info('cpu')}", file=sys.stderr, flush=True)
    for r in range(a.rounds):
        for name, kind, overrides in todo:
            s = stats[name]
            c = s["counts"]
            try:
                env = build(kind, overrides, a.num_envs, a.seed + r, a.compile)
                batched = -(-per_visit // env.num_envs)
                through_env = max(1, int(batched * a.env_share))
                s["env_steps"] += env_phase(env, kind, through_env, a.window, c, g, s["rates"])
                if kind != "multi":
                    s["env_steps"] += sim_phase(env, max(0, batched - through_env), a.window, a.reset_every, c, g, s["rates"])
            except Exception as e:  # noqa: BLE001 - a traceback is a finding of the soak: counted and reported, the soak goes on
                c.errors.append(f"round {r}: {type(e).__name__}: {e}")
            env = None
            gc.collect()
            s["rss_mb"].append(rss_mb())
            print(f"#   {name}: {s['env_steps']:,} env-steps, {s['rates'][-1] if s['rates'] else math.nan:,.0f} env-steps/s last window, "
                  f"at {time.perf_counter() - t_start:.0f} s", file=sys.stderr, flush=True)
        rss_rounds.append(rss_mb())
        print(f"# round {r + 1}/{a.rounds} done at {time.perf_counter() - t_start:.0f} s, RSS {rss_rounds[-1]:.0f} MB", file=sys.stderr, flush=True)
    rows = []
    for name, _, _ in todo:
        s, c = stats[name], stats[name]["counts"]
        rates = s["rates"]
        half = max(1, len(rates) // 2)
        first, last = (statistics.median(rates[:half]), statistics.median(rates[half:])) if len(rates) > 1 else (math.nan, math.nan)
        rows.append({"cell": name, "env_steps": s["env_steps"], "nan": c.nan, "inf_unexpected": c.inf_unexpected, "out_of_bounds": c.out_of_bounds,
                     "tunnelled": c.tunnelled, "bad_actions_refused": c.nan_rejected, "silent": c.silent, "errors": c.errors,
                     "env_steps_per_s_first_half": first, "env_steps_per_s_second_half": last,
                     "rss_mb_per_round": [round(x, 1) for x in s["rss_mb"]]})
    print(f"{'cell':<18} {'env-steps':>14} {'NaN':>5} {'inf':>5} {'out':>5} {'tunnel':>6} {'refused':>8} {'silent':>6} {'errors':>6} "
          f"{'steps/s 1st half':>17} {'2nd half':>10}")
    for row in rows:
        print(f"{row['cell']:<18} {row['env_steps']:>14,} {row['nan']:>5} {row['inf_unexpected']:>5} {row['out_of_bounds']:>5} {row['tunnelled']:>6} "
              f"{row['bad_actions_refused']:>8} {row['silent']:>6} {len(row['errors']):>6} {row['env_steps_per_s_first_half']:>17,.0f} "
              f"{row['env_steps_per_s_second_half']:>10,.0f}")
        for e in row["errors"][:3]:
            print(f"    {e}")
    total = {k: sum(r[k] for r in rows) for k in ("env_steps", "nan", "inf_unexpected", "out_of_bounds", "tunnelled", "bad_actions_refused", "silent")}
    summary = {"bench": "soak", "steps_requested": int(a.steps), **total, "errors": sum(len(r["errors"]) for r in rows), "cells": rows, "rounds": a.rounds, "num_envs": a.num_envs,
               "compiled": a.compile, "compiled_graphs": int(counters["stats"]["unique_graphs"]), "threads": a.threads, "wall_s": round(time.perf_counter() - t_start, 1),
               "rss_mb_per_round": [round(x, 1) for x in rss_rounds],
               "rss_growth_mb": round(rss_rounds[-1] - rss_rounds[0], 1) if len(rss_rounds) > 1 else 0.0, **common.machine_info("cpu")}
    print(f"\n{total['env_steps']:,} env-steps in {summary['wall_s']:.0f} s: NaN {total['nan']}, unexpected inf {total['inf_unexpected']}, "
          f"out of bounds {total['out_of_bounds']}, through walls {total['tunnelled']}, bad actions refused {total['bad_actions_refused']}, "
          f"accepted {total['silent']}, errors {summary['errors']}; RSS per round {summary['rss_mb_per_round']} MB")
    if a.json:
        common.emit_json(summary)
    return summary


if __name__ == "__main__":
    main()
