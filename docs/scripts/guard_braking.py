"""The shipped generalist with bounded braking: success and collisions on suite cells with 1 m/s^2 and 3 rad/s^2
acceleration limits, without and with a one-step actuator delay (docs/results.md, "Bounded braking").

    python docs/scripts/guard_braking.py                    # the speed guard as it plans: braking and delay
    python docs/scripts/guard_braking.py --instant-stop     # the guard planning an instant stop, for comparison

The episodes are the benchmark suite's (its cell seeds, recipes/benchmark.py), 200 per cell by default.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "recipes"))

import benchmark as bm  # noqa: E402
import torch  # noqa: E402

from torchnav import observation  # noqa: E402
from torchnav.config import merge, to_dict  # noqa: E402
from torchnav.evaluation import run_episodes, summarize  # noqa: E402
from torchnav.maps import available_maps  # noqa: E402
from torchnav.policy import load_policy  # noqa: E402
from torchnav.tasks import NavConfig  # noqa: E402

CELLS = ("arena", "street", "warehouse", "rooms/medium", "corridors/medium", "fences/medium")
LIMITS = {"lin_acc_max": 1.0, "ang_acc_max": 3.0}
CASES = {"acc": {"robot": LIMITS}, "acc+delay": {"robot": LIMITS, "randomize": {"delay": [1, 1]}}}


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", default=str(ROOT / "checkpoints" / "ppo_generalist_actor.pt"))
    p.add_argument("--episodes", type=int, default=200)
    p.add_argument("--instant-stop", action="store_true", help="the guard plans an instant stop (no braking, no delay)")
    a = p.parse_args(argv)
    if a.episodes < 1:
        p.error("--episodes must be >= 1")
    if a.instant_stop:
        observation.guard_dynamics = lambda cfg: (math.inf, 0)
    torch.set_num_threads(1)
    sp = load_policy(a.checkpoint)
    cells = {c.label: c for c in bm.suite(available_maps(), ["rooms", "corridors", "fences"], {"medium": 0.5}, bm.SEED_BASE)}
    print(f"# {a.checkpoint}, {a.episodes} episodes a cell, guard {'planning an instant stop' if a.instant_stop else 'with braking and delay'}")
    for label in CELLS:
        for name, extra in CASES.items():
            cfg = NavConfig.from_dict(merge(to_dict(cells[label].config(sp.config())), extra))
            s = summarize(run_episodes(sp.policy, cfg, a.episodes, seed=cells[label].seed))
            print(f"{label:18s} {name:10s} success {100 * s['success']['rate']:5.1f} %  collision {100 * s['collision']['rate']:5.1f} %  "
                  f"timeout {100 * s['timeout']['rate']:5.1f} %", flush=True)


if __name__ == "__main__":
    main()
