"""Simulator throughput: env-steps/s of one full ``torchnav.sim.step`` on a standard load.

Load (per env): one robot in a 10 x 10 m walled arena (4 wall segments), 4
oriented boxes and 4 circles placed at random independently in every env, a
20-ray lidar over 180 degrees with 10 m range; random start poses in free
space, random twist commands. The step is kinematics + odometry + collision
(disc clearance) + lidar, exactly ``torchnav.sim.step``.

Modes (``--modes``, comma separated):

* ``eager``             ``torchnav.sim.step`` as is (lidar reduction chosen per obstacle
                        kind by ``raycast.unrolled``: for this load's 4 slots per kind,
                        unrolled from 8,192 rays in the batch, 410 envs, and batched below).
* ``eager-batched``     ``step(..., unroll=False)``: one ``(B, R, N)`` pass per obstacle
                        kind, reduced by ``amin``.
* ``eager-unrolled``    ``step(..., unroll=True)``: a running minimum over the slots (with
                        ``eager-batched``, the two sides of the rule above).
* ``compiled``          ``torch.compile`` of a function that calls ``step``.
* ``compiled-batched``  ``torch.compile`` of the batched composition.
* ``cudagraphs``        CUDA only: ``torch.compile(mode="reduce-overhead")`` of ``step``.

Compile time is excluded from the rates and printed separately. See
docs/performance.md for the method and what each figure means.

    python bench/sim_throughput.py                      # full table, CPU (2 threads) and CUDA if present
    python bench/sim_throughput.py --json               # plus one JSON object per line
    python bench/sim_throughput.py --quick              # seconds-long smoke run (eager modes only)
    python bench/sim_throughput.py --sizes 4096 --modes eager,compiled --stages
    python bench/sim_throughput.py --device cpu --sizes 4096 --modes eager --options imu,camera64,movers4
    python bench/sim_throughput.py --device cpu --threads 1 --cpu-time --sizes 4096 --modes compiled --options pedestrians4
    python bench/sim_throughput.py --device cpu --threads 1 --cpu-time --sizes 64,128,256,512,1024,2048,4096 --modes eager,eager-unrolled,eager-batched

``--options`` adds rows of the same load with one simulator option switched on
(``OPTIONS``: the IMU, the camera's depth row, moving discs and boxes), each next to the plain
step (option ``plain``) in the same run, and prints their throughput relative to it.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402  (sets TORCHINDUCTOR_COMPILE_THREADS before torch is imported)

import torch  # noqa: E402

from torchnav.sim import (  # noqa: E402
    CameraParams,
    EnvParams,
    ImuParams,
    SimParams,
    SimState,
    World,
    apply_limits,
    disc_clearance,
    init_state,
    integrate,
    lidar_scan,
    Movers,
    make_movers,
    make_world,
    planar_world,
    sample_env_params,
    step,
)
from torchnav.sim.step import step_odometry  # noqa: E402
from torchnav.tasks import NavConfig  # noqa: E402

ALL_MODES = ("eager", "eager-batched", "eager-unrolled", "compiled", "compiled-batched", "cudagraphs")
DEFAULT_MODES = ("eager", "eager-batched", "compiled", "compiled-batched", "cudagraphs")
DEFAULT_SIZES = (1, 64, 1024, 4096, 16384)
QUICK_SIZES = (1, 64, 256)
CPU_TARGET = (4096, 1_000_000)  # env-steps/s at 4,096 envs on 2 CPU threads
CUDA_TARGET = 100_000_000  # env-steps/s at the best batch size on one H100

ARENA_HALF = 5.0  # m: the arena spans [-5, 5] x [-5, 5]
N_BOXES, N_CIRCLES = 4, 4
LOAD = "arena 10x10 m, 4 walls + 4 boxes + 4 circles random per env, lidar 20 rays / 180 deg / 10 m"
# The robot and lidar of every row: the navigation task's, driving both ways at up to 0.5 m/s.
ROBOT = NavConfig.from_dict({"robot": {"v_max": 0.5}, "action": {"forward_only": False}}).sim_params()


def _camera(n_cols: int) -> CameraParams:
    """The navigation task's camera, ``n_cols`` wide."""
    return NavConfig.from_dict({"camera": {"enabled": True, "n_cols": n_cols}}).sim_params().camera


