"""Dense worlds: simulator env-steps/s with 400 obstacles per env, next to the standard load.

Loads (per env, random and different in every env; one robot, random twists):

* ``standard``      the load of ``bench/sim_throughput.py``: 10 x 10 m arena, 4 walls +
                    4 boxes + 4 circles, 20 rays over 180 degrees, 10 m range;
* ``dense-sectors`` a 20 x 20 m walled room with 300 posts (circles, radius 0.05-0.3 m)
                    and 100 boxes (0.2-0.8 m sides), the exact sector scan with 20
                    sectors over 360 degrees, 10 m range;
* ``dense-rays``    the same worlds, 180 rays over 360 degrees (2-degree spacing);
* ``dense-brute``   dense-rays with the broad phase off (every ray against every
                    obstacle), as every version before the broad phase ran it;
* ``generalist``    what ``recipes/configs/ppo_generalist.yaml`` steps: its six world
                    families at the curriculum's top difficulty, each world padded to
                    the mixture's slots (68 walls, 70 circles, 48 boxes), its sector scan
                    (20 sectors, 360 degrees) and robot, from the task's own first episodes.

Each load runs ``torchnav.sim.step`` eager and compiled (``torch.compile``); compile
time is excluded from the rates. The table ends with the ratios measured in this
run: each dense load against the standard load, and the broad phase against brute
force. For the broad-phase loads it also prints how many envs' scans the broad phase
gives exactly (``scan_is_exact``, after the timed steps).

    python bench/dense_lidar.py                  # 4,096 envs, eager and compiled
    python bench/dense_lidar.py --quick          # a seconds-long smoke run (64 envs, eager)
    python bench/dense_lidar.py --num-envs 1024 --modes compiled --json
    python bench/dense_lidar.py --loads generalist --num-envs 2048 --modes compiled   # the generalist recipe's step
    python bench/dense_lidar.py --threads 1 --cpu-time --loads standard,dense-sectors --modes compiled   # a shared machine
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402  (sets TORCHINDUCTOR_COMPILE_THREADS before torch is imported)

import torch  # noqa: E402
from sim_throughput import ROBOT, make_load  # noqa: E402

from torchnav.sim import LidarParams, SimParams, World, init_state, make_world, planar_world, scan_is_exact, step  # noqa: E402

HALF = 10.0  # m: the dense room spans [-10, 10] x [-10, 10]
N_POSTS, N_BOXES = 300, 100


def _lidar(**layout: Any) -> LidarParams:
    """The navigation task's lidar (the one of sim_throughput's rows) with ``layout``."""
    return replace(ROBOT.lidar, **layout)


LOADS = {
    "standard": _lidar(n_rays=20, fov=math.pi, max_range=10.0),
    # The broad phase tuned for these worlds: one boundary ray per obstacle for the sectors,
    # 5 rays per obstacle for the ray scan, 16 wide obstacles per kind on every ray.
    "dense-sectors": _lidar(n_rays=20, fov=2 * math.pi, max_range=10.0, scan="sectors", window=0, dense_slots=16),
    "dense-rays": _lidar(n_rays=180, fov=2 * math.pi, max_range=10.0, window=2, dense_slots=16),
    "dense-brute": _lidar(n_rays=180, fov=2 * math.pi, max_range=10.0, dense_slots=10**9),
    "generalist": None,  # the recipe config's own lidar (make_generalist)
}
GENERALIST_CONFIG = Path(__file__).resolve().parent.parent / "recipes" / "configs" / "ppo_generalist.yaml"
TARGET_DENSE = 250_000  # env-steps/s at 4,096 envs, compiled, 2 CPU threads
TARGET_RATIO = 10.0  # the dense load within 10x of the standard load


def make_dense(num_envs: int, params: SimParams, seed: int = 0) -> tuple[Any, World, list[torch.Tensor]]:
    """Initial state, per-env random dense world and a few batches of random actions.

    The world is static, so it is stored component-major once here (``planar_world``),
    as a caller stepping one world many times would; ``step`` then skips its copy."""
    g = torch.Generator().manual_seed(seed)
    b, h = num_envs, HALF
    u = common.uniform_sampler(g)
    base = make_world(b, segments=[[-h, -h, h, -h], [h, -h, h, h], [h, h, -h, h], [-h, h, -h, -h]])
    posts = torch.stack((u(-h, h, b, N_POSTS), u(-h, h, b, N_POSTS), u(0.05, 0.3, b, N_POSTS)), -1)
    boxes = torch.stack((u(-h, h, b, N_BOXES), u(-h, h, b, N_BOXES), u(0.1, 0.4, b, N_BOXES), u(0.1, 0.4, b, N_BOXES), u(-math.pi, math.pi, b, N_BOXES)), -1)
    world = World(
        segments=base.segments, segment_mask=base.segment_mask,
        circles=posts, circle_mask=torch.ones(b, N_POSTS, dtype=torch.bool),
        boxes=boxes, box_mask=torch.ones(b, N_BOXES, dtype=torch.bool), batch_size=[b],
    )
    pose = common.free_poses(world, params.robot_radius, h, 0.3, u, tries=500)
    actions = common.random_twists(params, u, b)
    return init_state(pose, world, params), planar_world(world), actions


def make_generalist(num_envs: int, seed: int = 0) -> tuple[SimParams, Any, World, list[torch.Tensor]]:
    """The generalist recipe's simulator parameters, the first episodes of its task (every
    family at ``worlds.max_difficulty``; straight-line progress, so no goal grids are made)
    and a few batches of random twists."""
    import yaml

    from torchnav.tasks import NavConfig
    from torchnav.tasks.curriculum import CurriculumState
    from torchnav.tasks.navigation import NavTask

    raw = yaml.safe_load(GENERALIST_CONFIG.read_text())["task"]
    raw["worlds"]["difficulty"] = raw["worlds"]["max_difficulty"]
    raw["reward"]["progress_distance"] = "euclidean"
    cfg = NavConfig.from_dict(raw)
    task = NavTask(cfg, num_envs)
    g = torch.Generator().manual_seed(seed)
    state, _ = task.initial_state(CurriculumState.initial(cfg.curriculum, worlds=cfg.worlds), g)
    return task.params, state.sim, planar_world(state.world), common.random_twists(task.params, common.uniform_sampler(g), num_envs)


def bench_load(load: str, mode: str, num_envs: int, args: argparse.Namespace) -> dict[str, Any]:
    if load == "generalist":
        params, state, world, actions = make_generalist(num_envs, args.seed)
    else:
        params = replace(ROBOT, lidar=LOADS[load])
        state, world, actions = make_load(num_envs, "cpu", args.seed, params) if load == "standard" else make_dense(num_envs, params, args.seed)
    rec: dict[str, Any] = {"bench": "dense_lidar", "load": load, "mode": mode, "num_envs": num_envs, "obstacles": int(world.segment_mask[0].sum() + world.circle_mask[0].sum() + world.box_mask[0].sum()),
                           "readings": params.lidar.n_rays, "scan": params.lidar.scan, "compile_s": None,
                           "threads": torch.get_num_threads(), "clock": "cpu" if args.cpu_time else "wall"}

    def fn(s, a):
        return step(s, a, world, params)

    if mode == "compiled":
        torch._dynamo.reset()
        fn = torch.compile(fn)
    box = {"s": state, "i": 0}

    def call() -> None:
        box["s"] = fn(box["s"], actions[box["i"] % len(actions)])
        box["i"] += 1

    t0 = time.perf_counter()
    call()
    if mode == "compiled":
        rec["compile_s"] = round(time.perf_counter() - t0, 1)
    for _ in range(args.warmup):
        call()
    steps = args.steps or common.calibrate(call, "cpu", args.run_seconds, lo=2, hi=10_000)
    t = common.time_calls(call, items_per_call=num_envs, steps=steps, repeats=args.repeats, warmup=0, device="cpu")
    rec.update(**t.fields(), step_ms=round(t.call_us / 1000, 3))
    if load != "dense-brute":
        rec["exact_envs_frac"] = float(scan_is_exact(box["s"].pose, world, params.lidar).float().mean())
    return rec


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--num-envs", type=int, default=4096)
    p.add_argument("--loads", type=lambda s: s.split(","), default=[x for x in LOADS if x != "generalist"],
                   help=f"comma-separated, from {','.join(LOADS)} (default: all but generalist)")
    p.add_argument("--modes", type=lambda s: s.split(","), default=["eager", "compiled"], help="eager, compiled")
    common.timing_args(p, run_seconds=1.0, warmup=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="also print one JSON object per line")
    p.add_argument("--quick", action="store_true", help="64 envs, eager, few steps: a smoke test")
    args = p.parse_args(argv)
    if args.quick:
        args.num_envs, args.modes, args.steps, args.repeats, args.warmup = 64, ["eager"], 3, 2, 1
    bad = [x for x in args.loads if x not in LOADS] + [m for m in args.modes if m not in ("eager", "compiled")]
    if bad:
        p.error(f"unknown load or mode {bad}")
    return args


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    args = parse_args(argv)
    log = common.start(args, f"dense_lidar: {args.num_envs} envs on cpu", "cpu")
    records = []
    for load in args.loads:
        for mode in args.modes:
            rec = bench_load(load, mode, args.num_envs, args)
            records.append(rec)
            if args.json:
                common.emit_json(rec)
            print(f"   {load:>14} {mode:>8}: {common.human_rate(rec['env_steps_per_s'])} env-steps/s", file=sys.stderr, flush=True)
    rows = [[r["load"], r["mode"], r["obstacles"], f"{r['readings']} {r['scan']}", common.human_rate(r["env_steps_per_s"]), common.human_rate(r["env_steps_per_s_min"]),
             common.human_rate(r["env_steps_per_s_max"]), f"{r['step_ms']:.2f}", r["compile_s"] if r["compile_s"] is not None else "-",
             f"{r['exact_envs_frac']:.1%}" if "exact_envs_frac" in r else "-"] for r in records]
    print(file=log)
    common.print_table(["load", "mode", "obstacles", "lidar", "env-steps/s", "min", "max", "ms/step", "compile s", "exact envs"], rows, file=log)
    rate = {(r["load"], r["mode"]): r["env_steps_per_s"] for r in records}
    print("\n   ratios (same run):", file=log)
    for mode in args.modes:
        std = rate.get(("standard", mode))
        for load in ("dense-sectors", "dense-rays"):
            if std and (load, mode) in rate:
                print(f"   {mode:>8}: standard / {load} = x{std / rate[(load, mode)]:.1f} (target <= x{TARGET_RATIO:g})", file=log)
        if ("dense-brute", mode) in rate and ("dense-rays", mode) in rate:
            print(f"   {mode:>8}: dense-rays broad phase / brute force = x{rate[('dense-rays', mode)] / rate[('dense-brute', mode)]:.1f}", file=log)
        if ("dense-sectors", mode) in rate and mode == "compiled":
            r = rate[("dense-sectors", mode)]
            print(f"   {mode:>8}: dense-sectors {common.human_rate(r)} env-steps/s = x{r / TARGET_DENSE:.2f} of the {common.human_rate(TARGET_DENSE)} target", file=log)
    return records


if __name__ == "__main__":
    main()
