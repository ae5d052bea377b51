"""The bootstrapped goal radius as explicit, savable state (0-d tensors on the env device)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .config import CurriculumConfig


@dataclass
class CurriculumState:
    radius: Tensor  # 0-d, m: current maximum goal distance
    placements: Tensor  # 0-d int64: goals placed so far
    success_rate: Tensor  # 0-d: exponential average of episode success (mode "success")

    @classmethod
    def initial(cls, cfg: CurriculumConfig, device=None, dtype=torch.float32) -> "CurriculumState":
        r0 = cfg.max_radius if cfg.mode == "off" else cfg.init_radius
        return cls(
            radius=torch.tensor(r0, dtype=dtype, device=device),
            placements=torch.tensor(0, dtype=torch.int64, device=device),
            success_rate=torch.tensor(0.0, dtype=dtype, device=device),
        )

    def state_dict(self) -> dict[str, Tensor]:
        return {"radius": self.radius.clone(), "placements": self.placements.clone(), "success_rate": self.success_rate.clone()}

    def load_state_dict(self, sd: dict[str, Tensor]) -> None:
        missing = {"radius", "placements", "success_rate"} - set(sd)
        if missing:
            raise KeyError(f"curriculum state is missing {sorted(missing)}")
        self.radius = sd["radius"].to(self.radius)
        self.placements = sd["placements"].to(self.placements)
        self.success_rate = sd["success_rate"].to(self.success_rate)


def after_placements(cur: CurriculumState, cfg: CurriculumConfig, n_placed: Tensor) -> CurriculumState:
    """Mode "growth": ``radius = min(max_radius, init_radius + growth * placements)``."""
    placements = cur.placements + n_placed
    radius = cur.radius
    if cfg.mode == "growth":
        radius = (cfg.init_radius + cfg.growth * placements.to(radius.dtype)).clamp(max=cfg.max_radius)
    return CurriculumState(radius=radius, placements=placements, success_rate=cur.success_rate)


def after_episodes(cur: CurriculumState, cfg: CurriculumConfig, done: Tensor, success: Tensor) -> CurriculumState:
    """Mode "success": fold finished episodes ``done`` ``(B,)`` with outcome ``success`` ``(B,)``
    into the success average, and grow the radius by ``success_step`` when it exceeds the threshold."""
    if cfg.mode != "success":
        return cur
    n = done.sum()
    # Each finished episode moves the average by `success_smoothing` towards its outcome.
    keep = (1.0 - cfg.success_smoothing) ** n.to(cur.success_rate.dtype)
    mean = (success & done).sum().to(cur.success_rate.dtype) / n.clamp(min=1)
    rate = torch.where(n > 0, keep * cur.success_rate + (1 - keep) * mean, cur.success_rate)
    grow = (n > 0) & (rate > cfg.success_threshold)
    radius = torch.where(grow, cur.radius + cfg.success_step, cur.radius).clamp(max=cfg.max_radius)
    return CurriculumState(radius=radius, placements=cur.placements, success_rate=rate)