# Simulator options benchmarked next to the plain step: name -> (SimParams overrides, moving discs per env).
OPTIONS: dict[str, tuple[dict[str, Any], int | str]] = {
    "plain": ({}, 0),
    "imu": ({"imu": ImuParams()}, 0),  # noise-free: the bench steps without a generator, like the plain rows
    "camera16": ({"camera": _camera(16)}, 0),
    "camera64": ({"camera": _camera(64)}, 0),
    "movers4": ({}, 4),  # 4 discs bouncing inside the arena, seen by lidar and collision
    "boxmovers4": ({}, "boxes"),  # 4 boxes (the discs' rows, their half extents and yaws in Movers.boxes) bouncing inside the arena
    "pedestrians4": ({}, "pedestrians"),  # 4 pedestrians cycling through 4 waypoints, avoiding each other and the robot
    "all": ({"imu": ImuParams(), "camera": _camera(64)}, 4),
    "randomized": ({}, 0),  # per-env EnvParams: limits, 0-2 steps of actuator delay, lidar offset and range, radius
}
# The ranges of the "randomized" option (noise and dropout need a generator, which the bench does not pass).
RANDOMIZE = {"v_max": (0.3, 0.5), "omega_max": (0.5, 1.0), "lin_acc_max": (1.0, 3.0), "ang_acc_max": (2.0, 4.0), "delay": (0, 2),
             "angle_offset": (-0.05, 0.05), "max_range": (6.0, 10.0), "robot_radius": (0.15, 0.25)}


# -- the load ------------------------------------------------------------------------------------


def bench_params(option: str = "plain") -> SimParams:
    return replace(ROBOT, **OPTIONS[option][0])


def make_load(num_envs: int, device: str, seed: int = 0, params: SimParams | None = None, movers: int | str = 0) -> tuple[SimState, World, list[torch.Tensor]]:
    """Initial state, per-env random world and a few batches of random actions for ``num_envs`` envs.

    The world is returned component-major (``planar_world``), converted once as a caller
    stepping a static world would, so ``step`` skips its per-step copy."""
    params = params or bench_params()
    g = torch.Generator().manual_seed(seed)
    b = num_envs
    u = common.uniform_sampler(g)

    h = ARENA_HALF
    walls = [[-h, -h, h, -h], [h, -h, h, h], [h, h, -h, h], [-h, h, -h, -h]]
    base = make_world(b, segments=walls)
    boxes = torch.stack((u(-3.8, 3.8, b, N_BOXES), u(-3.8, 3.8, b, N_BOXES), u(0.2, 0.6, b, N_BOXES), u(0.15, 0.5, b, N_BOXES), u(-math.pi, math.pi, b, N_BOXES)), -1)
    circles = torch.stack((u(-3.8, 3.8, b, N_CIRCLES), u(-3.8, 3.8, b, N_CIRCLES), u(0.15, 0.5, b, N_CIRCLES)), -1)
    world = World(
        segments=base.segments,
        segment_mask=base.segment_mask,
        circles=circles,
        circle_mask=torch.ones(b, N_CIRCLES, dtype=torch.bool),
        boxes=boxes,
        box_mask=torch.ones(b, N_BOXES, dtype=torch.bool),
        batch_size=[b],
    )
    pose = common.free_poses(world, params.robot_radius, h, params.robot_radius + 0.05, u)  # start poses in free space
    actions = common.random_twists(params, u, b)
    world = planar_world(world.to(device))
    discs = None
    if movers:  # random discs bouncing inside the arena (they may start on a robot: the bench does not care)
        m = 4 if movers in ("pedestrians", "boxes") else int(movers)
        rows = torch.stack((u(-3.5, 3.5, b, m), u(-3.5, 3.5, b, m), u(-0.5, 0.5, b, m), u(-0.5, 0.5, b, m), u(0.2, 0.3, b, m)), -1)
        pts = [[[0.0, 0.0]] * 4] * m if movers == "pedestrians" else None
        one, mask, plan, _ = make_movers(1, [[0.0, 0.0, 0.5, 0.0, 0.3]] * m, region=(-h, -h, h, h), waypoints=pts, pedestrians=True)
        plan = torch.zeros(b, m, plan.shape[-1]) + plan  # a fresh tensor, also when empty
        if movers == "pedestrians":  # 4 random waypoints each
            plan[..., 4:] = u(-3.5, 3.5, b, m, 8)
        rows = torch.cat((rows, one[:, :, 5:].expand(b, -1, -1)), -1)
        shapes = torch.zeros(b, 0, 3)
        if movers == "boxes":  # every mover a box: half extents 0.15-0.3 m, any yaw; the radius column is the bounding circle's
            hx, hy = u(0.15, 0.3, b, m), u(0.15, 0.3, b, m)
            rows = torch.cat((rows[..., :4], torch.hypot(hx, hy)[..., None], rows[..., 5:]), -1)
            shapes = torch.stack((hx, hy, u(-math.pi, math.pi, b, m)), -1)
        discs = Movers(rows.to(device), mask.expand(b, -1).contiguous().to(device), plan.to(device), shapes.to(device))
    state = init_state(pose.to(device), world, params, movers=discs)
    return state, world, [a.to(device) for a in actions]


