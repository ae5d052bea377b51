"""Task throughput: the navigation env through TorchRL next to the raw simulator step on the same load.

Three figures, all in env-steps/s (one env advanced by one step = 1), on the
same env (map ``arena`` by default, 4,096 envs, 2 CPU threads):

* ``raw-sim``    ``torchnav.sim.step`` alone on the env's own world and robot poses
                 (the task's ``SimParams``, random twists): the ceiling.
* ``env-step``   ``env.step_and_maybe_reset`` in a loop with random actions: the
                 simulator plus task (observation, reward terms, termination,
                 episode statistics), TorchRL's TensorDict plumbing and partial resets.
* ``collector``  ``torchrl.collectors.Collector(env, policy=None)`` (a random
                 policy) with ``frames_per_batch = num_envs * k``: what a training
                 loop sees. The first batch is warm-up and not timed.
* ``gym-vector`` ``torchnav.gym.TorchnavVectorEnv`` over the same env, stepped with
                 random numpy actions (SAME_STEP autoreset): what a Gymnasium or
                 Stable-Baselines3 user sees, numpy conversions included. Skipped
                 when gymnasium is not installed.

Target: the full task keeps at least half of the raw simulator throughput
(``collector / raw-sim >= 0.5``).

    python bench/env_throughput.py                 # 4,096 envs on arena, CPU, 2 threads
    python bench/env_throughput.py --json          # plus one JSON object per line (tables on stderr)
    python bench/env_throughput.py --quick         # seconds-long smoke run
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402  (sets TORCHINDUCTOR_COMPILE_THREADS before torch is imported)

import torch  # noqa: E402
from torchrl.collectors import Collector  # noqa: E402

from torchnav.envs import make_nav_env  # noqa: E402
from torchnav.sim import step  # noqa: E402

TARGET_RATIO = 0.5


def _record(mode: str, args: argparse.Namespace, t: common.Timing | None, mem: common.PeakMemory | None, **extra: Any) -> dict[str, Any]:
    rec: dict[str, Any] = {
        "bench": "env_throughput", "device": args.device, "num_envs": args.num_envs, "mode": mode, "map": args.map,
        "env_steps_per_s": None, "env_steps_per_s_min": None, "env_steps_per_s_max": None, "step_us": None,
        "peak_mem_bytes": None, "peak_mem_method": None, "threads": torch.get_num_threads(),
    }
    if t is not None:
        rec.update(**t.fields(),
                   step_us=round(t.call_us, 2), steps=t.steps, repeats=len(t.seconds))
    if mem is not None:
        rec.update(peak_mem_bytes=mem.bytes, peak_mem_method=mem.method)
    rec.update(extra)
    return rec


def _steps(args: argparse.Namespace, call, device: str) -> int:
    return args.steps or common.calibrate(call, device, args.run_seconds, lo=3, hi=10_000)


def bench_raw(env, args: argparse.Namespace) -> dict[str, Any]:
    """``sim.step`` on the env's world and poses, with the task's params and random twists."""
    g = torch.Generator(device=args.device).manual_seed(args.seed)
    s = env.state
    world, params = s.world, env.task.params
    actions = [env.task.command(2 * torch.rand(args.num_envs, 2, generator=g, device=args.device) - 1) for _ in range(8)]
    box = {"s": s.sim, "i": 0}

    def call() -> None:
        box["s"] = step(box["s"], actions[box["i"] % len(actions)], world, params)
        box["i"] += 1

    for _ in range(args.warmup):
        call()
    t = common.time_calls(call, items_per_call=args.num_envs, steps=_steps(args, call, args.device), repeats=args.repeats, warmup=0, device=args.device)
    with common.PeakMemory(args.device) as mem:
        for _ in range(3):
            call()
    n_obs = {k: int(getattr(world, m)[0].sum()) for k, m in (("segments", "segment_mask"), ("circles", "circle_mask"), ("boxes", "box_mask"))}
    return _record("raw-sim", args, t, mem, obstacles_env0=n_obs, n_rays=params.lidar.n_rays)


def bench_env_step(env, args: argparse.Namespace) -> dict[str, Any]:
    """``env.step_and_maybe_reset`` with random actions, partial resets included."""
    acts = [env.action_spec.rand() for _ in range(8)]
    box: dict[str, Any] = {"td": env.reset(), "i": 0, "done": torch.zeros((), dtype=torch.int64, device=args.device)}

    def call() -> None:
        td = box["td"]
        td.set("action", acts[box["i"] % len(acts)])
        out, box["td"] = env.step_and_maybe_reset(td)
        box["done"] += out.get(("next", "done")).sum()
        box["i"] += 1

    for _ in range(args.warmup):
        call()
    steps = _steps(args, call, args.device)
    box["done"].zero_()
    box["i"] = 0
    t = common.time_calls(call, items_per_call=args.num_envs, steps=steps, repeats=args.repeats, warmup=0, device=args.device)
    resets = int(box["done"]) / max(1, box["i"] * args.num_envs)
    with common.PeakMemory(args.device) as mem:
        for _ in range(3):
            call()
    return _record("env-step", args, t, mem, reset_fraction=round(resets, 4))


def bench_collector(env, args: argparse.Namespace) -> dict[str, Any]:
    """Frames/s of a TorchRL ``Collector`` with a random policy; each batch is one timed run."""
    fpb = args.num_envs * args.batch_steps
    n_batches = args.repeats + 1  # the first batch is warm-up
    collector = Collector(env, policy=None, frames_per_batch=fpb, total_frames=fpb * n_batches)
    seconds: list[float] = []
    frames: list[int] = []
    done = 0
    try:
        with common.PeakMemory(args.device) as mem:
            t0 = common.CLOCK()
            for i, batch in enumerate(collector):
                common.sync(args.device)
                t1 = common.CLOCK()
                if i > 0:
                    seconds.append(t1 - t0)
                    frames.append(batch.numel())
                    done += int(batch.get(("next", "done")).sum())
                t0 = common.CLOCK()
    finally:
        collector.shutdown()
    t = common.Timing(items_per_call=fpb, steps=1, seconds=seconds)
    rates = [f / s for f, s in zip(frames, seconds)]
    rec = _record("collector", args, t, mem, frames_per_batch=fpb, batch_s=round(statistics.median(seconds), 4),
                  reset_fraction=round(done / max(1, sum(frames)), 4))
    rec.update(**common.rate_fields(rates),
               step_us=round(1e6 * statistics.median(seconds) / args.batch_steps, 2), steps=args.batch_steps, repeats=len(seconds),
               peak_mem_note="whole collection incl. the frames_per_batch output buffers")
    return rec


def bench_gym_vector(env, args: argparse.Namespace) -> dict[str, Any] | None:
    """``TorchnavVectorEnv.step`` with random numpy actions, autoresets included."""
    try:
        from torchnav.gym import TorchnavVectorEnv
    except ImportError:
        print("   gym-vector: skipped (gymnasium is not installed: pip install -e '.[gym]')", file=sys.stderr)
        return None
    vec = TorchnavVectorEnv(env)
    vec.reset(seed=args.seed)
    rng = __import__("numpy").random.default_rng(args.seed)
    acts = [vec.action_space.sample() if env.cfg.action.mode == "discrete" else rng.uniform(-1, 1, (args.num_envs, 2)).astype("float32") for _ in range(8)]
    box = {"i": 0, "done": 0}

    def call() -> None:
        _, _, term, trunc, _ = vec.step(acts[box["i"] % len(acts)])
        box["done"] += int((term | trunc).sum())
        box["i"] += 1

    for _ in range(args.warmup):
        call()
    steps = _steps(args, call, args.device)
    box["done"], box["i"] = 0, 0
    t = common.time_calls(call, items_per_call=args.num_envs, steps=steps, repeats=args.repeats, warmup=0, device=args.device)
    with common.PeakMemory(args.device) as mem:
        for _ in range(3):
            call()
    return _record("gym-vector", args, t, mem, reset_fraction=round(box["done"] / max(1, box["i"] * args.num_envs), 4))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--num-envs", type=int, default=4096, help="envs in the batch (default 4096)")
    p.add_argument("--map", default="arena", help="shipped map name or YAML path (default arena)")
    p.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    common.timing_args(p, run_seconds=0.5)
    p.add_argument("--batch-steps", type=int, default=8, help="collector frames_per_batch = num_envs * this (default 8)")
    p.add_argument("--pool", type=int, default=0, help="reset.pool of the env: episodes pre-sampled per refill (default 0: exact resets)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object per line on stdout (tables go to stderr)")
    p.add_argument("--quick", action="store_true", help="64 envs, few steps: a smoke test")
    args = p.parse_args(argv)
    if args.quick:
        if args.num_envs == 4096:
            args.num_envs = 64
        args.steps = args.steps or 5
        args.repeats = min(args.repeats, 3)
        args.warmup = min(args.warmup, 2)
        args.batch_steps = min(args.batch_steps, 4)
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        p.error(f"--device {args.device}: no CUDA device is available")
    return args


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    args = parse_args(argv)
    log = common.start(args, f"env_throughput: map {args.map}, {args.num_envs} envs on {args.device}", args.device, "env_machine")
    env = make_nav_env(args.map, num_envs=args.num_envs, device=args.device, seed=args.seed, reset={"pool": args.pool})
    env.reset()
    records = []
    for fn in (bench_raw, bench_env_step, bench_collector, bench_gym_vector):
        rec = fn(env, args)
        if rec is None:
            continue
        records.append(rec)
        if args.json:
            common.emit_json(rec)
        print(f"   {rec['mode']:>10}: {common.human_rate(rec['env_steps_per_s'])} env-steps/s", file=sys.stderr, flush=True)
    env.close()
    rows = [[r["mode"], common.human_rate(r["env_steps_per_s"]), common.human_rate(r["env_steps_per_s_min"]), common.human_rate(r["env_steps_per_s_max"]),
             f"{r['step_us']:.1f}", common.human_bytes(r["peak_mem_bytes"]), r.get("reset_fraction", "-"), f"{r['steps']}x{r['repeats']}"] for r in records]
    print(file=log)
    common.print_table(["mode", "env-steps/s", "min", "max", "us/step", "peak mem", "resets/env-step", "steps x reps"], rows, file=log)
    print(f"   peak mem: {records[0]['peak_mem_method']}; collector row: the whole collection, output buffers included", file=log)
    raw, st, col = (r["env_steps_per_s"] for r in records[:3])
    ratio = {"bench": "env_ratio", "device": args.device, "num_envs": args.num_envs, "map": args.map,
             "env_step_over_raw": round(st / raw, 3), "collector_over_raw": round(col / raw, 3), "collector_over_env_step": round(col / st, 3),
             "target_task_over_raw": TARGET_RATIO}
    print(f"\n   ratios (same run): env-step / raw-sim = {ratio['env_step_over_raw']:.2f}, collector / raw-sim = {ratio['collector_over_raw']:.2f}, "
          f"collector / env-step = {ratio['collector_over_env_step']:.2f}", file=log)
    verdict = "meets" if ratio["collector_over_raw"] >= TARGET_RATIO else "misses"
    if len(records) > 3:
        ratio["gym_vector_over_env_step"] = round(records[3]["env_steps_per_s"] / st, 3)
        print(f"   gym-vector / env-step = {ratio['gym_vector_over_env_step']:.2f}", file=log)
    print(f"   target: the full task (collector) keeps >= {TARGET_RATIO:.0%} of raw-sim throughput: {verdict} it ({ratio['collector_over_raw']:.0%})", file=log)
    if args.json:
        common.emit_json(ratio)
    return records + [ratio]


if __name__ == "__main__":
    main()
