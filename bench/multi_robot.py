"""Multi-robot throughput: env-steps/s and agent-steps/s of ``torchnav.sim.step_robots``, scaling in the
number of robots, and VMAS's ``navigation`` scenario at the same envs, agents and lidar rays.

Load (per env, after VMAS ``navigation``'s defaults): N robots of radius 0.1 m on an open plane,
started on a jittered grid in [-1, 1]^2 (no two closer than 0.25 m), each with a 12-ray lidar over
360 degrees of 0.35 m range that sees the other robots; random twist commands. ``--walls`` adds the
4 walls of a 4 x 4 m room around them. torchnav's figure is the raw simulator step (kinematics,
odometry, lidar against the other robots, clearance); VMAS's is its ``env.step`` (physics with two
substeps, collisions, lidar, rewards and observations), the smallest step VMAS offers.

VMAS is never a dependency of torchnav: its rows run when ``import vmas`` works in the interpreter
that runs this script (for example a throwaway venv with ``pip install vmas``) and are skipped
otherwise (``--vmas off`` skips them always).

    python bench/multi_robot.py                                   # 4,096 envs, N = 2, 4, 8, 16, eager and compiled
    python bench/multi_robot.py --envs 64 --repeats 1 --modes eager   # a quick check that it runs
    python bench/multi_robot.py --json --cpu-time --threads 1

The table gives, per simulator, mode and N: env-steps/s, agent-steps/s (env-steps/s times N),
``per-agent``, the agent-steps/s relative to the same simulator and mode at the smallest N (1.0
when the cost grows linearly in robots x rays), and ``x vmas``, torchnav's agent-steps/s over
VMAS's at the same N in the same run. Compile time is excluded from the rates.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402  (sets TORCHINDUCTOR_COMPILE_THREADS before torch is imported)

import torch  # noqa: E402

from torchnav.sim import SimParams, init_robots, make_robots, make_world, robot_world, step_robots  # noqa: E402
from torchnav.tasks import NavConfig  # noqa: E402

RADIUS = 0.1  # m, VMAS navigation's agent_radius
LIDAR_RANGE = 0.35  # m, VMAS navigation's lidar_range
SPAWN = 1.0  # m, robots start in [-SPAWN, SPAWN]^2 (VMAS navigation's world_spawning_x, _y)
ROOM = 2.0  # m, --walls: a room [-ROOM, ROOM]^2


def torchnav_params(rays: int) -> SimParams:
    """The navigation task's robot as VMAS's agent (radius, speed both ways), with a 360-degree lidar of ``rays`` rays."""
    return NavConfig.from_dict({"robot": {"radius": RADIUS, "v_max": 1.0, "omega_max": 2.0}, "action": {"forward_only": False},
                                "lidar": {"n_rays": rays, "n_sectors": rays, "fov_deg": 360.0, "max_range": LIDAR_RANGE}}).sim_params()


def start_poses(b: int, n: int, g: torch.Generator) -> torch.Tensor:
    """``(b, n, 3)`` poses on a jittered grid over the spawn square: cells of at least 0.5 m, jitter
    +-0.12 m, so robots start at least 0.26 m apart; random headings."""
    side = math.ceil(math.sqrt(n))
    cell = 2 * SPAWN / side
    idx = torch.randperm(side * side, generator=g)[:n]
    centre = torch.stack(((idx % side).double(), (idx // side).double()), -1) * cell - SPAWN + cell / 2
    xy = centre + (torch.rand(b, n, 2, generator=g, dtype=torch.float64) * 2 - 1) * min(0.12, cell / 2 - 0.13)
    theta = (torch.rand(b, n, 1, generator=g, dtype=torch.float64) * 2 - 1) * math.pi
    return torch.cat((xy, theta), -1).float()


def torchnav_row(mode: str, b: int, n: int, args: argparse.Namespace) -> dict[str, Any]:
    params = torchnav_params(args.rays)
    g = torch.Generator().manual_seed(args.seed)
    walls = [[-ROOM, -ROOM, ROOM, -ROOM], [ROOM, -ROOM, ROOM, ROOM], [ROOM, ROOM, -ROOM, ROOM], [-ROOM, ROOM, -ROOM, -ROOM]]
    world = make_world(b, segments=walls if args.walls else None, device=args.device)
    rows = robot_world(world, n)  # the static world of every robot row, made once
    robots = make_robots(b, n, device=args.device)
    state = init_robots(start_poses(b, n, g).to(args.device), rows, params, robots)
    u = common.uniform_sampler(g)
    actions = [torch.stack((u(-1.0, 1.0, b, n), u(-2.0, 2.0, b, n)), -1).to(args.device) for _ in range(8)]
    if mode == "compiled":
        torch._dynamo.reset()
    fn = torch.compile(step_robots) if mode == "compiled" else step_robots
    box = {"s": state, "i": 0}

    def call() -> None:
        box["s"] = fn(box["s"], actions[box["i"] % len(actions)], rows, params, robots)
        box["i"] += 1

    compile_s = None
    if mode == "compiled":
        t0 = time.perf_counter()
        for _ in range(2):  # the first call after init_robots and the first after a step compile once each
            call()
        compile_s = round(time.perf_counter() - t0, 2)
    return _timed("torchnav", mode, b, n, call, args, compile_s)


def vmas_row(b: int, n: int, args: argparse.Namespace) -> dict[str, Any]:
    import vmas

    env = vmas.make_env("navigation", num_envs=b, device=args.device, continuous_actions=True, n_agents=n,
                        n_lidar_rays=args.rays, seed=args.seed)
    env.reset()
    g = torch.Generator().manual_seed(args.seed)
    actions = [[(torch.rand(b, 2, generator=g) * 2 - 1).to(args.device) for _ in range(n)] for _ in range(8)]
    box = {"i": 0}

    def call() -> None:
        env.step(actions[box["i"] % len(actions)])
        box["i"] += 1

    return _timed("vmas", "eager", b, n, call, args, None)


def _timed(sim: str, mode: str, b: int, n: int, call, args: argparse.Namespace, compile_s: float | None) -> dict[str, Any]:
    for _ in range(args.warmup):
        call()
    steps = args.steps or common.calibrate(call, args.device, args.run_seconds, lo=2, hi=100_000)
    t = common.time_calls(call, items_per_call=b, steps=steps, repeats=args.repeats, warmup=0, device=args.device)
    return {"bench": "multi_robot", "sim": sim, "mode": mode, "robots": n, "num_envs": b, "rays": args.rays, "walls": args.walls,
            **t.fields(), "agent_steps_per_s": round(t.median * n, 1), "step_us": round(t.call_us, 2), "compile_s": compile_s,
            "steps": steps, "repeats": args.repeats, "device": args.device, "threads": torch.get_num_threads(),
            "clock": "cpu" if args.cpu_time else "wall"}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", type=int, default=4096, help="envs per batch (default 4096)")
    p.add_argument("--robots", default="2,4,8,16", help="robots per env to measure, comma separated (default 2,4,8,16)")
    p.add_argument("--rays", type=int, default=12, help="lidar rays per robot (default 12)")
    p.add_argument("--modes", default="eager,compiled", help="torchnav modes: eager, compiled (default both)")
    p.add_argument("--walls", action="store_true", help="add the 4 walls of a 4 x 4 m room to torchnav's world")
    p.add_argument("--vmas", choices=("auto", "off"), default="auto", help="auto: measure VMAS when `import vmas` works (default)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object per row on stdout (the table goes to stderr)")
    common.timing_args(p, run_seconds=1.0, warmup=3)
    args = p.parse_args(argv)
    args.robots = sorted(int(x) for x in args.robots.split(","))
    args.modes = args.modes.split(",")
    if bad := [m for m in args.modes if m not in ("eager", "compiled")]:
        p.error(f"--modes: unknown mode(s) {bad}; known: eager, compiled")
    if min(args.robots) < 1 or args.envs < 1 or args.rays < 1:
        p.error("--robots, --envs and --rays must be >= 1")
    return args


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    args = parse_args(argv)
    log = common.start(args, f"multi-robot step, {args.envs} envs, {args.rays} rays", args.device, "multi_robot_machine")
    have_vmas = False
    if args.vmas == "auto":
        try:
            import vmas  # noqa: F401

            have_vmas = True
        except ImportError:
            print("   VMAS: not importable here, its rows are skipped (pip install vmas in a separate venv to measure it)", file=log)
    recs = []
    for n in args.robots:
        for mode in args.modes:
            recs.append(torchnav_row(mode, args.envs, n, args))
        if have_vmas:
            recs.append(vmas_row(args.envs, n, args))
    first = {}
    for r in recs:
        first.setdefault((r["sim"], r["mode"]), r["agent_steps_per_s"])  # the smallest N comes first (sorted)
    vmas_rate = {r["robots"]: r["agent_steps_per_s"] for r in recs if r["sim"] == "vmas"}
    table = []
    for r in recs:
        r["per_agent_vs_first"] = round(r["agent_steps_per_s"] / first[(r["sim"], r["mode"])], 3)
        r["over_vmas"] = round(r["agent_steps_per_s"] / vmas_rate[r["robots"]], 2) if r["robots"] in vmas_rate and r["sim"] != "vmas" else None
        if args.json:
            common.emit_json(r)
        table.append([r["sim"], r["mode"], r["robots"], r["num_envs"], common.human_rate(r["env_steps_per_s"]), common.human_rate(r["agent_steps_per_s"]),
                      f"{r['per_agent_vs_first']:.2f}", "-" if r["over_vmas"] is None else f"{r['over_vmas']:.1f}",
                      "-" if r["compile_s"] is None else r["compile_s"], f"{r['steps']} x {r['repeats']}"])
    common.print_table(["sim", "mode", "robots", "envs", "env-steps/s", "agent-steps/s", "per-agent", "x vmas", "compile s", "steps x reps"],
                       table, file=log)
    return recs


if __name__ == "__main__":
    main()
