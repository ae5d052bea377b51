"""PettingZoo interface: one multi-robot env (:class:`~torchnav.envs.MultiNavEnv` with one env) as a
``pettingzoo.ParallelEnv`` whose agents are its robots, ``"robot_0"`` ... (docs/multi_robot.md).

Needs the ``pettingzoo`` extra. A robot leaves ``agents`` after the step that parks it (goal reached or
collided) or ends the episode; absent robots (``robots.min_n``) are never agents of that episode."""

from __future__ import annotations

import functools
from typing import Any

try:
    from gymnasium import spaces
    from pettingzoo import ParallelEnv
except ImportError as e:  # pragma: no cover - exercised only without the extra
    raise ImportError('torchnav.pettingzoo needs pettingzoo: pip install "torchnav[pettingzoo]"') from e

import numpy as np
import torch
from tensordict import TensorDict

from .envs import MultiNavEnv, make_multi_nav_env
from .gym import checked_actions
from .tasks import MultiNavConfig


class MultiNavParallelEnv(ParallelEnv):
    """The robots of one torchnav multi-robot env as PettingZoo agents.

    Observations ``(D,)`` float32 (each robot's ``("agents", "observation")``), actions ``(2,)`` in
    [-1, 1] float32 or an index into ``action.discrete_set``; ``infos[agent]`` holds ``success``,
    ``collision`` and ``robot_collision`` of the step, and the per-term rewards under ``reward_terms``.
    Build it from a :class:`~torchnav.tasks.MultiNavConfig` or from keyword overrides as
    :func:`~torchnav.envs.make_multi_nav_env` (``MultiNavParallelEnv(map="arena", n_robots=4)``)."""

    metadata = {"name": "torchnav_multi_nav_v0", "render_modes": []}

    def __init__(self, cfg: MultiNavConfig | None = None, *, device: torch.device | str = "cpu", seed: int | None = 0, **overrides: Any):
        if cfg is not None and overrides:
            raise ValueError("MultiNavParallelEnv: pass either a MultiNavConfig or keyword overrides, not both")
        self.env: MultiNavEnv = MultiNavEnv(cfg, num_envs=1, device=device, seed=seed) if cfg is not None else \
            make_multi_nav_env(num_envs=1, device=device, seed=seed, **overrides)
        self.possible_agents = [f"robot_{i}" for i in range(self.env.n_robots)]
        self.agents: list[str] = []
        self.render_mode = None
        self._td: TensorDict | None = None

    @functools.lru_cache(maxsize=None)
    def observation_space(self, agent: str) -> spaces.Box:
        return spaces.Box(-np.inf, np.inf, shape=(self.env.task.obs_size,), dtype=np.float32)

    @functools.lru_cache(maxsize=None)
    def action_space(self, agent: str) -> spaces.Space:
        if self.env.cfg.action.mode == "discrete":
            return spaces.Discrete(len(self.env.cfg.action.discrete_set))
        return spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)

    def _obs(self, td: TensorDict, agents: list[str]) -> dict[str, np.ndarray]:
        obs = td["agents", "observation"][0].cpu().numpy().astype(np.float32)
        return {a: obs[self.possible_agents.index(a)] for a in agents}

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        if seed is not None:
            self.env.set_seed(seed)
        self._td = self.env.reset()
        present = self._td["agents", "mask"][0, :, 0].tolist()
        self.agents = [a for a, p in zip(self.possible_agents, present) if p]
        return self._obs(self._td, self.agents), {a: {} for a in self.agents}

    def step(self, actions: dict[str, Any]):
        if self._td is None:
            raise RuntimeError("MultiNavParallelEnv.step: call reset() first")
        if not isinstance(actions, dict):
            raise ValueError(f"MultiNavParallelEnv.step: actions must be a dict of agent name to action, got {type(actions).__name__}")
        unknown = sorted(set(actions) - set(self.agents), key=str)
        if unknown:
            raise ValueError(f"MultiNavParallelEnv.step: actions for agents that are not live: {unknown} (live: {self.agents})")
        spec = self.env.full_action_spec["agents", "action"]
        act = torch.zeros(spec.shape, dtype=spec.dtype, device=self.env.device)  # parked and absent robots' actions are ignored
        discrete = self.env.cfg.action.mode == "discrete"
        if discrete:
            act[0, :, 0] = 1  # a valid one-hot for the robots that do not act
        for a, u in actions.items():
            i = self.possible_agents.index(a)
            try:
                u = checked_actions(u, () if discrete else (2,), spec.shape[-1] if discrete else None, per="robot")
            except ValueError as e:
                raise ValueError(f"MultiNavParallelEnv.step: {a}: {e}") from None
            if discrete:
                act[0, i] = 0
                act[0, i, int(u)] = 1
            else:
                act[0, i] = torch.as_tensor(u, dtype=torch.float32, device=self.env.device)
        self._td["agents", "action"] = act
        nxt = self.env.step(self._td)["next"]
        self._td = nxt
        live = self.agents
        idx = [self.possible_agents.index(a) for a in live]
        ag = nxt["agents"]
        reward = ag["reward"][0, :, 0].tolist()
        term, trunc = ag["terminated"][0, :, 0].tolist(), ag["truncated"][0, :, 0].tolist()
        flags = {f: ag[f][0, :, 0].tolist() for f in ("success", "collision", "robot_collision")}
        terms = {k: v[0, :, 0].tolist() for k, v in ag["reward_terms"].items()}
        obs = self._obs(nxt, live)
        rewards = {a: float(reward[i]) for a, i in zip(live, idx)}
        terminations = {a: bool(term[i]) for a, i in zip(live, idx)}
        truncations = {a: bool(trunc[i]) for a, i in zip(live, idx)}
        infos = {a: {**{f: bool(v[i]) for f, v in flags.items()}, "reward_terms": {k: v[i] for k, v in terms.items()}} for a, i in zip(live, idx)}
        self.agents = [a for a in live if not (terminations[a] or truncations[a])]
        return obs, rewards, terminations, truncations, infos

    def render(self) -> None:
        return None

    def close(self) -> None:
        pass

    def state(self) -> np.ndarray:
        """Every robot slot's observation, concatenated ``(N * D,)`` (a centralised critic's input)."""
        if self._td is None:
            raise RuntimeError("MultiNavParallelEnv.state: call reset() first")
        return self._td["agents", "observation"][0].reshape(-1).cpu().numpy().astype(np.float32)


def parallel_env(**kwargs: Any) -> MultiNavParallelEnv:
    """PettingZoo's conventional constructor: ``MultiNavParallelEnv(**kwargs)``."""
    return MultiNavParallelEnv(**kwargs)
