"""Lap-completion evaluation for the line-following task, with 95% confidence intervals.

Each env of the batch runs one episode from its own random start on the track
(the config's reset noise applies). The episode's outcome is read at its first
event: the target number of laps completed (``lap_complete``), or the episode
ended without it (``left_line``, ``stalled``, ``collision`` or ``timeout`` at
``cfg.max_steps``). The recipe target, "a full lap of the course from at least
95% of random starts", is ``summarize_laps(...)["lap_complete"]["rate"] >= 0.95``.

    from torchnav.line_evaluation import run_line_episodes, summarize_laps, format_lap_summary
    res = run_line_episodes(policy, LineConfig(track="course"), n_episodes=1000, seed=0)
    print(format_lap_summary(summarize_laps(res), title="course"))
"""

from __future__ import annotations

from typing import Any, Callable

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from .envs.line_env import LineEnv
from .evaluation import bind_policy, mean_interval, wilson_interval
from .tasks.line_config import LineConfig

OUTCOMES = ("lap_complete", "left_line", "stalled", "collision", "timeout")
_FLOATS = ("lap_time", "length", "lap_fraction", "time_off_line", "return")


@torch.no_grad()
def run_line_episodes(
    policy: Callable[[TensorDictBase], TensorDictBase],
    cfg: LineConfig,
    n_episodes: int,
    seed: int = 0,
    laps: int = 1,
    device: torch.device | str = "cpu",
    max_batch: int = 4096,
) -> dict[str, torch.Tensor]:
    """Run ``n_episodes`` episodes (one per env, in batches of at most ``max_batch``) with the
    deterministic ``policy`` until each completes ``laps`` laps or ends.

    A policy with a ``bind(env)`` method (e.g. ``LineFollower``) is bound to each env.
    Returns per-episode tensors: the bool outcomes :data:`OUTCOMES` (exactly one is True),
    ``lap_time`` (s to the first lap, nan without one), ``length`` (steps), ``lap_fraction``,
    ``time_off_line`` (s) and ``return`` at the outcome.
    """
    if laps < 1:
        raise ValueError(f"laps must be >= 1, got {laps}")
    parts: dict[str, list[torch.Tensor]] = {k: [] for k in OUTCOMES + _FLOATS}
    done, chunk = 0, 0
    while done < n_episodes:
        n = min(max_batch, n_episodes - done)
        env = LineEnv(cfg, num_envs=n, device=device, seed=seed + 7919 * chunk)
        bind_policy(policy, env)
        for k, v in _until_lap(policy, env, laps).items():
            parts[k].append(v.cpu())
        done += n
        chunk += 1
    return {k: torch.cat(v) for k, v in parts.items()}


def _until_lap(policy, env: LineEnv, laps: int) -> dict[str, torch.Tensor]:
    n, dev = env.num_envs, env.device
    finished = torch.zeros(n, dtype=torch.bool, device=dev)
    out = {k: torch.zeros(n, dtype=torch.bool, device=dev) for k in OUTCOMES}
    out.update({k: torch.full((n,), float("nan"), device=dev) for k in _FLOATS})
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(env.cfg.max_steps):
            td = env.step(policy(td))
            nxt = td["next"]
            ep = nxt["episode"]
            flat = lambda x: x.reshape(-1)  # noqa: E731
            lap = flat(ep["laps"]) >= laps
            ended = flat(nxt["done"])
            new = (lap | ended) & ~finished
            if new.any():
                outcome = {
                    "lap_complete": lap,
                    "left_line": ~lap & flat(nxt["left_line"]),
                    "stalled": ~lap & ~flat(nxt["left_line"]) & flat(nxt["stalled"]),
                    "collision": ~lap & ~flat(nxt["left_line"]) & ~flat(nxt["stalled"]) & flat(nxt["collision"]),
                    "timeout": ~lap & flat(nxt["truncated"]),
                }
                for k, v in outcome.items():
                    out[k] = torch.where(new, v, out[k])
                lap_time = torch.where(flat(ep["laps"]) >= 1, flat(ep["lap_time"]), torch.full_like(flat(ep["lap_time"]), float("nan")))
                vals = {"lap_time": lap_time, "length": flat(ep["length"]), "lap_fraction": flat(ep["lap_fraction"]),
                        "time_off_line": flat(ep["time_off_line"]), "return": flat(ep["return"])}
                for k, v in vals.items():
                    out[k] = torch.where(new, v.to(out[k].dtype), out[k])
                finished |= new
                if finished.all():
                    break
            td = nxt.exclude("reward", "done", "terminated", "truncated")
    return out


def summarize_laps(res: dict[str, torch.Tensor], dt: float = 0.05) -> dict[str, Any]:
    """Outcome rates with Wilson intervals; lap time (s, completed laps) and lap fraction (all
    episodes) with normal intervals; the fraction of driving time with no sensor on the line
    (``off_line``, ``dt`` s per step)."""
    n = res["lap_complete"].numel()
    out: dict[str, Any] = {"episodes": n}
    for k in OUTCOMES:
        c = int(res[k].sum())
        lo, hi = wilson_interval(c, n)
        out[k] = {"rate": c / n if n else float("nan"), "ci95": [lo, hi], "count": c}
    ok = res["lap_complete"]
    for k, x in (("lap_time", res["lap_time"][ok]), ("lap_fraction", res["lap_fraction"]), ("return", res["return"])):
        m, lo, hi = mean_interval(x)
        out[k] = {"mean": m, "ci95": [lo, hi]}
    total = float((res["length"] * dt).sum())
    out["off_line"] = {"fraction": float(res["time_off_line"].sum()) / total if total > 0 else float("nan")}
    return out


def format_lap_summary(s: dict[str, Any], title: str = "") -> str:
    """A small fixed-width table of :func:`summarize_laps` output."""
    rows = [f"{title}  ({s['episodes']} episodes)" if title else f"{s['episodes']} episodes"]
    for k in OUTCOMES:
        r = s[k]
        rows.append(f"  {k:<14}{100 * r['rate']:6.1f} %   95% CI [{100 * r['ci95'][0]:5.1f}, {100 * r['ci95'][1]:5.1f}]")
    for k, unit in (("lap_time", "s"), ("lap_fraction", "laps"), ("return", "")):
        r = s[k]
        rows.append(f"  {k:<14}{r['mean']:8.2f} {unit:<6} 95% CI [{r['ci95'][0]:.2f}, {r['ci95'][1]:.2f}]")
    rows.append(f"  {'off_line':<14}{100 * s['off_line']['fraction']:6.1f} %   of driving time")
    return "\n".join(rows)
