"""Evaluate a policy on many seeded episodes at once and summarise with 95% confidence intervals.

Each env of the batch runs exactly one episode; its outcome is read at its first
``done``. ``goals anywhere`` evaluation is the default: the curriculum is off, so
goals are drawn over the whole map.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from .config import merge, to_dict
from .envs import NavEnv
from .tasks import NavConfig

Z95 = 1.959964


def wilson_interval(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """95% Wilson score interval for a binomial rate ``k / n``."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def mean_interval(x: torch.Tensor, z: float = Z95) -> tuple[float, float, float]:
    """Mean and normal-approximation 95% interval of a 1-D sample (nan if empty)."""
    n = x.numel()
    if n == 0:
        return (float("nan"), float("nan"), float("nan"))
    m = x.double().mean().item()
    if n == 1:
        return (m, m, m)
    half = z * x.double().std().item() / math.sqrt(n)
    return (m, m - half, m + half)


def eval_config(cfg: NavConfig, map: str | None = None, anywhere: bool = True,
                worlds: Mapping[str, Any] | None = None) -> NavConfig:
    """``cfg`` for evaluation: optionally another map; with ``anywhere`` the curriculum is off.

    ``map`` also turns procedural worlds off, so a policy trained on generated worlds is
    evaluated on that map. ``worlds``: keys of the ``worlds`` section that replace those
    of ``cfg`` (``families`` are replaced, not merged), e.g. ``{"families": {"forest":
    1.0}, "difficulty": 0.5}``; the difficulty curriculum is off, so the difficulty is the
    one given (or ``cfg``'s ``worlds.difficulty``).

    With procedural worlds and ``anywhere``, the difficulty is fixed too: at
    ``worlds.max_difficulty`` when training used the difficulty curriculum (its target),
    else at ``worlds.difficulty``.
    """
    if map is not None and worlds is not None:
        raise ValueError("eval_config: give a map or procedural worlds, not both")
    d = to_dict(cfg)
    over: dict[str, Any] = {}
    if map is not None:
        over["map"] = map
        d["worlds"] = {**d["worlds"], "families": {}}
    if worlds is not None:
        d["worlds"] = {**d["worlds"], **worlds, "curriculum": False}
    if anywhere:
        over["curriculum"] = {"mode": "off"}
        w = d["worlds"]
        if w["families"]:
            over["worlds"] = {"curriculum": False, "difficulty": w["max_difficulty"] if w["curriculum"] else w["difficulty"]}
    return NavConfig.from_dict(merge(d, over))


@torch.no_grad()
def run_episodes(
    policy: Callable[[TensorDictBase], TensorDictBase],
    cfg: NavConfig,
    n_episodes: int,
    seed: int = 0,
    device: torch.device | str = "cpu",
    max_batch: int = 4096,
) -> dict[str, torch.Tensor]:
    """Run ``n_episodes`` episodes (one per env, in batches of at most ``max_batch`` envs).

    A policy with a ``bind`` method is bound to each env created here (``policy.bind(env)``).
    Returns per-episode tensors: ``success``, ``collision``, ``timeout`` (bool),
    ``length`` (steps), ``return``, ``path_length`` and ``straight_line`` (m).
    """
    keys = ("success", "collision", "timeout", "length", "return", "path_length", "straight_line")
    parts: dict[str, list[torch.Tensor]] = {k: [] for k in keys}
    done_so_far = 0
    chunk_id = 0
    while done_so_far < n_episodes:
        n = min(max_batch, n_episodes - done_so_far)
        env = NavEnv(cfg, num_envs=n, device=device, seed=seed + 7919 * chunk_id)
        bind_policy(policy, env)
        res = _one_episode_each(policy, env)
        for k in keys:
            parts[k].append(res[k].cpu())
        done_so_far += n
        chunk_id += 1
    return {k: torch.cat(v) for k, v in parts.items()}


def bind_policy(policy: Any, env: NavEnv) -> None:
    """Call ``policy.bind(env)`` if the policy has one (classical planners read the env's worlds)."""
    bind = getattr(policy, "bind", None)
    if callable(bind):
        bind(env)


