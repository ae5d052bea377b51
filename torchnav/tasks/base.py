"""What every task shares: its frozen config, the batch size, device and dtype."""

from __future__ import annotations

from typing import Any, Callable

import torch


class BatchedTask:
    """A task over ``num_envs`` envs on ``device``; subclasses add ``initial_state``, ``reset`` and ``step``."""

    def __init__(self, cfg: Any, num_envs: int, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.cfg = cfg
        self.num_envs = num_envs
        self.device = torch.device(device)
        self.dtype = dtype

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
