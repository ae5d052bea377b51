"""Reward terms and presets: each term is computed raw, weighted, and reported on its own.

The raw terms of navigation (``TERMS``) and the presets are tabled in docs/tasks.md;
:func:`weighted` and :func:`sum_terms` are the mechanism both tasks use."""

from __future__ import annotations

from typing import Callable

import torch
from torch import Tensor

from ..config import ConfigError
from .config import RewardConfig

TERMS = ("goal", "collision", "velocity", "turning", "proximity", "progress", "spin", "step", "heading")

PRESETS: dict[str, dict[str, float]] = {
    # The classic lidar TD3 reward: +-100 at the end, else v/2 - |omega|/2 - r3/2.
    "classic": {"goal": 100.0, "collision": -100.0, "velocity": 0.5, "turning": -0.5, "proximity": -0.5},
    "progress": {"goal": 100.0, "collision": -100.0, "progress": 10.0, "spin": -0.5, "proximity": -1.0},
    "shaped": {"goal": 50.0, "collision": -10.0, "progress": 1.0, "step": -0.01, "heading": 0.1},
}


def resolve_weights(cfg: RewardConfig) -> dict[str, float]:
    """The preset's weights with ``cfg.weights`` applied; unknown presets or terms raise."""
    if cfg.preset not in PRESETS:
        raise ConfigError(f"reward.preset: unknown preset {cfg.preset!r}; available: {', '.join(PRESETS)}")
    for k in cfg.weights:
        if k not in TERMS:
            raise ConfigError(f"reward.weights: unknown term {k!r}; terms: {', '.join(TERMS)}")
    w = dict(PRESETS[cfg.preset])
    w.update(cfg.weights)
    return {k: float(v) for k, v in w.items() if k in TERMS}


def reward_terms(
    weights: dict[str, float],
    cfg: RewardConfig,
    *,
    success: Tensor,
    collision: Tensor,
    vel: Tensor,
    d_min: Tensor,
    progress: Tensor,
    bearing: Tensor,
) -> dict[str, Tensor]:
    """Weighted reward terms ``{name: (B,)}`` for the terms named in ``weights``.

    Args are ``(B,)`` tensors except ``vel`` ``(B, 2)``; booleans for success/collision.
    """
    alive = (~(success | collision)).to(vel.dtype)
    v, w = vel[:, 0], vel[:, 1]
    raw = {
        "goal": lambda: success.to(vel.dtype),
        "collision": lambda: collision.to(vel.dtype),
        "velocity": lambda: v * alive,
        "turning": lambda: w.abs() * alive,
        "proximity": lambda: torch.relu(cfg.proximity_distance - d_min) * alive,
        "progress": lambda: progress,
        "spin": lambda: torch.relu(w.abs() - cfg.spin_threshold) * alive,
        "step": lambda: torch.ones_like(v),
        "heading": lambda: torch.cos(bearing) * alive,
    }
    return weighted(weights, raw)


def weighted(weights: dict[str, float], raw: dict[str, Callable[[], Tensor]]) -> dict[str, Tensor]:
    """``{name: weight * raw term (B,)}`` for the terms named in ``weights``; a raw term is computed only
    when weighted (both tasks' reward terms go through here)."""
    return {k: wt * raw[k]() for k, wt in weights.items()}


def sum_terms(terms: dict[str, Tensor], ep_terms: Tensor) -> tuple[Tensor, Tensor]:
    """The weighted terms stacked ``(B, T)`` in their order (``ep_terms`` ``(B, T)`` gives the shape when
    there are none) and their sum, the step's reward ``(B,)``."""
    stacked = torch.stack(list(terms.values()), dim=-1) if terms else ep_terms[:, :0]
    return stacked, stacked.sum(-1)
