"""What every task shares: its frozen config, the batch size, device and dtype."""

from __future__ import annotations

from typing import Any

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
