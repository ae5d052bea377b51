"""What every task shares: its frozen config, the batch size, device and dtype, the state
fields every episode carries (:class:`TaskState`), and the pool of pre-sampled episodes that
resets may draw from (:class:`EpisodePool`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import torch
from tensordict import tensorclass
from torch import Tensor

from ..sim import SimState
from .rewards import sum_terms


@tensorclass
class TaskState:
    """The per-env state every task keeps, all ``(B, ...)``."""

    sim: SimState  # the simulator state
    steps: Tensor  # (B,) int64 steps this episode
    history: Tensor  # (B, H, D) the last H observation frames, newest last
    ep_return: Tensor  # (B,) running sum of the reward
    ep_terms: Tensor  # (B, T) running sum of each weighted reward term


@dataclass
class EpisodePool:
    """Pre-sampled episodes that partial resets hand out in order (``reset.pool``, procedural worlds;
    docs/tasks.md, "Episode pool"). Whoever resets owns it (``NavEnv.pool``) and passes it to every
    ``NavTask.reset``, which draws from it and refills it in place, as it draws from the generator.
    A full reset (``initial_state``) starts a new one."""

    episodes: Any = None  # a task state (P, ...): the episodes of this pool; None until the first pooled reset
    pos: int = 0  # episodes handed out in this pass over them
    passes: int = 0  # passes over them so far (each after the first reshuffles them)

    def take(self, n: int, reuse: int, generator: torch.Generator, refill: Callable[[int], Any]) -> Any:
        """The next ``n`` episodes ``(n, ...)``. When this pass runs short, a new pass over the same
        episodes in a new order while fewer than ``reuse`` passes were made, else ``refill(n)`` (a
        new pool of at least ``n`` episodes)."""
        size = 0 if self.episodes is None else self.episodes.batch_size[0]
        if self.episodes is not None and self.pos + n > size and self.passes < reuse:
            self.episodes = self.episodes[torch.randperm(size, generator=generator, device=generator.device).to(self.episodes.device)]
            self.pos, self.passes = 0, self.passes + 1
        if self.episodes is None or self.pos + n > size:
            self.episodes = refill(n)
            self.pos, self.passes = 0, 1
        out = self.episodes[self.pos : self.pos + n]
        self.pos += n
        return out

    def state_dict(self) -> dict[str, Any] | None:
        """``None`` for an empty pool, else ``{"episodes": nested dict of tensors (copies), "pos", "passes"}``."""
        if self.episodes is None:
            return None
        return {"episodes": self.episodes.clone().to_dict(), "pos": self.pos, "passes": self.passes}

    def load_state_dict(self, sd: dict[str, Any] | None, rebuild: Callable[[dict[str, Any]], Any]) -> None:
        """Restore :meth:`state_dict`'s output; ``rebuild`` turns the saved episodes back into a task state
        (``BatchedEnv.state_from_dict``)."""
        if sd is None:
            self.episodes, self.pos, self.passes = None, 0, 0
        else:
            self.episodes, self.pos, self.passes = rebuild(sd["episodes"]), int(sd["pos"]), int(sd["passes"])


class BatchedTask:
    """A task over ``num_envs`` envs on ``device``; subclasses add ``initial_state``, ``reset`` and ``step``."""

    def __init__(self, cfg: Any, num_envs: int, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.cfg = cfg
        self.num_envs = num_envs
        self.device = torch.device(device)
        self.dtype = dtype

    @property
    def unit_features(self) -> torch.Tensor:
        """Mask ``(obs_size,)`` of the observation's features that are already scaled (or zero where absent) and whose
        spread under random actions says nothing of a policy's: normalisation statistics must
        leave these as they are. None here; a task with such features overrides this."""
        return torch.zeros(self.obs_size, dtype=torch.bool, device=self.device)

    def _episode_start(self, sim: SimState, frame: Tensor) -> dict[str, Any]:
        """The :class:`TaskState` fields of new episodes whose first observation frame is
        ``frame`` ``(n, D)``: a history of ``H`` copies of it, no steps, zero sums."""
        n = frame.shape[0]
        return dict(
            sim=sim, steps=torch.zeros(n, dtype=torch.int64, device=self.device),
            history=frame[:, None, :].expand(n, self.cfg.observation.history, frame.shape[-1]).clone(),
            ep_return=torch.zeros(n, dtype=self.dtype, device=self.device),
            ep_terms=torch.zeros(n, len(self.term_names), dtype=self.dtype, device=self.device), batch_size=[n], device=self.device,
        )

    @staticmethod
    def _episode_step(state: TaskState, sim: SimState, frame: Tensor, terms: dict[str, Tensor]) -> tuple[dict[str, Any], Tensor]:
        """The :class:`TaskState` fields one step after ``state``, which saw ``frame`` ``(B, D)`` and
        earned the weighted ``terms``, and the step's reward ``(B,)``."""
        stacked, reward = sum_terms(terms, state.ep_terms)
        return dict(
            sim=sim, steps=state.steps + 1, history=torch.cat((state.history[:, 1:], frame[:, None]), dim=1),
            ep_return=state.ep_return + reward, ep_terms=state.ep_terms + stacked, batch_size=state.batch_size, device=state.device,
        ), reward

    @staticmethod
    def replace_where(state: Any, mask: torch.Tensor, fresh: Callable[[torch.Tensor], Any]) -> tuple[Any, int]:
        """``state`` with the rows of the envs where ``mask`` ``(B,)`` is True replaced by ``fresh(idx)``
        (new episodes for envs ``idx``), and how many were replaced. Out of place, leaf by leaf: callers
        may hold views of the old state; the other envs are left bit-identical. One host
        synchronisation (``nonzero``) selects the envs, so only they are sampled."""
        idx = mask.reshape(-1).nonzero().squeeze(-1)
        if idx.numel() == 0:
            return state, 0
        return state.apply(lambda old, new: old.index_put((idx,), new), fresh(idx)), idx.numel()
