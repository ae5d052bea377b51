"""Generation time of the procedural world families (``torchnav.worlds.make_worlds``).

Each row times one ``make_worlds(family, num_envs, difficulty, generator)`` call as a
whole (layout, clearance raster, wavefront, start and goal placement) with
``time.perf_counter``, ``repeats`` times after one untimed warm-up call, and reports
the median seconds per call and generated envs per second. Difficulties: 0, 0.5, 1
and ``mixed`` (uniform per env). ``--guide-cells 64`` adds the goal's wavefront that the
geodesic progress reward needs (``reward.progress_distance: geodesic``); ``--cpu-time`` times
the process's CPU time instead of the wall clock (steadier on a shared machine).

    python bench/worlds.py                               # 1,024 envs, every family, 1 thread
    python bench/worlds.py --num-envs 256 --families rooms,cave --json
    python bench/worlds.py --num-envs 512 --difficulties 0.7 --guide-cells 64 --cpu-time
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402  (sets TORCHINDUCTOR_COMPILE_THREADS before torch is imported)

import torch  # noqa: E402

from torchnav.worlds import FAMILIES, make_worlds  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--num-envs", type=int, default=1024)
    ap.add_argument("--families", default=",".join(FAMILIES), help="comma-separated family names")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--difficulties", default="0,0.5,1,mixed", help="comma-separated difficulties in [0, 1], or mixed (uniform per env)")
    ap.add_argument("--guide-cells", type=int, default=0, help="also each goal's geodesic distance grid, this many cells a side (the geodesic reward: 64)")
    ap.add_argument("--cpu-time", action="store_true", help="time the process's CPU time instead of the wall clock")
    ap.add_argument("--json", action="store_true", help="print one JSON line per row instead of a table")
    args = ap.parse_args()
    labels = args.difficulties.split(",")
    bad = [x for x in labels if x != "mixed" and not (x.replace(".", "", 1).isdigit() and 0 <= float(x) <= 1)]
    if bad:
        ap.error(f"--difficulties: {bad} are neither numbers in [0, 1] nor 'mixed'")
    common.set_threads(args.threads)
    info = common.machine_info(args.device)
    if not args.json:
        print(f"# {info}")
        warning = common.load_warning(args.device)
        if warning:
            print(warning)
        print(f"{'family':10s} {'difficulty':>10s} {'s/call':>8s} {'envs/s':>8s}")
    clock = time.process_time if args.cpu_time else time.perf_counter
    for family in args.families.split(","):
        for label in labels:
            gen = torch.Generator(device=args.device).manual_seed(0)
            d = torch.rand(args.num_envs, generator=gen, device=args.device) if label == "mixed" else float(label)
            make_worlds(family, args.num_envs, d, gen, guide_cells=args.guide_cells)  # warm-up
            seconds = []
            for _ in range(args.repeats):
                common.sync(args.device)
                t = clock()
                make_worlds(family, args.num_envs, d, gen, guide_cells=args.guide_cells)
                common.sync(args.device)
                seconds.append(clock() - t)
            s = statistics.median(seconds)
            row = {"bench": "worlds", "family": family, "difficulty": label, "num_envs": args.num_envs, "guide_cells": args.guide_cells,
                   "clock": "cpu" if args.cpu_time else "wall", "seconds": round(s, 3),
                   "envs_per_s": round(args.num_envs / s, 1), "seconds_min": round(min(seconds), 3), "seconds_max": round(max(seconds), 3), **info}
            if args.json:
                common.emit_json(row)
            else:
                print(f"{family:10s} {label:>10s} {s:8.2f} {args.num_envs / s:8.0f}", flush=True)


if __name__ == "__main__":
    main()
