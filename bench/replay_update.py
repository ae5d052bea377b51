"""The cost of one TD3 gradient step at the quick start's sizes, two layouts timed in turns in one process.

    python bench/replay_update.py
    python bench/replay_update.py --hidden 256 256 --rounds 15 --threads 1

A round is ``--updates`` gradient steps (the recipe's ``train.updates_per_batch``) of ``--batch-size``
transitions from a replay buffer of ``--buffer`` random transitions, each step ``recipes/td3_lidar.py``'s
own (``make_step``, at the recipe's defaults: critics every step; actor and targets every second):

- ``separate``: two critics as two TorchRL MLPs, one ``buffer.sample()`` per step (the layout before
  ``recipes/builders.py``'s stacked ``TwinQ``);
- ``stacked``: ``builders.TwinQ`` (both critics' weights stacked, one batched matmul per layer) and
  every step's minibatch drawn in one call, as ``builders.replay_updates`` does.

The two layouts alternate for ``--rounds`` rounds; the script prints each one's median, fastest and
slowest milliseconds per gradient step and the ratio of the medians. On a 2-core VM the same code
reads up to a quarter apart between processes, so compare layouts only within one run.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "recipes"))
import common  # noqa: E402
import torch  # noqa: E402
from tensordict import TensorDict  # noqa: E402
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer  # noqa: E402
from torchrl.modules import MLP  # noqa: E402

import builders as B  # noqa: E402
import td3_lidar  # noqa: E402
from torchnav.policy import Actor  # noqa: E402
from torchnav.train_config import TD3Train  # noqa: E402

OBS, ACT = 24, 2  # the lidar navigation task's observation and action sizes


class SeparateQ(torch.nn.Module):
    """The reference layout: two independent TorchRL MLPs over the concatenated observation and action."""

    def __init__(self, hidden: list[int]) -> None:
        super().__init__()
        make = lambda: MLP(in_features=OBS + ACT, out_features=1, num_cells=hidden, activation_class=torch.nn.ReLU)  # noqa: E731
        self.first, self.second = make(), make()

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.cat((obs, action), dim=-1)
        return self.first(x), self.second(x)

    def q1(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.first(torch.cat((obs, action), dim=-1))


def make_update(critic: torch.nn.Module, hidden: list[int]):
    """``step(sample)``: recipes/td3_lidar.py's gradient step (its ``make_step``, the recipe's defaults) with this
    critic module."""
    actor = Actor(OBS, ACT, hidden)
    actor_target, critic_target = copy.deepcopy(actor).requires_grad_(False), copy.deepcopy(critic).requires_grad_(False)
    tc = TD3Train()
    opt_actor, opt_critic = B.adam(actor.parameters(), lr=tc.lr_actor), B.adam(critic.parameters(), lr=tc.lr_critic)
    done = [0]
    step = td3_lidar.make_step(tc, actor, critic, actor_target, critic_target, opt_actor, opt_critic, lambda: done[0])

    def counted(sample) -> None:
        step(sample)
        done[0] += 1

    return counted


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads (default 2, the recipe's on a 2-core machine)")
    p.add_argument("--hidden", type=int, nargs="+", default=[128, 128], help="hidden sizes of actor and critics (default 128 128)")
    p.add_argument("--batch-size", type=int, default=256, help="transitions per gradient step (default 256)")
    p.add_argument("--updates", type=int, default=128, help="gradient steps per round (default 128)")
    p.add_argument("--rounds", type=int, default=11, help="timed rounds of each layout, alternating (default 11)")
    p.add_argument("--buffer", type=int, default=100_000, help="random transitions in the replay buffer (default 100,000)")
    args = p.parse_args()
    for name in ("threads", "batch_size", "updates", "rounds", "buffer"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    if min(args.hidden) < 1:
        p.error(f"--hidden sizes must be at least 1, got {args.hidden}")
    common.set_threads(args.threads)
    common.print_header("TD3 gradient step: separate against stacked critics", "cpu", sys.stdout)
    torch.manual_seed(0)
    n = args.buffer
    data = TensorDict({"observation": torch.randn(n, OBS), "action": torch.rand(n, ACT) * 2 - 1,
                       "next": {"observation": torch.randn(n, OBS), "reward": torch.randn(n, 1), "discount": torch.full((n, 1), 0.97),
                                "done": torch.zeros(n, 1, dtype=torch.bool), "terminated": torch.zeros(n, 1, dtype=torch.bool)}},
                      batch_size=[n])
    per_step = TensorDictReplayBuffer(storage=LazyTensorStorage(n), batch_size=args.batch_size)
    per_round = TensorDictReplayBuffer(storage=LazyTensorStorage(n))
    per_step.extend(data)
    per_round.extend(data)
    separate, stacked = make_update(SeparateQ(args.hidden), args.hidden), make_update(B.TwinQ(OBS, ACT, args.hidden), args.hidden)
    u, b = args.updates, args.batch_size

    def separate_round() -> None:
        for _ in range(u):
            separate(per_step.sample())

    def stacked_round() -> None:
        for sample in per_round.sample(u * b).reshape(u, b).unbind(0):
            stacked(sample)

    layouts = {"separate": separate_round, "stacked": stacked_round}
    ms: dict[str, list[float]] = {k: [] for k in layouts}
    for fn in layouts.values():  # warm-up round
        fn()
    for _ in range(args.rounds):
        for name, fn in layouts.items():
            t = time.perf_counter()
            fn()
            ms[name].append((time.perf_counter() - t) / u * 1e3)
    print(f"\n{args.rounds} rounds of {u} gradient steps, batch {b}, hidden {args.hidden}, {args.threads} thread(s)\n")
    print("| layout | ms per gradient step (median) | fastest | slowest |")
    print("|---|---:|---:|---:|")
    for name, v in ms.items():
        print(f"| {name} | {statistics.median(v):.3f} | {min(v):.3f} | {max(v):.3f} |")
    ratio = statistics.median(ms["stacked"]) / statistics.median(ms["separate"])
    print(f"\nstacked / separate: {ratio:.2f} of the time per gradient step")


if __name__ == "__main__":
    main()
