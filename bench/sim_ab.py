"""Two trees' simulators in one process: the plain step and options' steps of both, timed in turns.

    python bench/sim_ab.py OTHER_TREE --options boxmovers4
    python bench/sim_ab.py OTHER_TREE --options boxmovers4,pedestrians4 --rounds 25 --steps 60 --envs 4096

A single run of ``sim_throughput.py`` gives an option's ratio to the plain step that moves by several
points between processes on the same VM and the same code (0.61-0.68 for ``boxmovers4``,
docs/performance.md, "Simulator options"); two copies of one tree compiled side by side in one
process read 0.005 and 0.018 apart in two runs (median of the rounds' ratios). So a change to the
step is best judged here, and a difference under about 0.02 is still noise: this script imports
``OTHER_TREE/torchnav/sim`` (a git worktree or checkout of another commit) as a second package,
builds ``sim_throughput.py``'s load for the plain step and each option, and times ``--steps`` steps
of every (tree, option) in turn, ``--rounds`` times, in CPU time on ``--threads`` threads. It prints,
per tree, the median microseconds per step, and each option's ratio to the same tree's plain step
(medians, and the median of the rounds' ratios).

The other tree's step gets this tree's ``SimParams`` and load (its ``SimState`` and ``World`` are
rebuilt field by field): trees whose parameters or state fields differ cannot be compared this way.
The copy's custom ops are renamed (``torchnav::`` -> ``torchnav_ab::``), so both register.
"""

from __future__ import annotations

import argparse
import importlib
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common  # noqa: E402  (sets TORCHINDUCTOR_COMPILE_THREADS before torch is imported)
import sim_throughput as st  # noqa: E402
import torch  # noqa: E402

import torchnav.sim as this_sim  # noqa: E402

OTHER = "torchnav_ab_sim"  # the other tree's package name


def import_other(tree: Path, workdir: Path):
    """``tree/torchnav/sim`` imported as package ``OTHER`` from a copy in ``workdir``."""
    src = tree / "torchnav" / "sim"
    if not (src / "step.py").is_file():
        raise SystemExit(f"{tree}: no torchnav/sim/step.py there (give the root of a torchnav checkout)")
    dst = workdir / OTHER
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__"))
    for f in dst.glob("*.py"):
        f.write_text(f.read_text().replace('"torchnav::', '"torchnav_ab::'))
    sys.path.insert(0, str(workdir))
    return importlib.import_module(OTHER)


def _rebuild(obj, cls):
    """A tensorclass instance of ``cls`` with ``obj``'s fields (same tensors, no copy)."""
    return cls(**{k: getattr(obj, k) for k in obj.to_dict().keys()}, batch_size=obj.batch_size, device=obj.device)


def _step_fn(pkg, params, name: str, compiled: bool) -> Callable:
    # A distinct function object per (tree, option), so each compiles once and keeps its own graph.
    ns: dict[str, Any] = {}
    exec(f"def {name}(s, a, w):\n    return STEP(s, a, w, PARAMS)\n", {"STEP": pkg.step, "PARAMS": params}, ns)
    return torch.compile(ns[name]) if compiled else ns[name]


def run(args: argparse.Namespace) -> dict[tuple[str, str], list[float]]:
    """Microseconds per step of every (tree, option), one value per round."""
    with tempfile.TemporaryDirectory() as tmp:
        other = import_other(args.other, Path(tmp))
        trees = {"this": this_sim, "other": other}
        torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, 4 * len(args.options))
        loads: dict[tuple[str, str], list[Any]] = {}
        for option in args.options:
            params = st.bench_params(option)
            state, world, actions = st.make_load(args.envs, "cpu", seed=args.seed, params=params, movers=st.OPTIONS[option][1])
            for tree, pkg in trees.items():
                s, w = (state, world) if pkg is this_sim else (_rebuild(state, pkg.SimState), _rebuild(world, pkg.World))
                fn = _step_fn(pkg, params, f"step_{tree}_{option}", not args.eager)
                for i in range(3):  # compiles, then warms up
                    s = fn(s, actions[i % len(actions)], w)
                loads[(tree, option)] = [fn, s, w, actions]
                print(f"   ready: {tree} {option}", file=sys.stderr, flush=True)
        us: dict[tuple[str, str], list[float]] = {k: [] for k in loads}
        for _ in range(args.rounds):
            for key, load in loads.items():
                fn, s, w, actions = load
                t0 = time.process_time()
                for i in range(args.steps):
                    s = fn(s, actions[i % len(actions)], w)
                us[key].append((time.process_time() - t0) / args.steps * 1e6)
                load[1] = s
    return us


def report(us: dict[tuple[str, str], list[float]], options: list[str], other: Path) -> list[list[str]]:
    rows = []
    for tree in ("this", "other"):
        plain = us[(tree, "plain")]
        for option in options:
            t = us[(tree, option)]
            ratio = "-" if option == "plain" else f"{statistics.median(plain) / statistics.median(t):.3f}"
            rounds = "-" if option == "plain" else f"{statistics.median([p / x for p, x in zip(plain, t)]):.3f}"
            rows.append([tree, option, f"{statistics.median(t):.0f}", f"{min(t):.0f}", ratio, rounds])
    common.print_table(["tree", "option", "us/step (median)", "min", "vs plain", "median of rounds"], rows)
    print(f"   this = {Path(__file__).resolve().parents[1]}, other = {other.resolve()}")
    return rows


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("other", type=Path, help="root of the other torchnav tree (a worktree or checkout)")
    p.add_argument("--options", type=lambda s: [x for x in s.split(",") if x], default=["boxmovers4"],
                   help=f"comma-separated, from {','.join(o for o in st.OPTIONS if o != 'plain')} (default boxmovers4)")
    p.add_argument("--envs", type=int, default=4096)
    p.add_argument("--rounds", type=int, default=15, help="timed turns of every (tree, option)")
    p.add_argument("--steps", type=int, default=60, help="steps per turn")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--eager", action="store_true", help="time the eager steps (a smoke test; the figures that matter are compiled)")
    a = p.parse_args(argv)
    bad = [o for o in a.options if o not in st.OPTIONS]
    if bad:
        p.error(f"unknown option(s) {bad}; choose from {tuple(st.OPTIONS)}")
    for name in ("envs", "rounds", "steps", "threads"):
        if getattr(a, name) < 1:
            p.error(f"--{name} must be >= 1")
    a.options = ["plain"] + [o for o in a.options if o != "plain"]
    return a


def main(argv: list[str] | None = None) -> list[list[str]]:
    args = parse_args(argv)
    common.set_threads(args.threads)
    return report(run(args), args.options, args.other)


if __name__ == "__main__":
    main()
