"""TorchRL environment for the navigation task: a :class:`~torchnav.envs.base.BatchedEnv` around
``NavTask`` that also keeps the curriculum. Per-episode statistics are running values under
``"episode"``: read them where ``done`` is set."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Unbounded

from ..deprecation import renamed_function
from ..tasks import CurriculumState, NavConfig, NavState, NavTask, after_episodes, after_family_episodes
from .base import BatchedEnv


class NavEnv(BatchedEnv):
    """Batched lidar navigation (see docs/tasks.md for observation, action and reward)."""

    config_class, task_class = NavConfig, NavTask

    def __init__(self, cfg: NavConfig | None = None, num_envs: int = 64, device: torch.device | str = "cpu", seed: int | None = 0,
                 compile_step: bool = False):
        self._given: tuple[Any, Any] | None = None  # starts and goals for the next reset (reset_to)
        super().__init__(cfg, num_envs, device, seed)
        if compile_step:  # the simulator step through torch.compile (not TorchRL's `compile`, which compiles the whole env step)
            self.task.compile_step()
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

    def reset_to(self, start: Any, goal: Any, mask: torch.Tensor | None = None) -> TensorDictBase:
        """:meth:`reset`, with the new episodes starting at the poses ``start`` ``(B, 3)`` ``[x, y, heading]``
        and their goals at ``goal`` ``(B, 2)`` (m, rad, the map's frame) instead of sampled ones; with a
        ``mask`` ``(B,)``, only in those envs. The map's random objects and moving obstacles are placed
        around them as usual, and the curriculum does not move (``NavTask.place_episodes``). Later
        episodes are sampled again. A map only: procedural worlds bring their own starts and goals.

        Bad starts or goals (shape, not finite, a start within the robot's radius of an obstacle, a
        goal inside one) raise ``ValueError`` naming the envs, before the env changes."""
        self._given = (start, goal)
        try:
            if mask is None:
                return self.reset()
            reset = torch.as_tensor(mask, dtype=torch.bool, device=self.device).reshape(*self.batch_size, 1)
            return self.reset(TensorDict({"_reset": reset}, batch_size=self.batch_size, device=self.device))
        finally:
            self._given = None

    def _new_state(self, mask: torch.Tensor | None) -> NavState:
        if self._given is not None:
            return self.task.place_episodes(self._state, *self._given, self.curriculum, self._generator, mask)
        if mask is None:
            state, self.curriculum = self.task.initial_state(self.curriculum, self._generator)
        else:
            state, self.curriculum = self.task.reset(self._state, mask, self.curriculum, self._generator)
        return state

    def _reset_view(self, s: NavState) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return s.history.reshape(self.num_envs, -1), {}

    def _after_step(self, out: dict[str, torch.Tensor]) -> None:
        done = out["terminated"] | out["truncated"]
        self.curriculum = after_episodes(self.curriculum, self.cfg.curriculum, done, out["success"])
        self.curriculum = after_family_episodes(self.curriculum, self.cfg.worlds, done, out["success"], self._state.family,
                                                self._state.difficulty)

    episode_keys = ("return", "length", "path_length", "straight_line")

    def _task_outputs(self, s: NavState) -> dict[str, torch.Tensor]:
        return {"goal": s.goal, "curriculum_radius": self.curriculum.radius.expand(*self.batch_size).reshape(*self.batch_size, 1).clone()}

    def _episode_stats(self, s: NavState) -> dict[str, torch.Tensor]:
        return {"path_length": s.ep_path, "straight_line": s.straight}

    # -- state for checkpoints and recording ------------------------------------------------

    def get_extra_state(self) -> dict[str, Any]:
        """Curriculum, generator, episodes in flight and the pool of pre-sampled ones: ``env.state_dict()["_extra_state"]``."""
        t = self.task
        pool = None if t._pool is None else {"episodes": t._pool.clone().to_dict(), "pos": t._pool_pos, "passes": t._pool_passes}
        return {"curriculum": self.curriculum.state_dict(), **super().get_extra_state(), "pool": pool}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        super().set_extra_state(state)  # first: rebuilding the episodes may place new ones, which moves the curriculum
        self.curriculum.load_state_dict(state["curriculum"])
        if "pool" in state:  # absent from checkpoints written before episodes were saved
            pool = state["pool"]
            t = self.task
            t._pool = None if pool is None else self.state_from_dict(pool["episodes"])
            t._pool_pos, t._pool_passes = (0, 0) if pool is None else (int(pool["pos"]), int(pool["passes"]))


def make_nav_env(map: str = "arena", num_envs: int = 64, device: torch.device | str = "cpu", seed: int | None = 0, **overrides: Any) -> NavEnv:
    """Build a ``NavEnv`` from keyword overrides of ``NavConfig`` (nested dicts for sections).

    Example: ``make_nav_env("warehouse", 256, curriculum={"growth": 0.01}, reward={"preset": "shaped"})``.
    Unknown keys raise a ConfigError naming the key.
    """
    cfg = NavConfig.from_dict({"map": map, **overrides})
    return NavEnv(cfg, num_envs=num_envs, device=device, seed=seed)


make_env = renamed_function(make_nav_env, "torchnav.envs.make_env")
