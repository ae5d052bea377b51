"""Planning time per query of the classical planners: A* on an occupancy grid and RRT-Connect.

Queries are real episodes: a ``NavEnv`` on the map (goals anywhere) samples one start,
goal and random-box layout per env, exactly as evaluation does, and each query plans
on its own env's world (fixed obstacles plus that episode's boxes), inflated by the
robot radius plus the first of the planner's margins. Rows, each timed per query with
``time.perf_counter`` on one CPU thread (numpy and Python):

* ``grid``   building the occupancy grid of one env: the map's fixed obstacles are
             rasterised once per map (reported as ``fixed_grid_ms``), then each env
             stamps its random boxes in, each within a window around it;
* ``astar``  8-connected A* on that grid, plus shortcutting (``plan_astar``);
* ``rrt``    RRT-Connect in continuous space with exact clearance checks, plus
             shortcutting (``plan_rrt``).

Reported: median, p90 and mean ms per query, and the fraction of queries that found a
path (a random pallet can close an aisle at this inflation; the controller then retries
with a smaller margin, which this benchmark does not time).

    python bench/planning.py                      # 200 queries on warehouse
    python bench/planning.py --map maze --queries 500 --json
    python bench/planning.py --quick              # a smoke run
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402  (sets TORCHINDUCTOR_COMPILE_THREADS before torch is imported)

import numpy as np  # noqa: E402
import torch  # noqa: E402

from torchnav.controllers import OccupancyGrid, RRTParams, make_controller, plan_astar, plan_rrt  # noqa: E402
from torchnav.envs import make_nav_env  # noqa: E402


def _stats(name: str, ms: list[float], ok: list[bool], args: argparse.Namespace, **extra: Any) -> dict[str, Any]:
    a = np.asarray(ms)
    return {
        "bench": "planning", "planner": name, "map": args.map, "queries": len(ms),
        "median_ms": round(float(np.median(a)), 3), "p90_ms": round(float(np.percentile(a, 90)), 3),
        "mean_ms": round(float(a.mean()), 3), "max_ms": round(float(a.max()), 3),
        "success": round(sum(ok) / len(ok), 4), **extra,
    }


def main(argv: list[str]) -> list[dict[str, Any]]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--map", default="warehouse", help="shipped map name or YAML path (default warehouse)")
    p.add_argument("--queries", type=int, default=200, help="start/goal pairs, each with its own box layout (default 200)")
    p.add_argument("--resolution", type=float, default=None, help="A* grid cell in m (default: the controller's, 0.1)")
    p.add_argument("--rrt-iters", type=int, default=None, help="RRT iteration cap (default: the controller's)")
    p.add_argument("--seed", type=int, default=0, help="env seed of the queries (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object per line on stdout (tables go to stderr)")
    p.add_argument("--quick", action="store_true", help="a few queries: a smoke test")
    a = p.parse_args(argv)
    if a.quick:
        a.queries = min(a.queries, 6)
    if a.queries < 1:
        p.error("--queries must be >= 1")
    common.set_threads(1)
    out = sys.stderr if a.json else sys.stdout

    gains = {k: v for k, v in (("resolution", a.resolution), ("rrt_max_iters", a.rrt_iters)) if v is not None}
    env = make_nav_env(a.map, num_envs=a.queries, seed=a.seed, curriculum={"mode": "off"})
    env.reset()
    astar = make_controller("astar", **gains).bind(env)
    rrt = make_controller("rrt", **gains).bind(env)
    g = astar.gains
    inflate = astar.radius + g.margins[0]
    params = RRTParams(step=rrt.gains.rrt_step, max_iters=rrt.gains.rrt_max_iters, check_step=rrt.gains.rrt_check_step)
    t0 = time.perf_counter()
    OccupancyGrid.build(astar.fixed, g.resolution)
    fixed_ms = 1e3 * (time.perf_counter() - t0)
    shape = astar.fixed_grid.clearance.shape

    s = env.state
    world = s.world.to("cpu")
    starts, goals = s.start[:, :2].double().numpy(), s.goal.double().numpy()
    times: dict[str, list[float]] = {"grid": [], "astar": [], "rrt": []}
    ok: dict[str, list[bool]] = {"grid": [], "astar": [], "rrt": []}
    for e in range(a.queries):
        full, rand = astar.env_obstacles(world, e)
        t0 = time.perf_counter()
        grid = astar.grid(rand)
        t1 = time.perf_counter()
        path = plan_astar(grid, starts[e], goals[e], inflate, snap=g.snap)
        t2 = time.perf_counter()
        times["grid"].append(1e3 * (t1 - t0))
        times["astar"].append(1e3 * (t2 - t1))
        ok["grid"].append(True)
        ok["astar"].append(path is not None)
        t0 = time.perf_counter()
        path = plan_rrt(full, starts[e], goals[e], inflate, params, seed=rrt.gains.seed)
        times["rrt"].append(1e3 * (time.perf_counter() - t0))
        ok["rrt"].append(path is not None)

    info = common.machine_info("cpu")
    extra = {"resolution_m": g.resolution, "grid_cells": list(shape), "inflate_m": round(inflate, 4), "rrt_max_iters": params.max_iters,
             "rrt_step_m": params.step, "fixed_grid_ms": round(fixed_ms, 2), "seed": a.seed}
    recs = [_stats(k, times[k], ok[k], a, **extra) for k in ("grid", "astar", "rrt")]
    print(f"planning on {a.map}: {a.queries} queries (start, goal and box layout each), inflation {inflate:.2f} m, "
          f"grid {shape[1]} x {shape[0]} cells of {g.resolution:g} m (fixed obstacles rasterised once: {fixed_ms:.1f} ms)", file=out)
    print(f"   {info['cpu']}, {info['cpu_count']} CPUs, torch {info['torch']}, 1 thread, load {info['loadavg_1m']}", file=out)
    warn = common.load_warning("cpu")
    if warn:
        print(warn, file=out)
    common.print_table(
        ["planner", "median ms", "p90 ms", "mean ms", "max ms", "found a path"],
        [[r["planner"], f"{r['median_ms']:.2f}", f"{r['p90_ms']:.2f}", f"{r['mean_ms']:.2f}", f"{r['max_ms']:.1f}",
          f"{100 * r['success']:.1f}%"] for r in recs],
        file=out,
    )
    print(f"   median rrt / astar (search only): {statistics.median(times['rrt']) / max(statistics.median(times['astar']), 1e-9):.1f}x", file=out)
    if a.json:
        common.emit_json({"bench": "planning_machine", **info})
        for r in recs:
            common.emit_json(r)
    return recs


if __name__ == "__main__":
    torch.set_num_threads(1)
    main(sys.argv[1:])
