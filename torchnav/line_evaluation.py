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

from functools import partial
from typing import Any, Callable

import torch
from tensordict import TensorDictBase

from .envs.line_env import LineEnv
from .evaluation import format_table, run_batched_episodes, summarize_outcomes
from .tasks.line_config import LineConfig

OUTCOMES = ("lap_complete", "left_line", "stalled", "collision", "timeout")


def run_line_episodes(
    policy: Callable[[TensorDictBase], TensorDictBase],
    cfg: LineConfig,
    n_episodes: int,
    seed: int = 0,
    laps: int = 1,
    device: torch.device | str = "cpu",
    max_batch: int = 4096,
    progress: str | None = None,
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
    return run_batched_episodes(policy, lambda n, s: LineEnv(cfg, num_envs=n, device=device, seed=s), partial(lap_outcome, laps=laps),
                                n_episodes, seed, max_batch, progress)


def lap_outcome(nxt: TensorDictBase, laps: int = 1) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """A line-following episode is judged when it completes ``laps`` laps or ends without them."""
    ep = nxt["episode"]
    flat = lambda x: x.reshape(-1)  # noqa: E731
    lap = flat(ep["laps"]) >= laps
    left, stalled = flat(nxt["left_line"]), flat(nxt["stalled"])
    lap_time = flat(ep["lap_time"])
    values = {
        "lap_complete": lap,
        "left_line": ~lap & left,
        "stalled": ~lap & ~left & stalled,
        "collision": ~lap & ~left & ~stalled & flat(nxt["collision"]),
        "timeout": ~lap & flat(nxt["truncated"]),
        "lap_time": torch.where(flat(ep["laps"]) >= 1, lap_time, torch.full_like(lap_time, float("nan"))),
        "length": flat(ep["length"]), "lap_fraction": flat(ep["lap_fraction"]),
        "time_off_line": flat(ep["time_off_line"]), "return": flat(ep["return"]),
    }
    return lap | flat(nxt["done"]), values


def summarize_laps(res: dict[str, torch.Tensor], dt: float = 0.05) -> dict[str, Any]:
    """Outcome rates with Wilson intervals; lap time (s, completed laps) and lap fraction (all
    episodes) with normal intervals; the fraction of driving time with no sensor on the line
    (``off_line``, ``dt`` s per step)."""
    out = summarize_outcomes(res, OUTCOMES, {"lap_time": res["lap_time"][res["lap_complete"]], "lap_fraction": res["lap_fraction"],
                                             "return": res["return"]})
    total = float((res["length"] * dt).sum())
    out["off_line"] = {"fraction": float(res["time_off_line"].sum()) / total if total > 0 else float("nan")}
    return out


def format_lap_summary(s: dict[str, Any], title: str = "") -> str:
    """A small fixed-width table of :func:`summarize_laps` output."""
    table = format_table(s, title, OUTCOMES, (("lap_time", "s"), ("lap_fraction", "laps"), ("return", "")), width=6)
    return table + f"\n  {'off_line':<14}{100 * s['off_line']['fraction']:6.1f} %   of driving time"