# -- step functions --------------------------------------------------------------------------------


def step_fn(mode: str, params: SimParams, dynamic: bool, env_params: EnvParams | None = None) -> Callable[[SimState, torch.Tensor, World], SimState]:
    unroll = {"eager-batched": False, "compiled-batched": False, "eager-unrolled": True}.get(mode)  # None: the rule's choice

    def fn(state: SimState, action: torch.Tensor, world: World) -> SimState:
        return step(state, action, world, params, unroll=unroll, env_params=env_params)

    if mode.startswith("eager"):
        return fn
    if mode == "cudagraphs":
        graphed = torch.compile(fn, mode="reduce-overhead", dynamic=dynamic)

        def replay(state: SimState, action: torch.Tensor, world: World) -> SimState:
            # A replay overwrites the graph's output buffers, and each step's input is the last
            # step's output: start a new step and copy the state out of the graph's memory pool.
            torch.compiler.cudagraph_mark_step_begin()
            return graphed(state, action, world).clone()

        return replay
    return torch.compile(fn, dynamic=dynamic)


def self_check(device: str) -> None:
    """The batched lidar reduction matches the unrolled one."""
    params = bench_params()
    state, world, actions = make_load(33, device, seed=1)
    ref = step(state, actions[0], world, params, unroll=True)
    batched = step(state, actions[0], world, params, unroll=False)
    torch.testing.assert_close(batched.ranges, ref.ranges, rtol=1e-5, atol=1e-5)


# -- timing ----------------------------------------------------------------------------------------


def bench_rows(mode: str, num_envs: int, device: str, args: argparse.Namespace, options: list[str]) -> list[dict[str, Any]]:
    """One row per option (``"plain"`` first) for ``mode`` at ``num_envs``.

    Each option's step is compiled, warmed up and calibrated on its own; the timed runs
    then take turns (run 1 of every option, then run 2, ...), so that a machine shared
    with other work slows every option alike and the ratios between rows hold."""
    rows = []
    # Every option's step is one more graph of the same function (two with the actuator delay's strides).
    torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, 2 * len(options) + 2)
    for option in options:
        params = bench_params(option)
        state, world, actions = make_load(num_envs, device, seed=args.seed, params=params, movers=OPTIONS[option][1])
        env_params = None
        if option == "randomized":
            env_params = sample_env_params(RANDOMIZE, params, num_envs, torch.Generator().manual_seed(args.seed), state.pose)
            state = init_state(state.pose, world, params, env_params=env_params, delay_steps=2)
        rec: dict[str, Any] = {
            "bench": "sim_throughput", "device": device, "num_envs": num_envs, "mode": mode, "option": option,
            "env_steps_per_s": None, "env_steps_per_s_min": None, "env_steps_per_s_max": None, "step_us": None,
            "compile_s": None, "peak_mem_bytes": None, "peak_mem_method": None,
            "steps": None, "repeats": args.repeats, "threads": torch.get_num_threads(), "load": LOAD,
            "clock": "cpu" if args.cpu_time else "wall",
        }
        compiled = mode.startswith("compiled") or mode == "cudagraphs"
        if compiled and option == options[0] and (not args.dynamic or num_envs == args.sizes[0]):
            # Static shapes: a fresh compile per (mode, size). Not per option: the options' steps share
            # one code object, so a reset here would drop the earlier options' graphs, which would then
            # recompile inside the first timed run (and past dynamo's limit, run eager).
            torch._dynamo.reset()
        fn = step_fn(mode, params, args.dynamic, env_params)
        box = {"s": state, "i": 0}

        def call(fn=fn, box=box, actions=actions, world=world) -> None:
            if mode == "cudagraphs":
                torch.compiler.cudagraph_mark_step_begin()
            box["s"] = fn(box["s"], actions[box["i"] % len(actions)], world)
            box["i"] += 1

        try:
            if not mode.startswith("eager"):
                t0 = time.perf_counter()
                call()  # compiles
                for _ in range(2):  # cudagraphs records on the first calls after compilation
                    call()
                common.sync(device)
                rec["compile_s"] = round(time.perf_counter() - t0, 2)
            for _ in range(args.warmup):
                call()
            steps = args.steps or common.calibrate(call, device, args.run_seconds, lo=3, hi=100_000)
            rows.append((rec, call, common.Timing(items_per_call=num_envs, steps=steps), fn, box, actions, world, params, env_params))
        except Exception as e:  # noqa: BLE001 - one failing mode must not end the table
            rec["error"] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"[:300]
            rows.append((rec, None, None, fn, box, actions, world, params, env_params))
    for _ in range(args.repeats):  # interleaved timed runs
        for rec, call, t, *_ in rows:
            if call is None or rec.get("error"):
                continue
            try:
                t.seconds += common.time_calls(call, items_per_call=num_envs, steps=t.steps, repeats=1, warmup=0, device=device).seconds
            except Exception as e:  # noqa: BLE001
                rec["error"] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"[:300]
    out = []
    for rec, call, t, fn, box, actions, world, params, env_params in rows:
        if call is not None and not rec.get("error"):
            try:
                with common.PeakMemory(device) as mem:
                    for _ in range(3):
                        call()
                rec.update(
                    **t.fields(), step_us=round(t.call_us, 2), steps=t.steps, peak_mem_bytes=mem.bytes, peak_mem_method=mem.method,
                )
                if not torch.isfinite(box["s"].pose).all():
                    rec["error"] = "non-finite pose after the timed steps"
                elif not mode.startswith("eager"):
                    rec.update(_check_against_eager(fn, mode, box["s"], actions[0], world, params, env_params))
            except Exception as e:  # noqa: BLE001
                rec["error"] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"[:300]
        out.append(rec)
    return out


