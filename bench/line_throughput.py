"""Line-following throughput in env-steps/s: the pure task step (``LineTask.step`` + masked
resets) and the TorchRL env (``LineEnv.step`` + ``maybe_reset``), with fixed wheel commands.

    python bench/line_throughput.py                      # course, 1024 and 4096 envs, 1 thread
    python bench/line_throughput.py --envs 256 --threads 2 --track oval

Figures and the machine they were measured on: docs/line.md.
"""

from __future__ import annotations

import argparse
import time

import torch
from torchrl.envs.utils import step_mdp

from torchnav.envs import LineEnv
from torchnav.tasks import LineConfig, LineTask


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="course")
    ap.add_argument("--envs", type=int, nargs="+", default=[1024, 4096])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    cfg = LineConfig.from_dict({"track": args.track})
    for n in args.envs:
        task = LineTask(cfg, n, device=args.device)
        gen = torch.Generator(device=args.device).manual_seed(0)
        a = torch.rand(n, 2, generator=gen, device=args.device) * 0.5 + 0.25
        st = task.initial_state(gen)
        for _ in range(10):
            st, out = task.step(st, a, gen)
        t0 = time.perf_counter()
        for _ in range(args.steps):
            st, out = task.step(st, a, gen)
            st = task.reset(st, out["terminated"] | out["truncated"], gen)
        task_rate = n * args.steps / (time.perf_counter() - t0)
        env = LineEnv(cfg, num_envs=n, device=args.device)
        td = env.reset()
        t0 = time.perf_counter()
        for _ in range(args.steps):
            td["action"] = a
            td = env.maybe_reset(step_mdp(env.step(td)))
        env_rate = n * args.steps / (time.perf_counter() - t0)
        print(f"{args.track:<8} {n:>6} envs  task {task_rate:>12,.0f} steps/s   env {env_rate:>12,.0f} steps/s   "
              f"(env/task {env_rate / task_rate:.2f}, {args.threads} thread(s), {args.device})")


if __name__ == "__main__":
    main()
