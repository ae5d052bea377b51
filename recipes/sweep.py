"""Sweeps: a grid of overrides x seeds of one recipe, launched through submitit, then one table.

    python recipes/sweep.py run td3_lidar --seeds 0 1 2 --grid task.curriculum.growth=0.004,0.008
    python recipes/sweep.py run ppo_lidar --seeds 0 1 --grid train.lr=0.001,0.0005 --set train.total_frames=2000000 --workers 2
    python recipes/sweep.py run td3_lidar --seeds 0 1 2 --grid ... --cluster slurm --slurm-partition gpu --timeout-min 120
    python recipes/sweep.py aggregate runs/sweep_td3_lidar_<time>

``run`` builds one job per setting (the product of the ``--grid`` values) and seed: each
runs ``python recipes/<recipe>.py seed=S <setting> <--set ...> logger.run_dir=OUT/<setting>/seedS``.
Jobs go through submitit: ``--cluster local`` (default) runs ``--workers`` of them at a
time as processes on this machine; ``--cluster slurm`` submits them as one SLURM job
array (``--workers`` at a time) with the same command, nothing else changes. Every
run's config is validated before anything is launched. When the jobs are done,
``aggregate`` runs on the output folder: per setting, the final score (success or
lap-completion rate) as the mean over seeds with a 95% t-interval, the pooled
episodes with a Wilson interval, and wall time; ``OUT/sweep.json`` and ``OUT/curves.png``
(periodic-evaluation score against frames, mean over seeds, min-max band).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import builders as B  # noqa: E402

from torchnav.evaluation import wilson_interval  # noqa: E402

RECIPES_DIR = Path(__file__).resolve().parent
T95 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262, 10: 2.228}  # two-sided, by dof


def settings(grid: list[str]) -> list[dict[str, str]]:
    """The product of ``key=v1,v2,...`` entries: ``[{key: v1, ...}, ...]`` (one empty setting without a grid)."""
    axes = []
    for g in grid:
        if "=" not in g:
            raise B.ConfigError(f"--grid expects KEY=V1,V2,..., got {g!r}")
        k, vals = g.split("=", 1)
        axes.append([(k, v) for v in vals.split(",") if v != ""] or [(k, "")])
    return [dict(combo) for combo in itertools.product(*axes)]


def setting_name(s: dict[str, str]) -> str:
    return "_".join(f"{k.split('.')[-1]}={v}" for k, v in s.items()) or "default"


def launch(a: argparse.Namespace) -> Path:
    import submitit
    from submitit.helpers import CommandFunction

    out = Path(a.out or Path("runs") / f"sweep_{a.recipe}_{time.strftime('%Y%m%d_%H%M%S')}")
    jobs, runs = [], {}
    for s in settings(a.grid):
        for seed in a.seeds:
            run = out / setting_name(s) / f"seed{seed}"
            if run in runs:  # a repeated seed or grid value: two workers would share one run directory
                raise B.ConfigError(f"--seeds {' '.join(map(str, a.seeds))} --grid {' '.join(a.grid)}: {runs[run]} and seed={seed} {s} both "
                                    f"run in {run}; every seed and grid value must be distinct")
            runs[run] = f"seed={seed} {s}"
            args = [f"seed={seed}", *(f"{k}={v}" for k, v in s.items()), *a.set, f"logger.run_dir={run}", "logger.progress=false"]
            B.load_config(a.recipe, args)  # a bad value stops the sweep here, before any job starts
            jobs.append(args)
    claim_sweep_dir(out, {"recipe": a.recipe, "seeds": a.seeds, "grid": a.grid, "set": a.set})
    ex = submitit.AutoExecutor(folder=out / "submitit", cluster=a.cluster)
    ex.update_parameters(timeout_min=a.timeout_min, slurm_array_parallelism=a.workers, cpus_per_task=a.cpus_per_task,
                         **({"slurm_partition": a.slurm_partition} if a.slurm_partition else {}))
    print(f"sweep: {len(jobs)} runs of {a.recipe} ({len(settings(a.grid))} settings x {len(a.seeds)} seeds) on {a.cluster}, "
          f"{a.workers} at a time -> {out}", flush=True)
    # Each job is the recipe's own command line (submitit's CommandFunction): nothing is pickled but the command.
    commands = [CommandFunction([sys.executable, str(RECIPES_DIR / f"{a.recipe}.py"), *args]) for args in jobs]
    if a.cluster == "slurm":
        with ex.batch():  # one job array, --workers running at a time
            submitted = [ex.submit(c) for c in commands]
        failed = _wait(submitted, jobs)
    else:  # the local executor starts every submitted job at once: submit them in waves of --workers
        failed = []
        for i in range(0, len(jobs), a.workers):
            failed += _wait([ex.submit(c) for c in commands[i : i + a.workers]], jobs[i : i + a.workers])
            print(f"sweep: {min(i + a.workers, len(jobs))}/{len(jobs)} runs done", flush=True)
    aggregate(out)
    if failed:
        raise SystemExit(f"sweep: {len(failed)} of {len(jobs)} runs failed: " + "; ".join(" ".join(f) for f in failed))
    return out


def claim_sweep_dir(out: Path, spec: dict[str, Any]) -> None:
    """Make ``out`` this sweep's folder, writing ``sweep_spec.json`` into it: refused (``ConfigError``)
    when it holds anything already, and the spec is created exclusively (``O_EXCL``), so of two sweeps
    launched on one folder at once exactly one goes on. An unwritable folder raises ``RunDirError``
    before any job starts. Each job's run directory is then claimed by its recipe (``builders.claim_run_dir``)."""
    if out.exists() and any(out.iterdir()):
        raise B.ConfigError(f"{out} is not empty; sweeps never write into an earlier sweep's folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = os.open(out / "sweep_spec.json", os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        raise B.ConfigError(f"{out}: another sweep started in this folder at the same time") from None
    except OSError as e:
        raise B.RunDirError(f"sweep folder {out} is not writable ({type(e).__name__}: {e}); choose another --out") from None
    with os.fdopen(fd, "w") as f:
        f.write(json.dumps(spec, indent=2))


def _wait(submitted: list[Any], jobs: list[list[str]]) -> list[list[str]]:
    """Wait for jobs; print the end of a failed one's output and return the failed ones' arguments."""
    failed = []
    for job, args in zip(submitted, jobs):
        try:
            job.result()
        except Exception as e:  # noqa: BLE001 - submitit's FailedJobError carries the run's output
            print(f"sweep: run {' '.join(args)} failed:\n{str(e)[-2000:]}", file=sys.stderr)
            failed.append(args)
    return failed


def _score(summary: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    key = "success" if "success" in summary["eval"] else "lap_complete"
    return key, summary["eval"][key]


def aggregate(out: Path) -> list[dict[str, Any]]:
    """Per setting of a sweep folder: final score over seeds (t-interval) and pooled (Wilson), wall time; writes sweep.json and curves.png."""
    out = Path(out)
    rows = []
    for setting in sorted(p for p in out.iterdir() if p.is_dir() and p.name != "submitit"):
        runs = sorted(p for p in setting.glob("seed*") if (p / "summary.json").is_file())
        if not runs:
            continue
        sums = [json.loads((r / "summary.json").read_text()) for r in runs]
        key, _ = _score(sums[0])
        rates = [_score(s)[1]["rate"] for s in sums]
        k = sum(_score(s)[1]["count"] for s in sums)
        n = sum(s["eval"]["episodes"] for s in sums)
        m = statistics.fmean(rates)
        half = T95.get(len(rates) - 1, 1.96) * statistics.stdev(rates) / math.sqrt(len(rates)) if len(rates) > 1 else float("nan")
        rows.append({"setting": setting.name, "seeds": len(runs), "metric": key, "mean": m, "ci95": [max(0.0, m - half), min(1.0, m + half)],
                     "per_seed": rates, "pooled": k / n, "pooled_ci95": list(wilson_interval(k, n)), "episodes": n,
                     "train_wall_s": statistics.fmean(s["train_wall_s"] for s in sums), "frames": sums[0]["frames"]})
    if not rows:
        raise SystemExit(f"{out}: no finished runs (no */seed*/summary.json)")
    print(f"\n{'setting':<40} {'seeds':>5} {'final ' + rows[0]['metric'] + ' (mean, 95% CI over seeds)':>44} {'pooled (Wilson)':>24} {'train s':>8}")
    for r in rows:
        ci = "" if math.isnan(r["ci95"][0]) else f" [{100 * r['ci95'][0]:.1f}, {100 * r['ci95'][1]:.1f}]"
        print(f"{r['setting']:<40} {r['seeds']:>5} {100 * r['mean']:>30.1f}%{ci:>13} {100 * r['pooled']:>8.1f}% "
              f"[{100 * r['pooled_ci95'][0]:.1f}, {100 * r['pooled_ci95'][1]:.1f}] {r['train_wall_s']:>8.0f}")
    (out / "sweep.json").write_text(json.dumps(rows, indent=2))
    _curves(out, [r["setting"] for r in rows])
    print(f"\nwrote {out / 'sweep.json'} and {out / 'curves.png'}")
    return rows


def _curves(out: Path, names: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from torchnav.render import read_scalars

    fig, ax = plt.subplots(figsize=(6, 3.6))
    for name in names:
        curves = [read_scalars(r).get("eval/score") for r in sorted((out / name).glob("seed*"))]
        curves = [c for c in curves if c is not None and len(c)]
        if not curves:
            continue
        n = min(len(c) for c in curves)
        steps = curves[0][:n, 0]
        vals = np.stack([c[:n, 1] for c in curves])
        ax.plot(steps, vals.mean(0), label=name)
        ax.fill_between(steps, vals.min(0), vals.max(0), alpha=0.2)
    ax.set_xlabel("frames")
    ax.set_ylabel("periodic evaluation score")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> Any:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="launch a sweep, then aggregate it")
    r.add_argument("recipe", choices=sorted(f.stem for f in RECIPES_DIR.glob("*.py") if (RECIPES_DIR / "configs" / f"{f.stem}.yaml").is_file()))
    r.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    r.add_argument("--grid", nargs="*", default=[], metavar="KEY=V1,V2", help="overrides to sweep (their product)")
    r.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="overrides shared by every run")
    r.add_argument("--workers", type=int, default=2, help="runs at a time (default 2)")
    r.add_argument("--cluster", choices=("local", "slurm", "debug"), default="local", help="submitit executor (default local)")
    r.add_argument("--timeout-min", type=int, default=180, help="per-run time limit in minutes (default 180)")
    r.add_argument("--cpus-per-task", type=int, default=2)
    r.add_argument("--slurm-partition", default=None)
    r.add_argument("--out", default=None, help="sweep folder (default runs/sweep_<recipe>_<time>; must not hold an earlier sweep)")
    g = sub.add_parser("aggregate", help="table and curves of a finished sweep folder")
    g.add_argument("out")
    a = p.parse_args(argv)
    if a.cmd == "aggregate":
        return aggregate(Path(a.out))
    if a.workers < 1:
        p.error("--workers must be >= 1")
    if a.slurm_partition and a.cluster != "slurm":
        p.error(f"--slurm-partition needs --cluster slurm (got --cluster {a.cluster})")
    return launch(a)


if __name__ == "__main__":
    B.main_guard(main)