def _check_against_eager(fn, mode: str, state: SimState, action: torch.Tensor, world: World, params: SimParams,
                         env_params: EnvParams | None = None) -> dict[str, Any]:
    """One step of the compiled ``fn`` against eager ``step`` from the same state (after the timed steps).

    Float32 op reordering moves poses by ~1e-6 m; a ray grazing an obstacle edge may flip
    between hit and miss, so ranges are compared as the fraction of rays off by > 1 mm.
    """
    state = state.clone()  # cudagraphs: the carried state lives in memory the next replay overwrites
    ref = step(state, action, world, params, env_params=env_params)
    if mode == "cudagraphs":
        torch.compiler.cudagraph_mark_step_begin()
    got = fn(state, action, world).clone()
    d = got.pose - ref.pose
    d = torch.cat((d[:, :2], torch.remainder(d[:, 2:] + math.pi, 2 * math.pi) - math.pi), -1)  # heading wraps at +-pi
    pose_err = float(d.abs().max())
    frac = float(((got.ranges - ref.ranges).abs() > 1e-3).float().mean())
    out: dict[str, Any] = {"check_pose_err": pose_err, "check_ranges_mismatch_frac": frac}
    if not (pose_err <= 1e-3 and frac <= 1e-3):
        out["error"] = f"{mode} disagrees with eager step: max pose error {pose_err:.2e}, rays off by > 1 mm {frac:.2%}"
    return out


# -- stage breakdown ---------------------------------------------------------------------------------


