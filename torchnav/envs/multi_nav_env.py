"""TorchRL multi-agent environment for several robots per env (docs/multi_robot.md): a
:class:`~torchnav.envs.base.BatchedEnv` of batch ``(num_envs,)`` around ``MultiNavTask`` whose robots
form one agent group of batch ``(num_envs, n_robots)``, laid out as TorchRL's multi-agent envs (VMAS)
lay theirs out: ``("agents", "observation")``, ``("agents", "action")``, ``("agents", "reward")``,
per-robot ``("agents", "done" / "terminated" / "truncated")`` beside the env's own ``done`` flags, and
``("agents", "mask")``, which robots exist in each env. ``("agents", "ranges")`` (each robot's raw
lidar, m) and ``("agents", "velocity")`` (its planar velocity in the world frame, m/s) are there for
classical controllers (``torchnav.controllers.ORCA``), which read the raw scan and the others' motion.

A robot that parks (goal reached or collided) reads ``("agents", "terminated")`` True until its env
resets; the env resets only when its own ``done`` is set (``"_reset"`` ``(B, 1)``), so TorchRL's
auto-reset, which also passes the robots' flags as ``("agents", "_reset")``, leaves running envs alone.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, OneHot, Unbounded

from ..tasks import CurriculumState, EpisodePool, MultiNavConfig, MultiNavState, MultiNavTask
from .base import BatchedEnv, CurriculumPoolState

AGENT_FLAGS = ("success", "collision", "robot_collision")


class MultiNavEnv(CurriculumPoolState, BatchedEnv):
    """``num_envs`` envs of ``cfg.robots.n`` robot slots each (see the module docstring for the keys)."""

    config_class, task_class = MultiNavConfig, MultiNavTask

    def __init__(self, cfg: MultiNavConfig | None = None, num_envs: int = 64, device: torch.device | str = "cpu", seed: int | None = 0):
        super().__init__(cfg, num_envs, device, seed)
        self.pool = EpisodePool()  # where partial resets take their episodes from when the task is pooled; new at every full reset
        self.restart_curriculum()

    def restart_curriculum(self) -> None:
        """Put the curricula back to their initial state (the goal radius of ``random``, the world difficulties)."""
        self.curriculum = CurriculumState.initial(self.cfg.curriculum, device=self.device, worlds=self.cfg.worlds)

    @property
    def n_robots(self) -> int:
        return self.task.n

    # -- specs ----------------------------------------------------------------------

    def _make_specs(self) -> None:
        b, n, dev = self.batch_size, self.task.n, self.device
        ab = (*b, n)
        flag = lambda shape: Categorical(2, shape=(*shape, 1), dtype=torch.bool, device=dev)  # noqa: E731
        col = lambda: Unbounded(shape=(*ab, 1), device=dev)  # noqa: E731
        agents = Composite(
            observation=Unbounded(shape=(*ab, self.task.obs_size), device=dev), mask=flag(ab),
            pose=Unbounded(shape=(*ab, 3), device=dev), goal=Unbounded(shape=(*ab, 2), device=dev),
            ranges=Unbounded(shape=(*ab, self.cfg.lidar.n_rays), device=dev), velocity=Unbounded(shape=(*ab, 2), device=dev),
            **{f: flag(ab) for f in AGENT_FLAGS},
            reward_terms=Composite({k: col() for k in self.task.term_names}, shape=ab, device=dev),
            episode_return=col(), shape=ab, device=dev,
        )
        self.observation_spec = Composite(agents=agents, team_success=flag(b), episode_length=Unbounded(shape=(*b, 1), device=dev),
                                          shape=b, device=dev)
        if self.cfg.action.mode == "discrete":
            k = len(self.cfg.action.discrete_set)
            action = OneHot(k, shape=(*ab, k), device=dev)
        else:
            action = Bounded(-1.0, 1.0, shape=(*ab, 2), device=dev)
        self.full_action_spec = Composite(agents=Composite(action=action, shape=ab, device=dev), shape=b, device=dev)
        self.full_reward_spec = Composite(agents=Composite(reward=col(), shape=ab, device=dev), shape=b, device=dev)
        dones = lambda shape: {k: flag(shape) for k in ("done", "terminated", "truncated")}  # noqa: E731
        self.full_done_spec = Composite(**dones(b), agents=Composite(**dones(ab), shape=ab, device=dev), shape=b, device=dev)

    # -- reset and step ---------------------------------------------------------------

    def _new_state(self, mask: torch.Tensor | None) -> MultiNavState:
        return self._drawn_state(mask)

    def _reset_view(self, s: MultiNavState) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        return s.observation, {}

    def _reset(self, tensordict: TensorDictBase | None = None, set_state: bool = False, **options: Any) -> TensorDictBase:
        """New episodes in every env, or where the env's ``"_reset"`` ``(B, 1)`` is set (the robots'
        ``("agents", "_reset")`` is not a reason to reset: a parked robot waits for its env);
        ``set_state=True`` continues the episodes held."""
        if options:
            raise ValueError(f"MultiNavEnv.reset: unknown options {sorted(options)}; it takes none")
        if set_state:
            if self._state is None:
                raise RuntimeError("MultiNavEnv.reset(set_state=True): the env holds no episodes to continue")
        else:
            mask = None if tensordict is None else tensordict.get("_reset", None)
            self._state = self._new_state(None if self._state is None or mask is None else mask.reshape(-1))
        s = self._state
        parked = (s.arrived | s.crashed)[..., None]
        zero = torch.zeros_like(s.present)
        terms = {k: torch.zeros_like(s.ep_return) for k in self.task.term_names}
        flags = {f: zero[..., None].clone() for f in AGENT_FLAGS}
        out = self._agent_outputs(s, terms, flags)
        false = lambda: torch.zeros(*self.batch_size, 1, dtype=torch.bool, device=self.device)  # noqa: E731
        out.update({"done": false(), "terminated": false(), "truncated": false(), "team_success": false(),
                    ("agents", "done"): parked.clone(), ("agents", "terminated"): parked.clone(), ("agents", "truncated"): zero[..., None].clone()})
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = self._checked_action(tensordict, ("agents", "action"), self.full_action_spec["agents", "action"], per="robot")
        before = self._state
        self._state, out = self.task.step(before, action, self._generator)
        self.curriculum = self.task.after_step(self.curriculum, before, out)
        terminated, truncated = out["team_terminated"][:, None], out["team_truncated"][:, None]
        td = self._agent_outputs(self._state, out["terms"], {f: out[f][..., None] for f in AGENT_FLAGS})
        a_term, a_trunc = out["terminated"][..., None], out["truncated"][..., None]
        td.update({"done": terminated | truncated, "terminated": terminated, "truncated": truncated, "team_success": out["team_success"][:, None],
                   ("agents", "reward"): out["reward"][..., None], ("agents", "done"): a_term | a_trunc, ("agents", "terminated"): a_term,
                   ("agents", "truncated"): a_trunc})
        return td

    def _agent_outputs(self, s: MultiNavState, terms: dict[str, torch.Tensor], flags: dict[str, torch.Tensor]) -> TensorDict:
        b, ab = self.batch_size, (*self.batch_size, self.task.n)
        r = s.sim.robots
        heading = r.pose[..., 2]
        velocity = r.vel[..., :1] * torch.stack((torch.cos(heading), torch.sin(heading)), -1)  # forward speed along the heading
        agents = TensorDict({
            "observation": s.observation, "mask": s.present[..., None].clone(), "pose": r.pose, "goal": s.goal,
            "ranges": r.ranges, "velocity": velocity, **flags,
            "reward_terms": {k: v[..., None] for k, v in terms.items()}, "episode_return": s.ep_return[..., None],
        }, batch_size=ab, device=self.device)
        return TensorDict({"agents": agents, "episode_length": s.steps.to(s.ep_return.dtype)[:, None]}, batch_size=b, device=self.device)

    def advance(self, action: torch.Tensor):
        raise NotImplementedError("MultiNavEnv has no differentiable rollout yet: step it through TorchRL's step")


def make_multi_nav_env(map: str = "arena", num_envs: int = 64, n_robots: int = 4, device: torch.device | str = "cpu", seed: int | None = 0,
                       **overrides: Any) -> MultiNavEnv:
    """Build a ``MultiNavEnv`` from keyword overrides of ``MultiNavConfig`` (nested dicts for sections).

    Example: ``make_multi_nav_env("arena", 256, 4, robots={"scenario": "circle_swap"})``; ``n_robots`` is ``robots.n``.
    Unknown keys raise a ConfigError naming the key."""
    robots = {"n": n_robots, **overrides.pop("robots", {})}
    cfg = MultiNavConfig.from_dict({"map": map, "robots": robots, **overrides})
    return MultiNavEnv(cfg, num_envs=num_envs, device=device, seed=seed)
