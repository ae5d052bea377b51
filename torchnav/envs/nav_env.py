"""TorchRL environment for the navigation task: a thin wrapper around ``NavTask``.

``batch_size=(num_envs,)``; specs made in one place (``_make_specs``); partial
resets through the ``"_reset"`` mask; an explicit ``torch.Generator`` seeded by
``set_seed``. Per-episode statistics are running values under ``"episode"``:
read them where ``done`` is set.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict
from torchrl.data import Bounded, Composite, Unbounded

from ..config import merge, to_dict
from ..tasks import CurriculumState, NavConfig, NavState, NavTask, after_episodes, after_family_episodes
from .base import BatchedEnv


class NavEnv(BatchedEnv):
    """Batched lidar navigation (see docs/tasks.md for observation, action and reward)."""

    def __init__(self, cfg: NavConfig | None = None, num_envs: int = 64, device: torch.device | str = "cpu", seed: int | None = 0,
                 compile_step: bool = False):
        cfg = cfg or NavConfig()
        super().__init__(num_envs, device, seed)
        self.cfg = cfg
        self.task = NavTask(cfg, num_envs, device=self.device)
        if compile_step:  # the simulator step through torch.compile (not TorchRL's `compile`, which compiles the whole env step)
            self.task.compile_step()
        self.restart_curriculum()
        self._state: NavState | None = None
        self._make_specs()

    def restart_curriculum(self) -> None:
        """Put the curriculum back to its initial state (goal radius, world difficulties)."""
        self.curriculum = CurriculumState.initial(self.cfg.curriculum, device=self.device, worlds=self.cfg.worlds)

    # -- specs ----------------------------------------------------------------------

    def _make_specs(self) -> None:
        b, dev, t = self.batch_size, self.device, self.task
        flag = self._flag_spec
        scalar = lambda: Unbounded(shape=(*b, 1), device=dev)  # noqa: E731
        lidar = self.cfg.lidar
        self.observation_spec = Composite(
            observation=Unbounded(shape=(*b, t.obs_size), device=dev),
            pose=Unbounded(shape=(*b, 3), device=dev),
            goal=Unbounded(shape=(*b, 2), device=dev),
            ranges=Bounded(lidar.min_range, lidar.max_range, shape=(*b, lidar.n_rays), device=dev),
            success=flag(),
            collision=flag(),
            curriculum_radius=scalar(),
            reward_terms=Composite({k: scalar() for k in t.term_names}, shape=b, device=dev),
            episode=Composite(
                {"return": scalar(), "length": scalar(), "path_length": scalar(), "straight_line": scalar(),
                 **{f"term_{k}": scalar() for k in t.term_names}},
                shape=b, device=dev,
            ),
            shape=b, device=dev,
        )
        self._make_action_done_specs(self.cfg.action)

    # -- the task hooks of BatchedEnv ---------------------------------------------------------

    flag_keys = ("success", "collision")

    def _new_state(self, mask: torch.Tensor | None) -> NavState:
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

    def _outputs(self, s: NavState, obs, terms, flags) -> TensorDict:
        b = self.batch_size
        col = lambda x: x.reshape(*b, 1)  # noqa: E731
        episode = {
            "return": col(s.ep_return), "length": col(s.steps.to(s.ep_return.dtype)),
            "path_length": col(s.ep_path), "straight_line": col(s.straight),
            **{f"term_{k}": col(s.ep_terms[:, i]) for i, k in enumerate(self.task.term_names)},
        }
        return TensorDict(
            {
                "observation": obs, "pose": s.sim.pose, "goal": s.goal, "ranges": s.sim.ranges,
                **flags,
                "curriculum_radius": self.curriculum.radius.expand(*b).reshape(*b, 1).clone(),
                "reward_terms": {k: col(v) for k, v in terms.items()},
                "episode": episode,
            },
            batch_size=b, device=self.device,
        )

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


def make_env(map: str = "arena", num_envs: int = 64, device: torch.device | str = "cpu", seed: int | None = 0, **overrides: Any) -> NavEnv:
    """Build a ``NavEnv`` from keyword overrides of ``NavConfig`` (nested dicts for sections).

    Example: ``make_env("warehouse", 256, curriculum={"growth": 0.01}, reward={"preset": "shaped"})``.
    Unknown keys raise a ConfigError naming the key.
    """
    cfg = NavConfig.from_dict(merge(to_dict(NavConfig()), {"map": map, **overrides}))
    return NavEnv(cfg, num_envs=num_envs, device=device, seed=seed)