def stage_breakdown(num_envs: int, device: str, args: argparse.Namespace, compiled: bool) -> list[dict[str, Any]]:
    """Median time per call of each stage of the step at ``num_envs``, eager (and compiled)."""
    params = bench_params()
    state, world, actions = make_load(num_envs, device, seed=args.seed)
    a = actions[0]
    nxt = step(state, a, world, params)
    stages: dict[str, Callable[[], Any]] = {
        "kinematics (limits, pose, odometry)": lambda: (lambda v: (integrate(state.pose, v, params), step_odometry(state.odom, v, params, None)))(apply_limits(a, state.vel, params)),
        "collision (disc_clearance)": lambda: disc_clearance(nxt.pose, world, params.robot_radius),
        "lidar unroll=True": lambda: lidar_scan(nxt.pose, world, params.lidar, unroll=True),
        "lidar unroll=False": lambda: lidar_scan(nxt.pose, world, params.lidar, unroll=False),
        "full step": lambda: step(state, a, world, params),
    }
    out = []
    for variant in ("eager", "compiled") if compiled else ("eager",):
        for name, f in stages.items():
            compile_s = None
            if variant == "compiled":
                torch._dynamo.reset()
                f = torch.compile(f, dynamic=args.dynamic)
                t0 = time.perf_counter()
                f()
                common.sync(device)
                compile_s = round(time.perf_counter() - t0, 2)
            for _ in range(args.warmup):
                f()
            steps = args.steps or common.calibrate(f, device, args.run_seconds / 2, lo=3, hi=100_000)
            t = common.time_calls(f, items_per_call=num_envs, steps=steps, repeats=args.repeats, warmup=0, device=device)
            out.append({"bench": "sim_stages", "device": device, "num_envs": num_envs, "mode": variant, "stage": name,
                        "call_us": round(t.call_us, 2), "env_steps_per_s": round(t.median, 1), "compile_s": compile_s})
    return out


# -- main ----------------------------------------------------------------------------------------------


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=lambda s: [int(x) for x in s.split(",")], default=None, help=f"comma-separated env counts (default {','.join(map(str, DEFAULT_SIZES))})")
    p.add_argument("--modes", type=lambda s: s.split(","), default=None, help=f"comma-separated, from {','.join(ALL_MODES)} (default: all; cudagraphs on CUDA only)")
    p.add_argument("--device", default="all", help="cpu, cuda, or all (cpu and, when present, cuda); default all")
    common.timing_args(p, run_seconds=0.4)
    p.add_argument("--dynamic", action=argparse.BooleanOptionalAction, default=False, help="torch.compile(dynamic=...) (default: static shapes, one compile per size)")
    p.add_argument("--stages", action="store_true", help="also time each stage of the step (at 4096 envs or the largest size below)")
    p.add_argument("--options", type=lambda s: [x for x in s.split(",") if x], default=None,
                   help=f"comma-separated simulator options to time next to the plain step, from {','.join(o for o in OPTIONS if o != 'plain')}")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object per line as well as the tables")
    p.add_argument("--quick", action="store_true", help="tiny sizes, few steps, eager modes only: a smoke test")
    args = p.parse_args(argv)
    if args.quick:
        args.sizes = args.sizes or list(QUICK_SIZES)
        args.modes = args.modes or ["eager", "eager-batched"]
        args.steps = args.steps or 5
        args.repeats = min(args.repeats, 3)
        args.warmup = min(args.warmup, 2)
    args.sizes = args.sizes or list(DEFAULT_SIZES)
    args.modes = args.modes or list(DEFAULT_MODES)
    bad = [m for m in args.modes if m not in ALL_MODES]
    if bad:
        p.error(f"unknown mode(s) {bad}; choose from {ALL_MODES}")
    bad = [o for o in args.options or [] if o not in OPTIONS]
    if bad:
        p.error(f"unknown option(s) {bad}; choose from {tuple(OPTIONS)}")
    args.options = ["plain"] + [o for o in args.options or [] if o != "plain"]
    return args


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    args = parse_args(argv)
    common.set_threads(args.threads)
    if args.cpu_time:
        common.CLOCK = time.process_time
    records: list[dict[str, Any]] = []
    log = sys.stderr if args.json else sys.stdout  # with --json, stdout holds only JSON lines
    for device in common.resolve_devices(args.device):
        modes = [m for m in args.modes if m != "cudagraphs" or device.startswith("cuda")]
        common.print_header(f"sim_throughput on {device}: {LOAD}" + (" (rates in CPU time: --cpu-time)" if args.cpu_time else ""), device, log,
                            "sim_machine" if args.json else None)
        self_check(device)
        rows, dev_records = [], []
        for n in args.sizes:
            for mode in modes:
                for rec in bench_rows(mode, n, device, args, args.options):
                    option = rec["option"]
                    dev_records.append(rec)
                    if args.json:
                        common.emit_json(rec)
                    rows.append(_row(rec))
                    print(f"   {mode:>16} {option:>9} {n:>6} envs: " + (rec.get("error") or f"{common.human_rate(rec['env_steps_per_s'])} env-steps/s"), file=sys.stderr, flush=True)
        print(file=log)
        common.print_table(["mode", "option", "envs", "env-steps/s", "min", "max", "us/step", "compile s", "peak mem", "steps x reps"], rows, file=log)
        print(f"   peak mem: {dev_records[0]['peak_mem_method'] or 'n/a'} (over the 3 steps after timing)", file=log)
        plain = [r for r in dev_records if r["option"] == "plain"]
        _ratios(plain, device, log)
        _option_ratios(dev_records, log)
        records += dev_records
        if args.stages:
            n = max([s for s in args.sizes if s <= 4096] or [min(args.sizes)])
            compiled = any(m.startswith("compiled") for m in modes)
            st = stage_breakdown(n, device, args, compiled)
            full = {r["mode"]: r["call_us"] for r in st if r["stage"] == "full step"}
            print(f"\n   stage breakdown at {n} envs on {device} (median us per call; % of the full step of the same variant)", file=log)
            common.print_table(
                ["variant", "stage", "us/call", "% of step", "compile s"],
                [[r["mode"], r["stage"], f"{r['call_us']:.1f}", f"{100 * r['call_us'] / full[r['mode']]:.0f}%", r["compile_s"] if r["compile_s"] is not None else "-"] for r in st],
                file=log,
            )
            if args.json:
                for r in st:
                    common.emit_json(r)
            records += st
    return records


