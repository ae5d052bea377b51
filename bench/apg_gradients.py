"""How the analytic policy gradient of recipes/apg_lidar.py behaves as the horizon grows.

    python bench/apg_gradients.py runs/study18/apg_lidar/seed0/checkpoint.pt --horizons 8 32 128 512

For a trained APG run (its ``checkpoint.pt``: policy and critic), and for each horizon H:
draw ``--repeats`` independent batches (``--envs`` arena episodes each, fresh starts,
goals and exploration noise), backpropagate the horizon loss through H simulator steps
(the critic bootstrapping the end, as in training), and report the gradient's norm
(median and largest over the repeats) and the mean cosine similarity between the
gradients of different batches: near 1 when every batch points the same way, near 0
when the gradient is noise. Prints one Markdown row per horizon; ``--json`` also writes them.
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "recipes"))


def main(argv: list[str]) -> list[dict]:
    import apg_lidar

    from torchnav.checkpoint import load_checked
    from torchnav.envs import NavEnv
    from torchnav.policy import Actor, load_policy
    from torchnav.train_config import build

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", help="an apg_lidar run's checkpoint.pt")
    p.add_argument("--horizons", type=int, nargs="+", default=[8, 32, 128, 512])
    p.add_argument("--envs", type=int, default=32)
    p.add_argument("--repeats", type=int, default=4)
    p.add_argument("--seed", type=int, default=30_000, help="env seed of the first batch (the others follow)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    ck = load_checked(a.checkpoint)
    if ck.get("format") != "torchnav-apg-lidar-v1":
        raise SystemExit(f"{a.checkpoint}: not an apg_lidar checkpoint")
    cfg = build("apg_lidar", ck["config"], source=str(a.checkpoint))
    sp = load_policy(a.checkpoint)
    obs_size = sp.actor.obs_size
    loc_net = Actor(obs_size, 2, cfg.train.hidden, cfg.train.activation, output="linear")
    loc_net.load_state_dict(ck["actor"])
    critic = Actor(obs_size, 1, cfg.train.hidden, cfg.train.activation, output="linear").requires_grad_(False)
    critic.load_state_dict(ck["critic_target"])
    params = list(loc_net.parameters())
    rows = []
    for h in a.horizons:
        grads, t0 = [], time.perf_counter()
        for r in range(a.repeats):
            env = NavEnv(sp.config(), num_envs=a.envs, seed=a.seed + r)
            env.reset()
            smooth = apg_lidar.make_smooth("nav", cfg.smooth, env)
            torch.manual_seed(a.seed + r)
            batch = apg_lidar.rollout(env, loc_net, critic, smooth, h, float(cfg.train.gamma), float(cfg.train.expl_sigma_end),
                                      ("success", "collision"))
            g = torch.autograd.grad(apg_lidar.horizon_loss(batch), params)
            grads.append(torch.cat([x.reshape(-1) for x in g]))
        norms = [float(g.norm()) for g in grads]
        cos = [float(torch.nn.functional.cosine_similarity(x, y, dim=0)) for x, y in itertools.combinations(grads, 2)]
        rows.append({"horizon": h, "norm_median": statistics.median(norms), "norm_max": max(norms),
                     "cosine_mean": statistics.mean(cos), "finite": all(torch.isfinite(g).all() for g in grads),
                     "seconds": time.perf_counter() - t0})
    print(f"| horizon | gradient norm: median | largest | mean cosine between batches ({a.repeats} batches of {a.envs} envs) | finite |")
    print("|---:|---:|---:|---:|---|")
    for r in rows:
        print(f"| {r['horizon']} | {r['norm_median']:.3g} | {r['norm_max']:.3g} | {r['cosine_mean']:.2f} | {r['finite']} |")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=2))
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
