"""A big static map held once for the batch, next to ``arena`` in the same run.

The map: a 50 x 30 m warehouse floor plan at 0.03 m/pixel, drawn procedurally (shelf rows, walls and
a scatter of small blobs, as an occupancy image from SLAM looks) and written as a ROS map_server map
(PGM + YAML) into a temporary folder; torchnav loads it as it is and turns its occupied pixels into a
few thousand boxes. Figures, per map and number of envs:

* ``build``      seconds to build ``NavEnv`` and reset it, and the peak memory of doing so (compiled: the
                 reset's first scans compile the march steps, once per process);
* ``raw-sim``    ``torchnav.sim.step`` alone on the env's worlds, poses and shared map (random twists),
                 eager and compiled (``torch.compile``; compile time is never in a rate);
* ``env-step``   ``env.step_and_maybe_reset`` with random actions, ``NavEnv(compile_step=True)`` and eager,
                 and the fraction of envs reset per step (``reset_fraction``, over every step it ran);
* the bytes of the shared map (the same for any number of envs) and of the per-env worlds.

Targets (4,096 envs, compiled, same run): on the big map raw-sim >= 500,000 and env-step >= 100,000
env-steps/s, each within 5x of arena's; the map held once; an env built in under 3 s.

    python bench/big_map.py                 # 64, 1,024 and 4,096 envs, eager and compiled
    python bench/big_map.py --json          # plus one JSON object per line (tables on stderr)
    python bench/big_map.py --quick         # 64 envs, eager, a few steps: a smoke run
    python bench/big_map.py --hold-memory   # malloc keeps freed memory (torchnav.memory.hold_freed_memory())
    python bench/big_map.py --write-map DIR # only write the map (DIR/big_warehouse.yaml + .pgm) and exit
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402  (sets TORCHINDUCTOR_COMPILE_THREADS before torch is imported)

import numpy as np  # noqa: E402
import torch  # noqa: E402

from torchnav.envs import NavEnv  # noqa: E402
from torchnav.sim import step  # noqa: E402
from torchnav.tasks import NavConfig  # noqa: E402

TARGET_RAW, TARGET_ENV, TARGET_RATIO, TARGET_BUILD_S = 500_000, 100_000, 5.0, 3.0
SIZE, RESOLUTION = (50.0, 30.0), 0.03  # m, m/pixel


def warehouse_mask(seed: int = 0) -> np.ndarray:
    """``(H, W)`` bool occupancy of the bench's warehouse (row 0 at the top): outer walls, rows of
    7 x 1 m shelves with 2 m aisles, two partition walls with doors, and 2,500 small blobs."""
    rng = np.random.default_rng(seed)
    w, h = int(round(SIZE[0] / RESOLUTION)), int(round(SIZE[1] / RESOLUTION))
    m = np.zeros((h, w), dtype=bool)
    px = lambda v: int(round(v / RESOLUTION))  # noqa: E731
    t = px(0.15)
    m[:t], m[-t:], m[:, :t], m[:, -t:] = True, True, True, True
    for x in (17.0, 34.0):  # partitions with two 1.5 m doors each
        m[:, px(x):px(x) + t] = True
        for y in (7.0, 22.0):
            m[px(y):px(y + 1.5), px(x):px(x) + t] = False
    for y0 in np.arange(2.5, SIZE[1] - 3.0, 3.0):  # shelf rows
        for x0 in np.arange(1.5, SIZE[0] - 8.0, 8.5):
            m[px(SIZE[1] - y0 - 1.0):px(SIZE[1] - y0), px(x0):px(x0 + 7.0)] = True
    for _ in range(2500):  # pallets, bins and SLAM speckle
        r, c = rng.integers(0, h), rng.integers(0, w)
        a, b = rng.integers(1, 8, size=2)
        m[max(0, r - b):r + b, max(0, c - a):c + a] = True
    return m


def write_map(folder: Path) -> Path:
    """The warehouse as a map_server map (trinary PGM, 0 occupied, 254 free): returns its YAML's path."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.where(warehouse_mask(), 0, 254).astype(np.uint8)).save(folder / "big_warehouse.pgm")
    yaml = folder / "big_warehouse.yaml"
    yaml.write_text(f"image: big_warehouse.pgm\nmode: trinary\nresolution: {RESOLUTION}\norigin: [0.0, 0.0, 0.0]\n"
                    "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return yaml


def _world_bytes(w) -> int:
    return sum(t.numel() * t.element_size() for t in (w.segments, w.circles, w.boxes, w.segment_mask, w.circle_mask, w.box_mask))


def _rec(args, map_name: str, n: int, mode: str, compiled: bool, **fields: Any) -> dict[str, Any]:
    return {"bench": "big_map", "device": args.device, "map": map_name, "num_envs": n, "mode": mode, "compiled": compiled,
            "threads": torch.get_num_threads(), **fields}


def bench_cell(args, map_path: str, map_name: str, n: int, compiled: bool) -> list[dict[str, Any]]:
    cfg = NavConfig.from_dict({"map": map_path})
    with common.PeakMemory(args.device) as mem:
        t0 = time.perf_counter()
        env = NavEnv(cfg, num_envs=n, device=args.device, seed=args.seed, compile_step=compiled)
        env.reset()
        build_s = time.perf_counter() - t0
    task, s = env.task, env.state
    static = task.static
    out = [_rec(args, map_name, n, "build", compiled, seconds=round(build_s, 3), peak_mem_bytes=mem.bytes,
                fixed_obstacles=task.spec.n_fixed, shared_map_bytes=static.nbytes() if static is not None else 0,
                shared_map_slots={k: v.slots for k, v in static.lists.items()} if static is not None else None, per_env_world_bytes=_world_bytes(s.world) // n)]

    g = torch.Generator(device=args.device).manual_seed(args.seed)
    twists = [task.command(2 * torch.rand(n, 2, generator=g, device=args.device) - 1) for _ in range(8)]
    fn = torch.compile(step) if compiled else step
    box = {"s": s.sim, "i": 0}

    def raw() -> None:
        box["s"] = fn(box["s"], twists[box["i"] % 8], s.world, task.params, static=static)
        box["i"] += 1

    actions = [env.action_spec.rand() for _ in range(8)]
    tds = {"td": env.reset(), "i": 0, "ended": torch.zeros((), dtype=torch.int64, device=args.device)}

    def env_step() -> None:
        td = tds["td"]
        td.set("action", actions[tds["i"] % 8])
        out, tds["td"] = env.step_and_maybe_reset(td)
        tds["ended"] += out["next", "done"].sum()  # episodes ended, so envs reset (read once, at the end)
        tds["i"] += 1

    for mode, call in (("raw-sim", raw), ("env-step", env_step)):
        t0 = time.perf_counter()
        call()  # compiles on the first call when compiled
        common.sync(args.device)
        first_s = time.perf_counter() - t0
        steps = args.steps or common.calibrate(call, args.device, args.run_seconds, lo=2, hi=2000)
        with common.PeakMemory(args.device) as mem:
            t = common.time_calls(call, items_per_call=n, steps=steps, repeats=args.repeats, warmup=args.warmup, device=args.device)
        extra = {"reset_fraction": round(int(tds["ended"]) / (tds["i"] * n), 4)} if mode == "env-step" else {}
        out.append(_rec(args, map_name, n, mode, compiled, **t.fields(), step_ms=round(1e3 * t.call_us / 1e6, 3), steps=steps,
                        repeats=len(t.seconds), first_call_s=round(first_s, 2), peak_mem_bytes=mem.bytes, **extra))
    env.close()
    return out


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", type=int, nargs="+", default=[64, 1024, 4096], help="numbers of envs (default 64 1024 4096)")
    p.add_argument("--compiled-envs", type=int, nargs="*", default=[4096], help="of those, run compiled too (default 4096)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object per line on stdout (tables go to stderr)")
    p.add_argument("--quick", action="store_true", help="64 envs, eager, few steps: a smoke run")
    p.add_argument("--write-map", type=Path, default=None, help="write the bench's map into this folder and exit")
    common.timing_args(p, run_seconds=1.0, warmup=2)
    args = p.parse_args(argv)
    if args.quick:
        args.envs, args.compiled_envs, args.steps, args.repeats, args.warmup = [64], [], 2, 1, 1
    bad = [n for n in args.envs + args.compiled_envs if n < 1]
    if bad:
        p.error(f"numbers of envs must be >= 1, got {bad}")
    return args


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    args = parse_args(argv)
    if args.write_map is not None:
        print(write_map(args.write_map))
        return []
    log = common.start(args, "big_map: a 50 x 30 m map_server warehouse at 0.03 m/pixel next to arena", args.device, "big_map_machine")
    records: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        big = str(write_map(Path(tmp)))
        for n in args.envs:
            for compiled in (False, True) if n in args.compiled_envs else (False,):
                for path, name in (("arena", "arena"), (big, "big_warehouse")):
                    for rec in bench_cell(args, path, name, n, compiled):
                        records.append(rec)
                        if args.json:
                            common.emit_json(rec)
                    print(f"   {name} {n} envs {'compiled' if compiled else 'eager'}: " + ", ".join(
                        f"{r['mode']} {common.human_rate(r['env_steps_per_s'])}/s"
                        + (f" ({100 * r['reset_fraction']:.1f}% of envs reset a step)" if "reset_fraction" in r else "")
                        for r in records[-3:] if "env_steps_per_s" in r), file=log, flush=True)
    rows = []
    for r in records:
        rate = common.human_rate(r["env_steps_per_s"]) if "env_steps_per_s" in r else f"{r['seconds']:.2f} s"
        rows.append([r["map"], r["num_envs"], r["mode"], "compiled" if r["compiled"] else "eager", rate, common.human_bytes(r["peak_mem_bytes"])])
    print(file=log)
    common.print_table(["map", "envs", "mode", "step", "env-steps/s (build: time)", "peak mem"], rows, file=log)
    built = [r for r in records if r["mode"] == "build" and r["map"] == "big_warehouse"]
    if built:
        b = built[-1]
        print(f"\n   big_warehouse: {b['fixed_obstacles']:,} fixed obstacles, shared map {common.human_bytes(b['shared_map_bytes'])} "
              f"(slots per env {b['shared_map_slots']}), per-env world {common.human_bytes(b['per_env_world_bytes'])}", file=log)
    summary = {"bench": "big_map_targets", "device": args.device}
    for mode, target in (("raw-sim", TARGET_RAW), ("env-step", TARGET_ENV)):
        pick = {r["map"]: r["env_steps_per_s"] for r in records if r["mode"] == mode and r["compiled"] and r["num_envs"] == 4096}
        if len(pick) == 2:
            ratio = pick["arena"] / pick["big_warehouse"]
            summary[mode] = {"big_warehouse": pick["big_warehouse"], "arena": pick["arena"], "arena_over_big": round(ratio, 2), "target": target}
            verdict = "meets" if pick["big_warehouse"] >= target and ratio <= TARGET_RATIO else "misses"
            print(f"   {mode}, 4,096 envs compiled: big_warehouse {common.human_rate(pick['big_warehouse'])}/s, arena {common.human_rate(pick['arena'])}/s "
                  f"({ratio:.1f}x); target >= {common.human_rate(target)}/s and within {TARGET_RATIO:g}x of arena: {verdict} it", file=log)
    builds = [r["seconds"] for r in built if not r["compiled"]]
    if builds:  # a compiled env's build also compiles the march its first reset runs (once per process, cached across them)
        summary["build_s_max"] = max(builds)
        compiled = [r["seconds"] for r in built if r["compiled"]]
        print(f"   building an env on big_warehouse: at most {max(builds):.2f} s (target < {TARGET_BUILD_S:g} s)"
              + (f"; compiled, with its first reset's compile: {max(compiled):.2f} s" if compiled else ""), file=log)
    if args.json:
        common.emit_json(summary)
    return records + [summary]


if __name__ == "__main__":
    main()