def _option_ratios(records: list[dict[str, Any]], log) -> None:
    """Throughput of each option relative to the plain step of the same mode and size (same run)."""
    ok = [r for r in records if not r.get("error")]
    rate = {(r["mode"], r["num_envs"], r["option"]): r["env_steps_per_s"] for r in ok}
    lines = []
    for (mode, n, option), v in rate.items():
        base = rate.get((mode, n, "plain"))
        if option != "plain" and base:
            lines.append(f"   {mode:>16} {n:>6} envs: {option:>9} x{v / base:.2f} of plain (step cost x{base / v:.2f})")
    if lines:
        print("\n   options against the plain step at the same mode and size (same run):", file=log)
        for line in lines:
            print(line, file=log)


def _row(rec: dict[str, Any]) -> list[Any]:
    if rec.get("error"):
        return [rec["mode"], rec["option"], rec["num_envs"], "ERROR", rec["error"][:60], "", "", "", "", ""]
    return [
        rec["mode"], rec["option"], rec["num_envs"], common.human_rate(rec["env_steps_per_s"]), common.human_rate(rec["env_steps_per_s_min"]),
        common.human_rate(rec["env_steps_per_s_max"]), f"{rec['step_us']:.1f}", rec["compile_s"] if rec["compile_s"] is not None else "-",
        common.human_bytes(rec["peak_mem_bytes"]), f"{rec['steps']}x{rec['repeats']}",
    ]


def _ratios(records: list[dict[str, Any]], device: str, log) -> None:
    ok = [r for r in records if not r.get("error")]
    rate = {(r["mode"], r["num_envs"]): r["env_steps_per_s"] for r in ok}
    print("\n   ratios against eager at the same size (same run):", file=log)
    for n in sorted({r["num_envs"] for r in ok}):
        base = rate.get(("eager", n))
        if not base:
            continue
        parts = [f"{m} x{rate[(m, n)] / base:.2f}" for m in ALL_MODES if m != "eager" and (m, n) in rate]
        print(f"   {n:>6} envs: " + (", ".join(parts) or "(eager only)"), file=log)
    if not ok:
        return
    if device.startswith("cuda"):
        best = max(ok, key=lambda r: r["env_steps_per_s"])
        print(f"   target (>= {common.human_rate(CUDA_TARGET)} env-steps/s at the best size on one GPU): best {common.human_rate(best['env_steps_per_s'])} "
              f"({best['mode']}, {best['num_envs']} envs) = x{best['env_steps_per_s'] / CUDA_TARGET:.2f} of target", file=log)
    else:
        n, target = CPU_TARGET
        at = [r for r in ok if r["num_envs"] == n]
        if at:
            best = max(at, key=lambda r: r["env_steps_per_s"])
            print(f"   target (>= {common.human_rate(target)} env-steps/s at {n} envs, {torch.get_num_threads()} threads): best {common.human_rate(best['env_steps_per_s'])} "
                  f"({best['mode']}) = x{best['env_steps_per_s'] / target:.2f} of target", file=log)
        else:
            print(f"   target (>= {common.human_rate(target)} env-steps/s at {n} envs): not measured in this run", file=log)


if __name__ == "__main__":
    main()
