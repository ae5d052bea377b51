"""Benchmark suite: every shipped map and generated worlds of every family at three
difficulties, the same seeded episodes for any checkpoints and the classical controllers.

    python recipes/benchmark.py checkpoints/td3_arena_actor.pt                 # full suite, 200 episodes a cell
    python recipes/benchmark.py CKPT_A CKPT_B --episodes 50 --out runs/bench
    python recipes/benchmark.py --maps arena maze --families forest --levels easy=0.2 hard=0.8 --controllers reactive astar
    python recipes/benchmark.py CKPT --map-file examples/maps/lab.yaml --map-file my_maps/office.yaml
    python recipes/benchmark.py CKPT --controllers reactive --perturb          # and under every perturbation

Cells: each map of ``--maps`` (default every shipped map; goals anywhere, curriculum
off), each map file of ``--map-file`` (repeatable: a torchnav or ROS map_server YAML,
docs/maps.md; labelled by its path, played like a shipped map) and each family of ``--families`` (default ``rooms corridors cave forest open fences``) at
each level of ``--levels`` (default ``easy=0.2 medium=0.5 hard=0.8``, a difficulty in
[0, 1]): every episode of such a cell is a fresh world of that family at that difficulty,
with the generator's start and reachable goal (curriculum off; docs/worlds.md).

Methods: the checkpoints (each in its own task config; one whose scenarios differ from
the first's is refused, as in compare.py) and ``--controllers`` (default the memoryless
``go_to_goal reactive potential_field``, in the first checkpoint's task config). The
planners ``astar`` and ``rrt`` plan on a map's fixed obstacles and bounds (its spec; they
refuse procedural worlds, ``PlannerController.bind``), so they run on map cells only;
their generated cells read n/a.

Seeds: cell ``i`` plays episodes with env seed ``--seed + 10007 * i`` (default ``--seed``
1000000), ``i`` its index in the canonical suite: shipped maps by ``MAP_INDEX`` (the order
they were added in), then ``MAX_LEVELS`` slots per family (``FAMILIES`` order) for its level's position
in ``--levels``, and a map file ``FILE_BASE`` plus the CRC-32 of the file's bytes modulo
``FILE_SLOTS`` (so the same file has the same seed wherever it lies; two different files share
one once in 10,000 pairs). A cell's seed does not depend on which
other cells run, so a subset reproduces the full suite's figures. The recipes train on env seed ``seed`` (0 in every
shipped config) and evaluate on ``10000 + seed`` and ``20000 + seed``, compare.py and
evaluate.py on 20000: the benchmark's seeds (1000000 and up) are disjoint from all of them
for any training seed below 980000.

Writes to ``--out`` (default runs/benchmark), after every cell: ``results.json`` (every
summary, each method's exact config and seed per cell, planner statistics),
``results.md`` (cells x methods: success % with its 95% Wilson interval; with two or more
methods, a second table pairs each with the first on the same episodes: success difference and
exact McNemar p, from each episode's outcome kept in ``results.json``; then time to goal over
the optimal time with the time score, and smoothness) and, at the end, ``heatmap.png``
(methods x cells, success %).

Time: each episode's optimal time is its shortest collision-free path for the robot's disc
(``torchnav.evaluation.shortest_episode_paths``: A* at 0.05 m on the episode's obstacles at
its start, shortcut), less the goal tolerance, at the robot's top speed with no time to turn;
``time_ratio`` is the successful episodes' steps over their optimal steps (summed), ``time_score``
the mean over all episodes of ``success * min(1, optimal / actual time)``
(``torchnav.evaluation.time_efficiency``). Smoothness: ``speed_change`` and ``turn_change``,
the mean absolute change of the driven speed and turn rate per step.

Overrides: ``--set KEY=VALUE ...`` lays task keys over every method's config (each checkpoint's own,
and the controllers'), e.g. ``--set robot.preset=jackal`` plays a policy trained on the idealised
robot on a Jackal-class body; a bad key or value is named before any episode.

Robustness: ``--perturb NAME ...`` (none given: all) also plays every method on every cell
under each perturbation of ``torchnav.evaluation.PERTURBATIONS`` (3 cm lidar noise, odometry
noise, 5% lidar dropout, a one-step actuator delay, 1 m/s^2 and 3 rad/s^2 acceleration limits),
with the cell's seed (the draws of a randomised setting change the episodes, the same for every
method); ``results.md`` ends with a table per method of success / collision % under each.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import zlib
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import builders as B  # noqa: E402
from compare import _pct, evaluate_method, load_methods, method_configs  # noqa: E402
from evaluate import parse_sets  # noqa: E402

from torchnav.config import to_dict  # noqa: E402
from torchnav.controllers import CONTROLLERS, PlannerController  # noqa: E402
from torchnav.evaluation import PERTURBATIONS, eval_config, paired_successes, perturbed, shortest_episode_paths  # noqa: E402
from torchnav.maps import MapError, available_maps, load_map  # noqa: E402
from torchnav.tasks import NavConfig  # noqa: E402
from torchnav.worlds import FAMILIES  # noqa: E402

DEFAULT_LEVELS = ("easy=0.2", "medium=0.5", "hard=0.8")
DEFAULT_CONTROLLERS = ("go_to_goal", "reactive", "potential_field")
DEFAULT_EPISODES = 200
SEED_BASE, SEED_STRIDE = 1_000_000, 10_007
MAP_SLOTS, MAX_LEVELS = 100, 16  # canonical cell index: maps in [0, MAP_SLOTS), then MAX_LEVELS per family
# A shipped map's cell index, by name: a map added later takes the next index, so adding one never
# moves the seeds (and figures) of the cells before it. tests/test_benchmark.py checks that every
# shipped map has its index.
MAP_INDEX = {name: i for i, name in enumerate(("arena", "empty", "maze", "street", "warehouse"))}
FILE_BASE, FILE_SLOTS = 10_000, 10_000  # map files' cell indices: past any family's, seeds below 2**31
CHECK_EPISODES = 16  # episodes per cell compared before the run to refuse a checkpoint with other scenarios


@dataclass(frozen=True)
class Cell:
    """One cell of the suite: a shipped map or a map file, or a family of generated worlds at one difficulty."""

    label: str  # "arena", "examples/maps/lab.yaml", "forest/hard"
    kind: str  # "map" or "world"
    name: str  # shipped map name, map file path or family name
    level: str | None  # level name ("hard"), None for a map
    difficulty: float | None  # in [0, 1], None for a map
    seed: int  # env seed of the cell's episodes

    def config(self, cfg: NavConfig) -> NavConfig:
        """``cfg`` evaluated on this cell (goals anywhere, every curriculum off)."""
        if self.kind == "map":
            return eval_config(cfg, map=self.name)
        return eval_config(cfg, worlds={"families": {self.name: 1.0}, "difficulty": self.difficulty})


def parse_levels(items: list[str]) -> dict[str, float]:
    """``["easy=0.2", ...]`` -> ``{"easy": 0.2, ...}``; raises ``ValueError`` naming a bad item."""
    levels: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name or "/" in name:
            raise ValueError(f"--levels: expected NAME=DIFFICULTY (e.g. hard=0.8), got {item!r}")
        try:
            d = float(value)
        except ValueError:
            raise ValueError(f"--levels: {item!r}: {value!r} is not a number") from None
        if not 0.0 <= d <= 1.0:
            raise ValueError(f"--levels: {item!r}: difficulty must be in [0, 1]")
        if name in levels:
            raise ValueError(f"--levels: level {name!r} given twice")
        levels[name] = d
    if len(levels) > MAX_LEVELS:
        raise ValueError(f"--levels: at most {MAX_LEVELS} levels, got {len(levels)}")
    return levels


def file_index(path: str) -> int:
    """The canonical cell index of the map file ``path``, from its bytes: not from its path, which differs
    between checkouts and working folders."""
    return FILE_BASE + zlib.crc32(Path(path).read_bytes()) % FILE_SLOTS


def suite(maps: list[str], families: list[str], levels: dict[str, float], seed: int, files: list[str] = ()) -> list[Cell]:
    """The cells in run order (shipped maps, map ``files``, then each family at each level), each with its seed."""
    fams = list(FAMILIES)
    cells = [Cell(m, "map", m, None, None, seed + SEED_STRIDE * MAP_INDEX[m]) for m in maps]
    cells += [Cell(os.path.normpath(f), "map", f, None, None, seed + SEED_STRIDE * file_index(f)) for f in files]
    for f in families:
        for k, (level, d) in enumerate(levels.items()):
            index = MAP_SLOTS + MAX_LEVELS * fams.index(f) + k
            cells.append(Cell(f"{f}/{level}", "world", f, level, d, seed + SEED_STRIDE * index))
    return cells


def runs_on(policy: Any, cell: Cell) -> bool:
    """Whether ``policy`` is evaluated on ``cell``: the planners need a map's spec and refuse
    procedural worlds (``PlannerController.bind``), so they run on map cells only."""
    return cell.kind == "map" or not isinstance(policy, PlannerController)


def markdown(results: dict[str, dict[str, Any]], cells: list[Cell], episodes: int) -> str:
    """One Markdown table: a row per cell, a column per method, success % [95% Wilson interval].
    ``results[method][cell]``: a summary, None where the method does not run (n/a), absent before it ran."""
    methods = list(results)
    lines = [
        f"Success % [95% Wilson interval], {episodes} episodes per cell; seeds per cell in results.json "
        "(n/a: planners need a map's spec; –: not run yet).",
        "",
        "| cell | seed | " + " | ".join(methods) + " |",
        "|---|---:|" + "---:|" * len(methods),
    ]
    for c in cells:
        row = []
        for m in methods:
            s = results[m].get(c.label, "–")
            row.append("n/a" if s is None else s if s == "–" else _pct(s, "success"))
        lines.append(f"| {c.label} | {c.seed} | " + " | ".join(row) + " |")
    time_note = ("Time to goal over the optimal time (the successful episodes' steps over their optimal steps, summed; the optimal "
                 "time: the episode's shortest path for the robot's disc, A* at 0.05 m, less the goal tolerance, at the top speed "
                 "with no time to turn) · time score (all episodes: success x min(1, optimal / actual time)).")
    smooth_note = "Smoothness: mean |change of v| m/s · mean |change of omega| rad/s per step of the driven velocity (all episodes)."
    return ("\n".join(lines) + "\n" + paired_table(results, cells)
            + metric_table(results, cells, time_note, lambda s: f"{s['time_ratio']['mean']:.2f}x · {s['time_score']['mean']:.2f}"
                           if "time_ratio" in s else "–")
            + metric_table(results, cells, smooth_note, lambda s: f"{s['speed_change']['mean']:.3f} · {s['turn_change']['mean']:.3f}"))


def robustness_tables(results: dict[str, dict[str, Any]], robustness: dict[str, dict[str, dict[str, Any]]], cells: list[Cell]) -> str:
    """With ``--perturb``, one table per method: cells x (none and each perturbation), success % / collision %."""
    if not robustness:
        return ""
    perts = list(robustness)
    out = []
    for m in results:
        lines = ["", f"Robustness of {m}: success % / collision % unperturbed and under each perturbation "
                     "(results.json \"perturbations\" holds their settings).", "",
                 "| cell | none | " + " | ".join(perts) + " |", "|---|" + "---:|" * (len(perts) + 1)]
        for c in cells:
            base = results[m].get(c.label, "–")
            row = []
            for s in [base] + [robustness[p].get(m, {}).get(c.label, "–") for p in perts]:
                row.append("n/a" if base is None else s if s == "–" else f"{100 * s['success']['rate']:.1f} / {100 * s['collision']['rate']:.1f}")
            lines.append(f"| {c.label} | " + " | ".join(row) + " |")
        out.append("\n".join(lines) + "\n")
    return "".join(out)


def metric_table(results: dict[str, dict[str, Any]], cells: list[Cell], note: str, cell_text) -> str:
    """A table of cells x methods, each entry ``cell_text(summary)``; n/a where a method does not run, – before it ran."""
    methods = list(results)
    lines = ["", note, "", "| cell | " + " | ".join(methods) + " |", "|---|" + "---:|" * len(methods)]
    for c in cells:
        row = []
        for m in methods:
            s = results[m].get(c.label, "–")
            row.append("n/a" if s is None else s if s == "–" else cell_text(s).replace("nanx", "–").replace("nan", "–"))
        lines.append(f"| {c.label} | " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def paired_table(results: dict[str, dict[str, Any]], cells: list[Cell]) -> str:
    """With two or more methods, each against the first on the same episodes: the difference in
    success points, the episodes only the first / only the other succeeded on, and the exact
    McNemar p (``torchnav.evaluation.paired_successes``); "" with one method."""
    methods = list(results)
    if len(methods) < 2:
        return ""
    ref, others = methods[0], methods[1:]
    lines = [
        "",
        f"Paired against {ref} on the same episodes: success points of {ref} minus the other's "
        f"(episodes only {ref} / only the other succeeded on, exact McNemar p; p < 0.05 is unlikely by chance "
        "in one cell, but expect about one such cell in 20 among equal methods).",
        "",
        "| cell | " + " | ".join(others) + " |",
        "|---|" + "---:|" * len(others),
    ]
    for c in cells:
        a, row = results[ref].get(c.label, "–"), []
        for m in others:
            b = results[m].get(c.label, "–")
            if a is None or b is None or a == "–" or b == "–":
                row.append("n/a" if a is None or b is None else "–")
                continue
            d = paired_successes([o == "S" for o in a["outcomes"]], [o == "S" for o in b["outcomes"]])
            row.append(f"{100 * d['difference']:+.1f} ({d['only_a']}/{d['only_b']}, p {d['p']:.2g})")
        lines.append(f"| {c.label} | " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def heatmap(results: dict[str, dict[str, Any]], cells: list[Cell], episodes: int, seed: int):
    """Methods x cells, coloured and annotated by success % (interval below); grey: not run (n/a)."""
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    methods = list(results)
    rate = np.full((len(methods), len(cells)), np.nan)
    for i, m in enumerate(methods):
        for j, c in enumerate(cells):
            if results[m].get(c.label):
                rate[i, j] = 100 * results[m][c.label]["success"]["rate"]
    cmap = colormaps["RdYlGn"].with_extremes(bad="0.85")
    fig = Figure(figsize=(max(6.0, 2.2 + 0.8 * len(cells)), 1.8 + 0.75 * len(methods)))
    ax = fig.add_subplot()
    im = ax.imshow(np.ma.masked_invalid(rate), cmap=cmap, vmin=0, vmax=100, aspect="auto")
    for i, m in enumerate(methods):
        for j, c in enumerate(cells):
            if np.isnan(rate[i, j]):
                ax.text(j, i, "n/a", ha="center", va="center", fontsize=8, color="0.4")
                continue
            lo, hi = (100 * x for x in results[m][c.label]["success"]["ci95"])
            r, g, b, _ = cmap(rate[i, j] / 100)
            ink = "white" if 0.299 * r + 0.587 * g + 0.114 * b < 0.5 else "black"
            ax.text(j, i - 0.12, f"{rate[i, j]:.0f}", ha="center", va="center", fontsize=11, color=ink)
            ax.text(j, i + 0.24, f"{lo:.0f}–{hi:.0f}", ha="center", va="center", fontsize=7, color=ink)
    ax.set_xticks(range(len(cells)), [c.label for c in cells], rotation=45, ha="right", fontsize=9)
    ax.set_yticks(range(len(methods)), methods, fontsize=9)
    for j in range(1, len(cells)):  # separate the maps and each family's levels
        if cells[j].kind != cells[j - 1].kind or (cells[j].kind == "world" and cells[j].name != cells[j - 1].name):
            ax.axvline(j - 0.5, color="white", lw=3)
    fig.colorbar(im, ax=ax, fraction=0.025, pad=0.01).set_label("success %", fontsize=8)
    ax.set_title(f"Success % and its 95% Wilson interval, {episodes} episodes per cell, seed base {seed}", fontsize=9)
    fig.tight_layout()
    return fig


def document(a: argparse.Namespace, levels: dict[str, float], cells: list[Cell], methods: list, cfgs: dict,
             results: dict, planning: dict, reference: dict, robustness: dict, complete: bool) -> dict[str, Any]:
    """Everything ``results.json`` holds: options, cells with each method's exact config, summaries."""
    return {
        "complete": complete, "episodes": a.episodes, "seed": a.seed, "levels": levels, "set": a.set,
        "checkpoints": a.checkpoints, "methods": [n for n, _, _ in methods],
        "cells": [{**asdict(c), "configs": {n: to_dict(cfg) for n, cfg in cfgs[c.label].items()}} for c in cells],
        "results": results, "planning": planning, "shortest_paths": reference,
        "perturbations": {k: PERTURBATIONS[k] for k in robustness}, "robustness": robustness,
    }


