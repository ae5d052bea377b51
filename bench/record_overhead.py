"""Cost of recording one env of a large batch during an evaluation rollout.

    python bench/record_overhead.py [--num-envs 4096] [--steps 200] [--device cpu] [--repeats 3]

Runs the same evaluation rollout (``record_rollout`` with a fixed policy) with
recording off and with env 0 recorded to an MCAP file, alternating, and prints
the best-of-repeats times and their ratio (the minimum is the estimate least
disturbed by other load on a shared machine). It also times the recorder's own
calls (``write_step``, ``flush``, ``close``) inside the recorded runs, which
measures the cost directly and is robust to noise. The issue's target:
recording costs under 10% of evaluation time.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import torch

from torchnav.envs.nav_env import make_nav_env
from torchnav.record import EpisodeRecorder, record_rollout


def _time_calls(rec: EpisodeRecorder, acc: list) -> None:
    """Accumulate the wall time of the recorder's public calls into ``acc[0]``."""
    for name in ("write_step", "flush", "close"):
        fn = getattr(rec, name)

        def timed(*a, _fn=fn, **k):
            t = time.perf_counter()
            try:
                return _fn(*a, **k)
            finally:
                acc[0] += time.perf_counter() - t

        setattr(rec, name, timed)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--num-envs", type=int, default=4096)
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--repeats", type=int, default=8)
    ap.add_argument("--map", default="arena")
    args = ap.parse_args()

    env = make_nav_env(args.map, num_envs=args.num_envs, device=args.device, seed=0, max_steps=100)
    gen = torch.Generator(device=args.device).manual_seed(0)
    table = torch.rand(64, args.num_envs, 2, generator=gen, device=args.device) * 2 - 1
    step = {"i": 0}

    def policy(td):  # a cheap stand-in for an actor: precomputed actions
        step["i"] += 1
        return td.set("action", table[step["i"] % 64])

    def sync():
        if str(args.device).startswith("cuda"):
            torch.cuda.synchronize()

    record_rollout(env, policy, 10)  # warm-up
    off, on, inside = [], [], [0.0]
    with tempfile.TemporaryDirectory() as tmp:
        def run_off():
            sync(); t = time.perf_counter()
            record_rollout(env, policy, args.steps)
            sync(); off.append(time.perf_counter() - t)

        def run_on(r):
            path = Path(tmp) / f"bench{r}.mcap"
            sync(); t = time.perf_counter()
            with EpisodeRecorder(path, env, envs=(0,)) as rec:
                _time_calls(rec, inside)
                record_rollout(env, policy, args.steps, rec)
            sync(); on.append(time.perf_counter() - t)
            return path.stat().st_size

        for r in range(args.repeats):  # alternate the order to cancel drifts in machine load
            if r % 2:
                size = run_on(r)
                run_off()
            else:
                run_off()
                size = run_on(r)
    m_off, m_on = min(off), min(on)
    rec_share = inside[0] / sum(on)
    print(f"device={args.device} num_envs={args.num_envs} steps={args.steps} map={args.map} repeats={args.repeats}")
    print(f"evaluation without recording: {m_off:.3f} s ({args.steps * args.num_envs / m_off:,.0f} env-steps/s)")
    print(f"evaluation recording env 0:   {m_on:.3f} s (file {size / 1e6:.2f} MB)")
    print(f"  all runs off: {', '.join(f'{x:.2f}' for x in off)} s; on: {', '.join(f'{x:.2f}' for x in on)} s")
    med_off, med_on = statistics.median(off), statistics.median(on)
    print(f"wall-clock overhead (median of {args.repeats} interleaved runs): {100 * (med_on / med_off - 1):+.1f}%  (ratio {med_on / med_off:.3f}; target < 1.10)")
    print(f"wall-clock overhead (best of {args.repeats}): {100 * (m_on / m_off - 1):+.1f}%  (ratio {m_on / m_off:.3f})")
    print(f"time inside the recorder: {100 * rec_share:.2f}% of the recorded runs' time")


if __name__ == "__main__":
    main()
