"""Analytic policy gradients through the differentiable simulator (SHAC-style, recipes/apg_*.py):
a horizon of every env rolled out with the autograd graph kept, the horizon's actor loss, the
critic's TD(lambda) targets, and the smoothed stand-ins for each task's terminal events.
docs/training.md#analytic-policy-gradients-apg describes what is differentiated.
"""

from __future__ import annotations

from typing import Any, Callable

import torch
from tensordict import TensorDict
from torch import Tensor

from .config import ConfigError


def _contact(smooth, env) -> Callable[[Any], Tensor]:
    """Navigation: ``smooth.contact * relu(1 - clearance / smooth.contact_margin)``: 0 with ``contact_margin``
    m of clearance or more, ``smooth.contact`` at contact, growing further when penetrating."""
    weight, margin = float(smooth.contact), float(smooth.contact_margin)
    return lambda state: weight * torch.relu(1.0 - state.sim.clearance / margin)


def _path(smooth, env) -> Callable[[Any], Tensor]:
    """Line following: ``smooth.path * (distance from the lap path / the distance that ends the episode)^2``."""
    weight, limit = float(smooth.path), float(env.cfg.termination.max_path_distance)
    return lambda state: weight * (state.path_dist / limit).square()


SMOOTH_TERMS = {"nav": _contact, "line": _path}  # task name -> (smooth config, env) -> (state -> (B,))


def make_smooth(task_name: str, smooth, env) -> Callable[[Any], Tensor]:
    """The differentiable reward term ``state -> (B,)`` of a task, from a config's ``smooth`` section."""
    if task_name not in SMOOTH_TERMS:
        raise ConfigError(f"apg: no smoothed terms for task {task_name!r}")
    return SMOOTH_TERMS[task_name](smooth, env)


def rollout(env, loc_net: Callable[[Tensor], Tensor], value: Callable[[Tensor], Tensor], smooth: Callable[[Any], Tensor], horizon: int,
            gamma: float, sigma: float, outcome_keys: tuple[str, ...]) -> TensorDict:
    """``horizon`` steps of every env of a ``BatchedEnv`` with the autograd graph kept; returns a ``(N, horizon)`` batch.

    The action is ``tanh(loc_net(obs) + sigma * noise)``; ``"loc"`` holds ``loc_net(obs)`` with its graph
    (for :func:`horizon_loss`'s ``action_reg``). ``"apg"`` holds each step's share of the
    differentiable objective ``gamma^k r_t (+ gamma^(k+1) V(s_{t+1})`` at a horizon end or truncation),
    ``k`` counting from the horizon start or the episode start if later, ``r_t`` the task's reward plus
    ``smooth(state)``; ``"observation"``, ``"reward"`` and ``"bootstrap"`` (``V`` of the next state, 0
    after a terminal event) are detached, for the critic; ``"next"`` holds ``done``, ``terminated``, the
    task's outcome flags and the finished episodes' ``episode`` statistics, as a collector's batch would.
    The env state is detached at the end.
    """
    n = env.num_envs
    obs = env.observation()
    disc = obs.new_ones(n)
    steps: list[dict[str, Tensor]] = []
    for t in range(horizon):
        loc = loc_net(obs)
        action = torch.tanh(loc + sigma * torch.randn_like(loc))
        last, out = env.advance(action)
        reward = out["reward"] + smooth(last)
        terminated, done = out["terminated"], out["terminated"] | out["truncated"]
        v_next = value(out["observation"])[:, 0]
        boot = torch.where(terminated, torch.zeros_like(v_next), v_next)
        end = done if t < horizon - 1 else torch.ones_like(done)
        apg = disc * (reward + gamma * boot * end.to(boot.dtype))
        steps.append({
            "apg": apg, "loc": loc, "observation": obs.detach(), "reward": reward.detach(), "bootstrap": boot.detach(),
            "next": {"done": done[:, None], "terminated": terminated[:, None], **{k: out[k][:, None] for k in outcome_keys},
                     "episode": {"return": last.ep_return.detach()[:, None], "length": last.steps.to(obs.dtype)[:, None]}},
        })
        disc = torch.where(done, torch.ones_like(disc), disc * gamma)
        obs = env.observation()
    env.detach_state()
    return TensorDict.stack([TensorDict(s, batch_size=[n]) for s in steps], dim=1)


def horizon_loss(batch: TensorDict, action_reg: float = 0.0) -> Tensor:
    """The actor loss of a horizon: minus the differentiable objective per env step, plus
    ``action_reg`` times the mean square of the pre-``tanh`` actions (it keeps them out of the
    ``tanh``'s flat tails, where the gradient of the return no longer reaches the policy)."""
    loss = -batch["apg"].sum() / batch.numel()
    return loss + action_reg * batch["loc"].square().mean() if action_reg else loss


def lambda_returns(reward: Tensor, bootstrap: Tensor, done: Tensor, gamma: float, lmbda: float) -> Tensor:
    """TD(lambda) targets ``(N, H)`` from rewards, bootstrap values of the next states (0 after a
    terminal event) and done flags, all ``(N, H)``; the last step bootstraps fully."""
    out = torch.empty_like(reward)
    g = bootstrap[:, -1]
    for t in reversed(range(reward.shape[1])):
        if t < reward.shape[1] - 1:
            g = torch.where(done[:, t], bootstrap[:, t], (1 - lmbda) * bootstrap[:, t] + lmbda * g)
        g = reward[:, t] + gamma * g
        out[:, t] = g
    return out