def main(argv: list[str]) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoints", nargs="*", help="actor.pt / checkpoint.pt files of navigation policies")
    p.add_argument("--maps", nargs="*", default=None, help="shipped maps (default all; none: --maps)")
    p.add_argument("--map-file", action="append", default=[], metavar="PATH",
                   help="a map file (torchnav or ROS map_server YAML) as one more cell; repeatable")
    p.add_argument("--families", nargs="*", default=None, help=f"world families (default all: {' '.join(FAMILIES)}; none: --families)")
    p.add_argument("--levels", nargs="+", default=list(DEFAULT_LEVELS), help=f"NAME=DIFFICULTY (default {' '.join(DEFAULT_LEVELS)})")
    p.add_argument("--controllers", nargs="*", default=list(DEFAULT_CONTROLLERS),
                   help=f"controllers (default {' '.join(DEFAULT_CONTROLLERS)}; any of {' '.join(CONTROLLERS)}; none: --controllers)")
    p.add_argument("--episodes", type=int, default=DEFAULT_EPISODES, help=f"episodes per method and cell (default {DEFAULT_EPISODES})")
    p.add_argument("--seed", type=int, default=SEED_BASE, help=f"seed of the first cell (default {SEED_BASE}); cell i adds {SEED_STRIDE} * i")
    p.add_argument("--perturb", nargs="*", default=None, metavar="NAME",
                   help=f"also play every cell under each perturbation (none given: all of {' '.join(PERTURBATIONS)})")
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                   help="task overrides for every method, e.g. robot.preset=jackal randomize.delay=[1,1] (each checkpoint's own config otherwise)")
    p.add_argument("--out", default="runs/benchmark", help="output directory (default runs/benchmark)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--threads", type=B.threads_arg, default="auto", help="torch CPU threads: auto (the cores other processes leave free) or a number")
    a = p.parse_args(argv)
    maps = available_maps() if a.maps is None else a.maps
    families = list(FAMILIES) if a.families is None else a.families
    if a.episodes < 1:
        p.error("--episodes must be >= 1")
    if a.seed < 0:
        p.error("--seed must be >= 0")
    for m in maps:
        if m not in available_maps():
            p.error(f"--maps: unknown map {m!r}; shipped maps: {', '.join(available_maps())} (a map file: --map-file PATH)")
    for f in a.map_file:
        if not f.endswith((".yaml", ".yml")):
            p.error(f"--map-file: {f!r}: expected a .yaml or .yml map file (a shipped map: --maps {f})")
        try:
            load_map(f)  # every problem of the file now, before any episode
        except MapError as e:
            p.error(f"--map-file: {e}")
    for f in families:
        if f not in FAMILIES:
            p.error(f"--families: unknown family {f!r}; known: {', '.join(FAMILIES)}")
    for name in a.controllers:
        if name not in CONTROLLERS:
            p.error(f"--controllers: unknown controller {name!r}; available: {', '.join(CONTROLLERS)}")
    try:
        levels = parse_levels(a.levels)
    except ValueError as e:
        p.error(str(e))
    cells = suite(maps, families, levels, a.seed, a.map_file)
    if not cells:
        p.error("no cells: give --maps, --map-file or --families")
    if len({c.label for c in cells}) < len(cells):
        p.error(f"a cell is given twice: {' '.join(c.label for c in cells)}")
    if not a.checkpoints and not a.controllers:
        p.error("nothing to benchmark: give checkpoints or --controllers")
    perturbations = [] if a.perturb is None else list(a.perturb or PERTURBATIONS)
    for name in perturbations:
        if name not in PERTURBATIONS:
            p.error(f"--perturb: unknown perturbation {name!r}; known: {', '.join(PERTURBATIONS)}")
    B.ThreadGovernor(a.threads)
    methods, base = load_methods(a.checkpoints, a.controllers, parse_sets(p, "--set", a.set))
    # Every cell's configs (and the scenario check of each checkpoint) before any episode runs.
    cfgs = {c.label: dict(zip([n for n, _, _ in methods], method_configs(methods, base, c.config, CHECK_EPISODES, c.seed, c.label)))
            for c in cells}
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, dict[str, Any]] = {n: {} for n, _, _ in methods}
    planning: dict[str, dict[str, Any]] = {}
    reference: dict[str, dict[str, Any]] = {}  # per cell: the shortest paths' statistics
    robustness: dict[str, dict[str, dict[str, Any]]] = {}  # perturbation -> method -> cell -> summary
    t0 = time.perf_counter()
    for i, c in enumerate(cells):
        what = f"map {c.name}" if c.kind == "map" else f"{c.name} worlds at difficulty {c.difficulty:g}"
        print(f"[{i + 1}/{len(cells)}] {c.label}: {what}, seed {c.seed}, {a.episodes} episodes", flush=True)
        # every method plays the same episodes (method_configs checked): one shortest path each, for all of them
        t_ref = time.perf_counter()
        shortest = shortest_episode_paths(cfgs[c.label][methods[0][0]], a.episodes, seed=c.seed, device=a.device)
        reference[c.label] = {"seconds": round(time.perf_counter() - t_ref, 2), "no_path": int((~shortest.isfinite()).sum()),
                              "mean_m": float(shortest[shortest.isfinite()].mean()) if shortest.isfinite().any() else None}
        for name, policy, _ in methods:
            if not runs_on(policy, c):
                results[name][c.label] = None
                print(f"[{c.label}] {name:<22} n/a (a planner needs a map's spec)", flush=True)
                continue
            results[name][c.label], stats = evaluate_method(name, policy, cfgs[c.label][name], a.episodes, c.seed, a.device, c.label,
                                                            shortest=shortest)
            if stats is not None:
                planning.setdefault(name, {})[c.label] = stats
            for pert in perturbations:  # the same method under each perturbation (their own episodes: randomisation draws)
                s, _ = evaluate_method(f"{name} [{pert}]", policy, perturbed(cfgs[c.label][name], pert), a.episodes, c.seed, a.device, c.label)
                robustness.setdefault(pert, {}).setdefault(name, {})[c.label] = s
        done = time.perf_counter() - t0
        print(f"    {done:.0f} s so far, about {done / (i + 1) * (len(cells) - i - 1):.0f} s to go", flush=True)
        doc = document(a, levels, cells, methods, cfgs, results, planning, reference, robustness, complete=i + 1 == len(cells))
        (out / "results.json").write_text(json.dumps(doc, indent=2))
        (out / "results.md").write_text(markdown(results, cells, a.episodes) + robustness_tables(results, robustness, cells))
    print("\n" + markdown(results, cells, a.episodes) + robustness_tables(results, robustness, cells))
    heatmap(results, cells, a.episodes, a.seed).savefig(out / "heatmap.png", dpi=110)
    print(f"wrote {out / 'results.json'}, {out / 'results.md'}, {out / 'heatmap.png'}")
    return doc


if __name__ == "__main__":
    from torchnav.memory import hold_freed_memory

    hold_freed_memory()  # big evaluation batches reuse their freed memory (docs/performance.md, "Memory allocator")
    B.main_guard(main)
