"""TorchRL environment for the navigation task: a :class:`~torchnav.envs.base.BatchedEnv` around
``NavTask`` that also keeps what its resets carry from one to the next: the curriculum
(``env.curriculum``) and the pool of pre-sampled episodes (``env.pool``). Per-episode statistics
are running values under ``"episode"``: read them where ``done`` is set."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Unbounded

from ..tasks import CurriculumState, EpisodePool, NavConfig, NavState, NavTask, after_episodes, after_family_episodes
from .base import BatchedEnv, CurriculumPoolState


class NavEnv(CurriculumPoolState, BatchedEnv):
    """Batched lidar navigation (see docs/tasks.md for observation, action and reward)."""

    config_class, task_class = NavConfig, NavTask

    def __init__(self, cfg: NavConfig | None = None, num_envs: int = 64, device: torch.device | str = "cpu", seed: int | None = 0,
                 compile_step: bool = False):
        super().__init__(cfg, num_envs, device, seed)
        if compile_step:  # the simulator step through torch.compile (not TorchRL's `compile`, which compiles the whole env step)
            self.task.compile_step()
        self.pool = EpisodePool()  # where partial resets take their episodes from when the task is pooled; new at every full reset
        self.restart_curriculum()

    def restart_curriculum(self) -> None:
        """Put the curriculum back to its initial state (goal radius, world difficulties)."""
        self.curriculum = CurriculumState.initial(self.cfg.curriculum, device=self.device, worlds=self.cfg.worlds)

    # -- specs ----------------------------------------------------------------------

    def _make_specs(self) -> None:
        b, dev, lidar = self.batch_size, self.device, self.cfg.lidar
        super()._make_specs(
            observation=Unbounded(shape=(*b, self.task.obs_size), device=dev), goal=Unbounded(shape=(*b, 2), device=dev),
            curriculum_radius=Unbounded(shape=(*b, 1), device=dev),
            ranges=Bounded(lidar.min_range, lidar.max_range, shape=(*b, lidar.n_rays), device=dev),
        )

    # -- the task hooks of BatchedEnv ---------------------------------------------------------

    flag_keys = ("success", "collision")
    reset_options = ("start", "goal")

    def reset_to(self, start: Any, goal: Any, mask: torch.Tensor | None = None) -> TensorDictBase:
        """:meth:`reset`, with the new episodes starting at the poses ``start`` ``(B, 3)`` ``[x, y, heading]``
        and their goals at ``goal`` ``(B, 2)`` (m, rad, the map's frame) instead of sampled ones; with a
        ``mask`` ``(B,)``, only in those envs. The map's random objects and moving obstacles are placed
        around them as usual, and the curriculum does not move (``NavTask.place_episodes``). Later
        episodes are sampled again. A map only: procedural worlds bring their own starts and goals.
        The same as ``env.reset(td, start=start, goal=goal)`` (``td`` holding ``"_reset"``).

        Bad starts or goals (shape, not finite, a start within the robot's radius of an obstacle, a
        goal inside one) raise ``ValueError`` naming the envs, before the env changes."""
        td = None
        if mask is not None:
            reset = torch.as_tensor(mask, dtype=torch.bool, device=self.device).reshape(*self.batch_size, 1)
            td = TensorDict({"_reset": reset}, batch_size=self.batch_size, device=self.device)
        return self.reset(td, start=start, goal=goal)

    def _new_state(self, mask: torch.Tensor | None, start: Any = None, goal: Any = None) -> NavState:
        """New episodes: at the given ``start`` and ``goal`` (``reset_to``), else sampled, a full reset
        from scratch (a new pool) and a partial one through the pool when the task is pooled; the
        curriculum moves with every sampled goal."""
        if (start is None) != (goal is None):
            raise ValueError("NavEnv.reset: options 'start' and 'goal' go together")
        if start is not None:
            return self.task.place_episodes(self._state, start, goal, self.curriculum, self._generator, mask)
        return self._drawn_state(mask)

    def _reset_view(self, s: NavState) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return s.history.reshape(self.num_envs, -1), {}

    def _after_step(self, out: dict[str, torch.Tensor]) -> None:
        done = out["terminated"] | out["truncated"]
        self.curriculum = after_episodes(self.curriculum, self.cfg.curriculum, done, out["success"])
        self.curriculum = after_family_episodes(self.curriculum, self.cfg.worlds, done, out["success"], self._state.family,
                                                self._state.difficulty)

    episode_keys = ("return", "length", "path_length", "straight_line", "speed_change", "turn_change")

    def _task_outputs(self, s: NavState) -> dict[str, torch.Tensor]:
        return {"goal": s.goal, "curriculum_radius": self.curriculum.radius.expand(*self.batch_size).reshape(*self.batch_size, 1).clone()}

    def _episode_stats(self, s: NavState) -> dict[str, torch.Tensor]:
        return {"path_length": s.ep_path, "straight_line": s.straight, "speed_change": s.ep_speed_change, "turn_change": s.ep_turn_change}


def make_nav_env(map: str = "arena", num_envs: int = 64, device: torch.device | str = "cpu", seed: int | None = 0, **overrides: Any) -> NavEnv:
    """Build a ``NavEnv`` from keyword overrides of ``NavConfig`` (nested dicts for sections).

    Example: ``make_nav_env("warehouse", 256, curriculum={"growth": 0.01}, reward={"preset": "shaped"})``.
    Unknown keys raise a ConfigError naming the key.
    """
    cfg = NavConfig.from_dict({"map": map, **overrides})
    return NavEnv(cfg, num_envs=num_envs, device=device, seed=seed)

