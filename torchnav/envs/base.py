"""What NavEnv and LineEnv share: the batch, the explicit generator, the action and done
specs, the NaN-action check, the current task state and the generator's checkpoint state."""

from __future__ import annotations

from typing import Any

import torch
from torchrl.data import Bounded, Categorical, Composite, OneHot, Unbounded
from torchrl.envs import EnvBase


class BatchedEnv(EnvBase):
    """``batch_size=(num_envs,)`` env stepping a pure task with one ``torch.Generator`` seeded by ``seed``."""

    _has_dynamic_specs = False

    def __init__(self, num_envs: int, device: torch.device | str, seed: int | None) -> None:
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self._generator = torch.Generator(device=self.device)
        self._generator.manual_seed(0 if seed is None else int(seed))
        self._state: Any = None

    def _flag_spec(self) -> Categorical:
        return Categorical(2, shape=(*self.batch_size, 1), dtype=torch.bool, device=self.device)

    def _make_action_done_specs(self, action_cfg) -> None:
        """One-hot over ``action_cfg.discrete_set`` (mode ``discrete``) or 2 values in [-1, 1]; reward and done flags."""
        b, dev = self.batch_size, self.device
        if action_cfg.mode == "discrete":
            n = len(action_cfg.discrete_set)
            self.action_spec = OneHot(n, shape=(*b, n), device=dev)
        else:
            self.action_spec = Bounded(-1.0, 1.0, shape=(*b, 2), device=dev)
        self.reward_spec = Unbounded(shape=(*b, 1), device=dev)
        self.done_spec = Composite(done=self._flag_spec(), terminated=self._flag_spec(), truncated=self._flag_spec(), shape=b, device=dev)

    def _checked_action(self, tensordict) -> torch.Tensor:
        """The ``"action"``, of the action spec's shape (else a ValueError naming both shapes); with
        ``cfg.check_actions`` a NaN or inf raises naming the envs (one host sync)."""
        action = tensordict.get("action")
        if action.shape != self.action_spec.shape:
            raise ValueError(f"{type(self).__name__}.step: action has shape {tuple(action.shape)}, expected {tuple(self.action_spec.shape)} "
                             f"({self.action_spec.shape[-1]} values per env for {self.num_envs} envs)")
        if self.cfg.check_actions and not torch.isfinite(action).all():
            bad = (~torch.isfinite(action)).reshape(action.shape[0], -1).any(-1).nonzero().squeeze(-1).tolist()
            raise ValueError(
                f"{type(self).__name__}.step: action contains NaN or inf in envs {bad[:10]}{'...' if len(bad) > 10 else ''}; "
                "fix the policy, or pass check_actions=False to let the simulator treat them as a stop command"
            )
        return action

    def _set_seed(self, seed: int | None) -> None:
        self._generator.manual_seed(0 if seed is None else int(seed))

    @property
    def num_envs(self) -> int:
        return self.batch_size[0]

    @property
    def state(self):
        """The current task state (read-only use: worlds, goals, poses of every env)."""
        return self._state

    # Checkpoint state goes through nn.Module's extra-state hooks, so ``env.state_dict()`` and
    # ``env.load_state_dict(sd)`` keep nn.Module's signatures and a TransformedEnv's state_dict
    # includes it (under ``base_env._extra_state``). Episodes in flight are not saved.

    def get_extra_state(self) -> dict[str, Any]:
        """The generator's state (NavEnv adds the curriculum)."""
        return {"generator": self._generator.get_state()}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        if "generator" in state:
            self._generator.set_state(state["generator"])

    def load_state_dict(self, state_dict: Any, strict: bool = True, assign: bool = False) -> Any:
        """nn.Module's, also accepting the ``{"curriculum", "generator"}`` dict that checkpoints
        written before the extra-state hooks hold."""
        if "generator" in state_dict and "_extra_state" not in state_dict:
            state_dict = {"_extra_state": dict(state_dict)}
        return super().load_state_dict(state_dict, strict=strict, assign=assign)