def _one_episode_each(policy, env: NavEnv) -> dict[str, torch.Tensor]:
    n = env.num_envs
    finished = torch.zeros(n, dtype=torch.bool, device=env.device)
    out = {k: torch.zeros(n, dtype=torch.bool if k in ("success", "collision", "timeout") else torch.float32, device=env.device)
           for k in ("success", "collision", "timeout", "length", "return", "path_length", "straight_line")}
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(env.cfg.max_steps):
            td = env.step(policy(td))
            nxt = td["next"]
            new = nxt["done"].reshape(-1) & ~finished
            if new.any():
                ep = nxt["episode"]
                vals = {
                    "success": nxt["success"].reshape(-1), "collision": nxt["collision"].reshape(-1),
                    "timeout": nxt["truncated"].reshape(-1), "length": ep["length"].reshape(-1),
                    "return": ep["return"].reshape(-1), "path_length": ep["path_length"].reshape(-1),
                    "straight_line": ep["straight_line"].reshape(-1),
                }
                for k, v in vals.items():
                    out[k] = torch.where(new, v.to(out[k].dtype), out[k])
                finished |= new
                if finished.all():
                    break
            td = nxt.exclude("reward", "done", "terminated", "truncated")
    return out


def summarize(res: dict[str, torch.Tensor]) -> dict[str, Any]:
    """Rates with Wilson intervals; mean steps to goal (successful episodes) and path-length
    ratio (path / straight line, successful episodes) with normal intervals."""
    n = res["success"].numel()
    out: dict[str, Any] = {"episodes": n}
    for k in ("success", "collision", "timeout"):
        c = int(res[k].sum())
        lo, hi = wilson_interval(c, n)
        out[k] = {"rate": c / n if n else float("nan"), "ci95": [lo, hi], "count": c}
    s = res["success"]
    m, lo, hi = mean_interval(res["length"][s])
    out["steps_to_goal"] = {"mean": m, "ci95": [lo, hi]}
    ratio = res["path_length"][s] / res["straight_line"][s].clamp(min=1e-6)
    m, lo, hi = mean_interval(ratio)
    out["path_ratio"] = {"mean": m, "ci95": [lo, hi]}
    m, lo, hi = mean_interval(res["return"])
    out["return"] = {"mean": m, "ci95": [lo, hi]}
    return out


def format_summary(s: dict[str, Any], title: str = "") -> str:
    """A small fixed-width table of ``summarize`` output."""
    rows = [f"{title}  ({s['episodes']} episodes)" if title else f"{s['episodes']} episodes"]
    for k in ("success", "collision", "timeout"):
        r = s[k]
        rows.append(f"  {k:<14}{100 * r['rate']:6.1f} %   95% CI [{100 * r['ci95'][0]:5.1f}, {100 * r['ci95'][1]:5.1f}]")
    for k, unit in (("steps_to_goal", "steps"), ("path_ratio", "x straight"), ("return", "")):
        r = s[k]
        rows.append(f"  {k:<14}{r['mean']:8.2f} {unit:<10} 95% CI [{r['ci95'][0]:.2f}, {r['ci95'][1]:.2f}]")
    return "\n".join(rows)


@torch.no_grad()
def record_episodes(
    policy: Callable[[TensorDictBase], TensorDictBase],
    cfg: NavConfig,
    path,
    n_episodes: int,
    seed: int = 0,
    device: torch.device | str = "cpu",
    metadata: dict[str, Any] | None = None,
) -> Any:
    """Write ``n_episodes`` episodes of the deterministic ``policy`` (one per env) to an MCAP file.

    Returns the recorder (its ``error`` is set, and a warning was issued, if the file
    could not be written; training code can carry on).
    """
    from .record import EpisodeRecorder, record_rollout

    env = NavEnv(cfg, num_envs=n_episodes, device=device, seed=seed)
    bind_policy(policy, env)
    meta = {"seed": seed, **(metadata or {})}
    with EpisodeRecorder(path, env, envs=range(n_episodes), metadata=meta, episodes=1) as rec:
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            record_rollout(env, policy, max_steps=cfg.max_steps, recorder=rec, stack=False)
    return rec
