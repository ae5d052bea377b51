"""The shipped generalist on the Jackal preset with a one- or two-step actuator delay: success and collisions on two
suite cells with the straight-line speed guard and the arc guard (docs/results.md, "A Jackal-class robot").

    python docs/scripts/guard_arc.py

The episodes are the benchmark suite's (its cell seeds, recipes/benchmark.py), 200 per cell by default.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "recipes"))

import benchmark as bm  # noqa: E402
import torch  # noqa: E402

from torchnav.config import merge, to_dict  # noqa: E402
from torchnav.evaluation import run_episodes, summarize  # noqa: E402
from torchnav.maps import available_maps  # noqa: E402
from torchnav.policy import load_policy  # noqa: E402
from torchnav.tasks import NavConfig  # noqa: E402
from torchnav.tasks.robots import override_config  # noqa: E402

CELLS = ("warehouse", "rooms/medium")
CASES = {"delay 1": {"robot": {"preset": "jackal"}}, "delay 2": {"robot": {"preset": "jackal"}, "randomize": {"delay": [2, 2]}}}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", default=str(ROOT / "checkpoints" / "ppo_generalist_actor.pt"))
    p.add_argument("--episodes", type=int, default=200)
    a = p.parse_args(argv)
    if a.episodes < 1:
        p.error("--episodes must be >= 1")
    torch.set_num_threads(1)
    sp = load_policy(a.checkpoint)
    cells = {c.label: c for c in bm.suite(available_maps(), ["rooms", "corridors", "fences"], {"medium": 0.5}, bm.SEED_BASE)}
    print(f"# {a.checkpoint}, {a.episodes} episodes a cell")
    for label in CELLS:
        for name, extra in CASES.items():
            for path in ("straight", "arc"):
                over = merge(extra, {"action": {"stop_path": path}})
                cfg = NavConfig.from_dict(override_config(to_dict(cells[label].config(sp.config())), over))
                s = summarize(run_episodes(sp.policy, cfg, a.episodes, seed=cells[label].seed))
                print(f"{label:14s} {name:8s} {path:9s} success {100 * s['success']['rate']:5.1f} %  "
                      f"collision {100 * s['collision']['rate']:5.1f} %", flush=True)


if __name__ == "__main__":
    main()
