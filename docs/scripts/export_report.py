"""The size, cost and accuracy tables of docs/export.md: every shipped policy in every weight format.

    OMP_NUM_THREADS=1 python docs/scripts/export_report.py [--episodes 1000] [--seed 3000000] [--json out.json]

For each checkpoint in checkpoints/ and each weight format it exports the C code with
``--target cortex-m4f`` (1000 verification observations, built with arm-none-eabi-gcc and
run in qemu-system-arm: flash, RAM, instructions per inference), saves the quantised
policy (PyTorch with the dequantised weights: what the C code computes) as an actor.pt
in a temporary folder and evaluates it with recipes/evaluate.py on ``--episodes``
episodes from seed ``--seed`` (default 3,000,000: disjoint from the recipes' training
and evaluation seeds 10,000+ and 20,000+). Prints markdown tables. Needs the cortex-m4f
toolchain (see docs/export.md); one evaluation process at a time, one thread each.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

from torchnav.export import WEIGHT_FORMATS, export, quantized_actor
from torchnav.policy import load_policy, save_policy

ROOT = Path(__file__).resolve().parents[2]
CHECKPOINTS = ["td3_arena_actor", "ppo_arena_actor", "sac_arena_actor", "ppo_movers_actor", "ppo_generalist_actor",
               "ppo_generalist_jackal_actor", "ppo_course_actor", "dqn_course_actor"]


def evaluate(path: Path, episodes: int, seed: int, out: Path) -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    subprocess.run([sys.executable, str(ROOT / "recipes" / "evaluate.py"), str(path), "--episodes", str(episodes),
                    "--seed", str(seed), "--threads", "1", "--json", str(out)], check=True, env=env,
                   stdout=subprocess.DEVNULL)
    return json.loads(out.read_text())


def main(argv: list[str]) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=1000)
    p.add_argument("--seed", type=int, default=3_000_000)
    p.add_argument("--json", default=None, help="also write the rows as JSON here")
    p.add_argument("--only", nargs="*", default=CHECKPOINTS, help="checkpoint stems (default: all shipped)")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    with tempfile.TemporaryDirectory(prefix="export_report_") as tmp:
        tmp = Path(tmp)
        for stem in a.only:
            ckpt = ROOT / "checkpoints" / f"{stem}.pt"
            sp = load_policy(ckpt)
            for fmt in WEIGHT_FORMATS:
                r = export(sp, c_dir=tmp / f"{stem}_{fmt}", weights=fmt, target="cortex-m4f", verify=1000)
                m4 = r["cortex_m4f"]
                qpath = tmp / f"{stem}_{fmt}.pt"
                actor = sp.actor if fmt == "float32" else quantized_actor(sp.actor, fmt)
                save_policy(qpath, actor, task=sp.task, task_config=sp.task_config, algorithm=sp.algorithm,
                            action_table=sp.action_table)
                ev = evaluate(qpath, a.episodes, a.seed, tmp / f"{stem}_{fmt}.json")
                outcome = ev["success"] if sp.task == "nav" else ev["lap_complete"]  # reaching the goal / a full lap
                row = {"policy": stem, "weights": fmt, "flash_bytes": m4["flash_bytes"], "ram_bytes": m4["ram_bytes"],
                       "static_ram_bytes": m4["static_ram_bytes"], "stack_bytes": m4["stack_bytes"],
                       "policy_flash_bytes": m4["policy_text_bytes"] + m4["policy_rodata_bytes"] + m4["policy_data_bytes"],
                       "instructions": m4["instructions"], "fits": m4["fits"], "max_error": m4.get("action_max_abs_err"),
                       "q_max_error": m4.get("q_max_abs_err"), "success": outcome["rate"], "successes": outcome["count"],
                       "episodes": ev["episodes"], "seed": ev["seed"], "task": sp.task, "map": ev["map"]}
                rows.append(row)
                print(json.dumps(row), file=sys.stderr, flush=True)
    print("| policy | weights | flash (B) | RAM (B): data+bss + stack | instructions / inference | fits 256 KiB / 64 KiB | success (%) |")
    print("|---|---|---:|---:|---:|:---:|---:|")
    for r in rows:
        print(f"| `{r['policy']}` | {r['weights']} | {r['flash_bytes']:,} | {r['ram_bytes']:,}: {r['static_ram_bytes']:,} + "
              f"{r['stack_bytes']} | {r['instructions']:,} | {'yes' if r['fits'] else 'no'} | {100 * r['success']:.1f} |")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main(sys.argv[1:])
