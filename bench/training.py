"""Time-to-result of a training recipe over several seeds, in one run.

    python bench/training.py ppo_lidar --seeds 0 1 2
    python bench/training.py ppo_line --seeds 0 1 2 --out runs/bench_ppo_line
    python bench/training.py sac_lidar --seeds 0 -- train.total_frames=300000   # overrides after --

Runs ``python recipes/<recipe>.py seed=S logger.run_dir=<out>/seedS logger.progress=false
[overrides]`` for each seed one after the other (each in its own process, as a user
would), times the whole command with a wall clock, and reads each run's
``summary.json``. Prints one Markdown row per seed and the mean (sd): final score
(success rate for navigation, lap-completion rate for line following) over
``eval.final_episodes`` episodes with its 95% interval, whole-command wall time,
training wall time, when periodic evaluation first reached ``eval.target_success``
(seconds from the command's start, and frames), when it first reached 90% (training
seconds and frames, from the run's logs), and the frames/s of collection, of
the updates and of both together (periodic evaluation excluded). ``--busy N`` runs N
CPU-bound processes next to every run (the load of a user's other work); ``--json``
also writes the table as JSON. Otherwise use an idle machine: on 2 cores another
busy process changes every figure (docs/performance.md).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ("td3_lidar", "ppo_lidar", "sac_lidar", "ppo_line", "dqn_line", "apg_lidar", "apg_line")


def score_of(ev: dict) -> tuple[str, dict]:
    key = "success" if "success" in ev else "lap_complete"
    return key, ev[key]


def first_reached(run: Path, level: float) -> tuple[int, float] | None:
    """(frames, training wall s) of the first periodic evaluation whose score (``eval/score`` in the
    run's CSV logs) reached ``level``; None if none did or the run logged no evaluation."""
    from torchnav.render import read_scalars

    s = read_scalars(run)
    if "eval/score" not in s or "eval/wall_s" not in s:
        return None
    for (frames, score), (_, wall) in zip(s["eval/score"], s["eval/wall_s"]):
        if score >= level:
            return int(frames), float(wall)
    return None


def run_seed(recipe: str, seed: int, out: Path, overrides: list[str]) -> dict:
    run = out / f"seed{seed}"
    cmd = [sys.executable, str(ROOT / "recipes" / f"{recipe}.py"), f"seed={seed}", f"logger.run_dir={run}",
           "logger.progress=false", *overrides]
    print(f"$ {' '.join(cmd[1:])}", file=sys.stderr, flush=True)
    t0, launched = time.perf_counter(), time.time()
    p = subprocess.run(cmd, cwd=ROOT, env={**os.environ, "RL_WARNINGS": "False"}, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"{recipe} seed {seed} failed (exit {p.returncode}):\n{p.stdout[-3000:]}")
    summary = json.loads((run / "summary.json").read_text())
    key, sc = score_of(summary["eval"])
    return {"seed": seed, "score_key": key, "score": sc["rate"], "ci95": sc["ci95"], "episodes": summary["eval"]["episodes"],
            "command_wall_s": wall, "train_wall_s": summary["train_wall_s"], "time_to_target_s": summary["time_to_target_s"],
            "command_to_target_s": summary["target_unix"] - launched if summary.get("target_unix") else None,
            "collect_fps": summary["frames"] / max(summary["collect_s"], 1e-9),
            "update_fps": summary["frames"] / max(summary["update_s"], 1e-9),
            "train_fps": summary["frames"] / max(summary["collect_s"] + summary["update_s"], 1e-9),
            "frames": summary["frames"], "frames_to_target": summary["frames_to_target"], "run_dir": str(run),
            "first_90": first_reached(run, 0.9)}


def _mean_sd(xs: list[float], digits: int = 1) -> str:
    if not xs:
        return "never"
    f = f",.{digits}f"
    return f"{statistics.mean(xs):{f}} ({statistics.stdev(xs):{f}})" if len(xs) > 1 else f"{xs[0]:{f}}"


def table(recipe: str, rows: list[dict], busy: int = 0) -> str:
    key = rows[0]["score_key"]
    lines = [f"| seed | {key} ({rows[0]['episodes']} episodes) | 95% CI | whole command | training | "
             "eval first >= target, from command start | eval first >= 90%, training s | frames/s: collection | updates | both |",
             "|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        ttt = f"{r['command_to_target_s']:.0f} s ({r['frames_to_target']:,} frames)" if r["command_to_target_s"] is not None else "never"
        f90 = r.get("first_90")
        t90 = f"{f90[1]:.0f} s ({f90[0]:,} frames)" if f90 else "never"
        lines.append(f"| {r['seed']} | {100 * r['score']:.1f}% | [{100 * r['ci95'][0]:.1f}, {100 * r['ci95'][1]:.1f}] | "
                     f"{r['command_wall_s']:.0f} s | {r['train_wall_s']:.0f} s | {ttt} | {t90} | "
                     f"{r['collect_fps']:,.0f} | {r['update_fps']:,.0f} | {r['train_fps']:,.0f} |")
    reached = [r["command_to_target_s"] for r in rows if r["command_to_target_s"] is not None]
    r90 = [r["first_90"][1] for r in rows if r.get("first_90")]
    lines.append(f"| **mean (sd)** | **{_mean_sd([100 * r['score'] for r in rows])}%** | | "
                 f"{_mean_sd([r['command_wall_s'] for r in rows])} s | {_mean_sd([r['train_wall_s'] for r in rows])} s | "
                 f"{_mean_sd(reached) + (' s' if reached else '')} ({len(reached)}/{len(rows)} seeds) | "
                 f"{_mean_sd(r90) + (' s' if r90 else '')} ({len(r90)}/{len(rows)} seeds) | {_mean_sd([r['collect_fps'] for r in rows], 0)} | "
                 f"{_mean_sd([r['update_fps'] for r in rows], 0)} | {_mean_sd([r['train_fps'] for r in rows], 0)} |")
    title = recipe + (f", next to {busy} busy process{'es' if busy > 1 else ''}" if busy else "")
    return f"{title}\n\n" + "\n".join(lines)


@contextlib.contextmanager
def busy_processes(n: int):
    """``n`` processes that spin on the CPU until the block ends: the load of a user's other work."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield procs
    finally:
        for pr in procs:
            pr.kill()
            pr.wait()


def main(argv: list[str]) -> list[dict]:
    if "--" in argv:
        i = argv.index("--")
        argv, overrides = argv[:i], argv[i + 1:]
    else:
        overrides = []
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recipe", choices=RECIPES)
    p.add_argument("--table", default=None, metavar="JSON", help="no runs: print the table of a --json file written earlier (filling in what it lacks from its runs' logs)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--out", default=None, help="parent of the run directories (default runs/bench_<recipe>_<time>; an existing run in it is not overwritten)")
    p.add_argument("--json", default=None, help="also write the rows as JSON here")
    p.add_argument("--busy", type=int, default=0, help="run this many CPU-bound processes next to each run (contention)")
    a = p.parse_args(argv)
    if a.table:
        rows = json.loads(Path(a.table).read_text())["rows"]
        for r in rows:
            r.setdefault("first_90", first_reached(Path(r["run_dir"]), 0.9))
        print(table(a.recipe, rows))
        return rows
    out = Path(a.out or ROOT / "runs" / f"bench_{a.recipe}_{time.strftime('%Y%m%d_%H%M%S')}")
    load = os.getloadavg()[0]
    if load > 0.5:
        print(f"warning: load average {load:.2f} before the first run; timings need an idle machine", file=sys.stderr)
    if a.busy < 0:
        raise SystemExit("--busy must be >= 0")
    with busy_processes(a.busy):
        rows = [run_seed(a.recipe, s, out, overrides) for s in a.seeds]
    print(table(a.recipe, rows, a.busy))
    if a.json:
        Path(a.json).write_text(json.dumps({"recipe": a.recipe, "overrides": overrides, "busy": a.busy, "rows": rows}, indent=2))
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
