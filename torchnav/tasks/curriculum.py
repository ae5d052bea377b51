"""Curricula as explicit, savable state on the env device: the bootstrapped goal radius
(0-d tensors) and, with procedural worlds, one difficulty level per world family."""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from .config import CurriculumConfig, WorldsConfig


@dataclass
class CurriculumState:
    radius: Tensor  # 0-d, m: current maximum goal distance
    placements: Tensor  # 0-d int64: goals placed so far
    success_rate: Tensor  # 0-d: exponential average of episode success (mode "success")
    difficulty: Tensor  # (F,) in [0, 1]: each world family's difficulty (F = 0 without worlds)
    family_success: Tensor  # (F,): each family's exponential average of episode success

    @classmethod
    def initial(cls, cfg: CurriculumConfig, device=None, dtype=torch.float32, worlds: WorldsConfig | None = None) -> "CurriculumState":
        r0 = cfg.max_radius if cfg.mode == "off" else cfg.init_radius
        f = len(worlds.families) if worlds is not None else 0
        return cls(
            radius=torch.tensor(r0, dtype=dtype, device=device),
            placements=torch.tensor(0, dtype=torch.int64, device=device),
            success_rate=torch.tensor(0.0, dtype=dtype, device=device),
            difficulty=torch.full((f,), worlds.difficulty if f else 0.0, dtype=dtype, device=device),
            family_success=torch.zeros(f, dtype=dtype, device=device),
        )

    FIELDS = ("radius", "placements", "success_rate", "difficulty", "family_success")

    def state_dict(self) -> dict[str, Tensor]:
        return {k: getattr(self, k).clone() for k in self.FIELDS}

    def load_state_dict(self, sd: dict[str, Tensor]) -> None:
        """Restore :meth:`state_dict`'s output; ``KeyError`` names missing fields, ``ValueError`` a shape
        that does not fit (the world families are one entry each)."""
        missing = set(self.FIELDS) - set(sd)
        if missing:
            raise KeyError(f"curriculum state is missing {sorted(missing)}")
        for k in self.FIELDS:
            if sd[k].shape != getattr(self, k).shape:
                raise ValueError(f"curriculum state {k!r} has shape {tuple(sd[k].shape)}, expected {tuple(getattr(self, k).shape)}"
                                 + (" (one per world family)" if k in ("difficulty", "family_success") else ""))
        for k in self.FIELDS:
            setattr(self, k, sd[k].to(getattr(self, k)))


def after_placements(cur: CurriculumState, cfg: CurriculumConfig, n_placed: Tensor) -> CurriculumState:
    """Mode "growth": ``radius = min(max_radius, init_radius + growth * placements)``."""
    placements = cur.placements + n_placed
    radius = cur.radius
    if cfg.mode == "growth":
        radius = (cfg.init_radius + cfg.growth * placements.to(radius.dtype)).clamp(max=cfg.max_radius)
    return replace(cur, radius=radius, placements=placements)


def _fold(rate: Tensor, n: Tensor, successes: Tensor, smoothing: float) -> Tensor:
    """A success average after ``n`` finished episodes, ``successes`` of them successful: each
    moves it by ``smoothing`` towards its outcome (unchanged where ``n`` is 0)."""
    keep = (1.0 - smoothing) ** n
    return torch.where(n > 0, keep * rate + (1 - keep) * successes / n.clamp(min=1), rate)


def after_episodes(cur: CurriculumState, cfg: CurriculumConfig, done: Tensor, success: Tensor) -> CurriculumState:
    """Mode "success": fold finished episodes ``done`` ``(B,)`` with outcome ``success`` ``(B,)``
    into the success average, and grow the radius by ``success_step`` when it exceeds the threshold."""
    if cfg.mode != "success":
        return cur
    dtype = cur.success_rate.dtype
    n = done.sum().to(dtype)
    rate = _fold(cur.success_rate, n, (success & done).sum().to(dtype), cfg.success_smoothing)
    grow = (n > 0) & (rate > cfg.success_threshold)
    radius = torch.where(grow, cur.radius + cfg.success_step, cur.radius).clamp(max=cfg.max_radius)
    return replace(cur, radius=radius, success_rate=rate)


def after_family_episodes(cur: CurriculumState, cfg: WorldsConfig, done: Tensor, success: Tensor, family: Tensor,
                          difficulty: Tensor | None = None) -> CurriculumState:
    """With ``cfg.curriculum``: fold finished episodes ``done`` ``(B,)`` of world families
    ``family`` ``(B,)`` (indices into ``cfg.families``) into each family's success average,
    and raise a family's difficulty by ``difficulty_step`` when its average exceeds the threshold;
    the raised family's average then restarts from 0.

    ``difficulty`` ``(B,)``, the level each episode was generated at: episodes below their
    family's current level (pooled episodes generated before the last raise) are not
    counted, so a family cannot climb on the success of worlds easier than its level."""
    if not cfg.curriculum or cur.difficulty.numel() == 0:
        return cur
    dtype = cur.family_success.dtype
    if difficulty is not None:
        done = done & (difficulty >= cur.difficulty[family] - 1e-6)
    hot = torch.nn.functional.one_hot(family, cur.difficulty.numel()).to(dtype) * done.to(dtype)[:, None]  # (B, F)
    n = hot.sum(0)
    rate = _fold(cur.family_success, n, (hot * success.to(dtype)[:, None]).sum(0), cfg.success_smoothing)
    grow = (n > 0) & (rate > cfg.success_threshold) & (cur.difficulty < cfg.max_difficulty)
    difficulty = torch.where(grow, cur.difficulty + cfg.difficulty_step, cur.difficulty).clamp(max=cfg.max_difficulty)
    # A raised family starts its average afresh: it must earn the next level at the new one
    # (about 1 / success_smoothing episodes), not ride the average of the easier level.
    return replace(cur, difficulty=difficulty, family_success=torch.where(grow, torch.zeros_like(rate), rate))
