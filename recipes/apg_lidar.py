"""Analytic policy gradients through the differentiable simulator (SHAC-style), on lidar navigation.

    python recipes/apg_lidar.py                       # arena, 32 envs, horizons of 32 steps, CPU, 2-5 minutes
    python recipes/apg_lidar.py train.horizon=16 smooth.contact=-20
    python recipes/apg_lidar.py --resume              # continue the newest run

No replay buffer, no likelihood ratios: the policy is improved by the gradient of
the return itself, backpropagated through ``NavTask.step`` (kinematics, lidar,
clearance, goal distance) over a short horizon of batched envs, as in SHAC (Xu et
al., "Accelerated Policy Learning with Parallel Differentiable Simulation", 2022):

- each iteration rolls the ``env.num_envs`` envs ``train.horizon`` steps forward
  with the autograd graph kept (``BatchedEnv.advance``; envs whose episode ends are
  reset in place, their fresh state has no graph);
- the actor loss is ``-(sum_t gamma^t r_t + gamma^H V(s_H)) / (H N)``, the value
  ``V`` of a frozen target critic bootstrapping the horizon's end and truncated
  episodes (0 after terminal events); ``V`` is differentiated with respect to its
  input, so the critic carries what the horizon cannot see;
- ``train.action_reg`` times the mean squared pre-``tanh`` action is added to the loss
  (a saturated ``tanh`` passes no gradient: the policy would drive into boxes at full speed);
- the gradient is clipped to ``train.max_grad_norm``, and an update whose norm is
  not finite or above ``train.skip_grad_norm`` is skipped (exploding gradients);
- the env state is detached between horizons (truncated backpropagation through time);
- the critic is then fitted to TD(lambda) targets of the horizon's (detached)
  rewards, and the target critic follows it by Polyak averaging.

The task's terminal events (goal reached, collision) are constants with no
gradient; ``smooth.*`` adds a differentiable term in their place (``contact``: a
penalty ramping up as the robot's clearance falls below ``smooth.contact_margin``)
to the reward the actor and critic see, its weight ramped in over
``smooth.ramp_frames`` (at full weight from the start, or with the `proximity` term
on, the first updates learned to stand still). Exploration is Gaussian noise before the
``tanh`` (reparameterised, so it does not block the gradient). The shared loop in
``recipes/_train.py`` does progress output, periodic evaluation, checkpoints, the
final evaluation and MCAP episodes; the saved ``actor.pt`` is ``tanh`` of the
policy network, like PPO's. Every config key is documented in
recipes/configs/apg_lidar.yaml; docs/training.md#analytic-policy-gradients-apg
describes what is differentiated and where it fails.
"""

from __future__ import annotations

import copy
import math
import sys
from pathlib import Path
from typing import Any, Callable, Iterator

import torch
from tensordict import TensorDict
from torch import Tensor

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as C  # noqa: E402
from _train import NavAdapter, Trainer  # noqa: E402

from torchnav.policy import Actor  # noqa: E402


# -- smoothed terms: differentiable stand-ins for the task's terminal events ---------------------

def nav_smooth(smooth, state) -> Tensor:
    """``smooth.contact * relu(1 - clearance / smooth.contact_margin)``: 0 with ``contact_margin`` m
    of clearance or more, ``smooth.contact`` at contact, growing further when penetrating."""
    return float(smooth.contact) * torch.relu(1.0 - state.sim.clearance / float(smooth.contact_margin))


def make_smooth(task_name: str, smooth, env) -> Callable[[Any], Tensor]:
    """The differentiable reward term ``state -> (B,)`` of a task, from the config's ``smooth`` section."""
    if task_name == "nav":
        return lambda state: nav_smooth(smooth, state)
    if task_name == "line":  # smooth.path * (distance from the lap path / the distance that ends the episode)^2
        limit = float(env.cfg.termination.max_path_distance)
        return lambda state: float(smooth.path) * (state.path_dist / limit).square()
    raise C.ConfigError(f"apg: no smoothed terms for task {task_name!r}")


# -- one horizon of the differentiable rollout -------------------------------------------------

def rollout(env, loc_net: Actor, value: Actor, smooth: Callable[[Any], Tensor], horizon: int, gamma: float, sigma: float,
            outcome_keys: tuple[str, ...]) -> TensorDict:
    """``horizon`` steps of every env with the autograd graph kept; returns a ``(N, horizon)`` batch.

    ``"loc"`` holds the policy's pre-``tanh`` mean action (with its graph, for
    :func:`horizon_loss`'s ``action_reg``); ``"apg"`` holds each step's share of the differentiable objective
    ``gamma^k r_t (+ gamma^(k+1) V(s_{t+1})`` at a horizon end or truncation), ``k`` counting
    from the horizon start or the episode start if later; ``"observation"``, ``"reward"``
    and ``"bootstrap"`` (``V`` of the next state, 0 after a terminal event) are detached,
    for the critic; ``"next"`` holds ``done``, ``terminated``, the task's outcome flags and
    the finished episodes' ``episode`` statistics, as a collector's batch would (for the
    shared loop's statistics). The env state is detached at the end.
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


def horizon_loss(batch: TensorDict, action_reg: float = 0.0) -> Tensor:
    """The actor loss of a horizon: minus the differentiable objective per env step, plus
    ``action_reg`` times the mean square of the pre-``tanh`` actions (it keeps them out of the
    ``tanh``'s flat tails, where the gradient of the return no longer reaches the policy)."""
    loss = -batch["apg"].sum() / batch.numel()
    return loss + action_reg * batch["loc"].square().mean() if action_reg else loss


def main(argv: list[str], name: str = "apg_lidar", adapter: type = NavAdapter) -> dict:
    """Train; ``name`` picks ``configs/<name>.yaml`` and ``adapter`` the task (``apg_line.py`` reuses this)."""
    t = Trainer(name, argv, ckpt_format=f"torchnav-{name.replace('_', '-')}-v1", adapter=adapter, action_mode="continuous")
    tc, env, device = t.cfg.train, t.env, t.device
    horizon, gamma, lmbda, tau = int(tc.horizon), float(tc.gamma), float(tc.lmbda), float(tc.tau)

    # -- networks: the policy (pre-tanh mean), a critic and its frozen target copy -------------
    obs_size = env.task.obs_size
    loc_net = Actor(obs_size, 2, tc.hidden, tc.activation, output="linear").to(device)
    critic = Actor(obs_size, 1, tc.hidden, tc.activation, output="linear").to(device)
    critic_target = copy.deepcopy(critic).requires_grad_(False)
    opt_actor = torch.optim.Adam(loc_net.parameters(), lr=float(tc.lr_actor))
    opt_critic = torch.optim.Adam(critic.parameters(), lr=float(tc.lr_critic))
    modules = {"actor": loc_net, "critic": critic, "critic_target": critic_target, "opt_actor": opt_actor, "opt_critic": opt_critic}
    t.restore(modules)
    t.export_actor = lambda: loc_net.squashed()
    t.counters.setdefault("skipped_updates", 0)
    term = make_smooth(t.task.name, t.cfg.smooth, env)
    ramp = int(t.cfg.smooth.ramp_frames)

    def smooth(state) -> Tensor:
        """The smoothed terms, their weight ramped from 0 over ``smooth.ramp_frames`` (continuation:
        learn to move before learning to keep away; a full weight at once can teach standing still)."""
        return term(state) * (min(1.0, t.counters["frames"] / ramp) if ramp else 1.0)
    env.reset()  # episodes in flight are not checkpointed: a resumed run starts fresh ones

    def sigma() -> float:
        """Exploration noise, annealed linearly over ``train.expl_anneal_frames``."""
        frac = min(1.0, t.counters["frames"] / max(int(tc.expl_anneal_frames), 1))
        return float(tc.expl_sigma_init) + frac * (float(tc.expl_sigma_end) - float(tc.expl_sigma_init))

    def batches() -> Iterator[TensorDict]:
        for _ in range(math.ceil(t.remaining_frames() / (env.num_envs * horizon))):
            yield rollout(env, loc_net, critic_target, smooth, horizon, gamma, sigma(), t.task.outcome_keys)

    mb = int(tc.minibatch_size)

    def update(batch: TensorDict) -> dict[str, Tensor]:
        if tc.lr_decay:  # linearly to 0 at train.total_frames, as SHAC
            keep = max(0.0, 1.0 - t.counters["frames"] / int(tc.total_frames))
            for opt, lr in ((opt_actor, tc.lr_actor), (opt_critic, tc.lr_critic)):
                for group in opt.param_groups:
                    group["lr"] = float(lr) * keep
        # actor: backpropagate the horizon's return through the simulator
        loss = horizon_loss(batch, float(tc.action_reg))
        opt_actor.zero_grad(set_to_none=True)
        loss.backward()
        norm = torch.nn.utils.clip_grad_norm_(loc_net.parameters(), float(tc.max_grad_norm))
        if torch.isfinite(norm) and norm <= float(tc.skip_grad_norm):
            opt_actor.step()
        else:  # an exploding or non-finite gradient: drop this update rather than the policy
            t.counters["skipped_updates"] += 1
        t.counters["updates"] += 1
        # critic: TD(lambda) targets of the detached horizon
        with torch.no_grad():
            target = lambda_returns(batch["reward"], batch["bootstrap"], batch["next", "done"][..., 0], gamma, lmbda)
        obs, target = batch["observation"].reshape(-1, obs_size), target.reshape(-1)
        for _ in range(int(tc.critic_epochs)):
            for idx in torch.randperm(target.numel(), device=device).split(mb):
                v_loss = (critic(obs[idx])[:, 0] - target[idx]).square().mean()
                opt_critic.zero_grad(set_to_none=True)
                v_loss.backward()
                torch.nn.utils.clip_grad_norm_(critic.parameters(), float(tc.max_grad_norm))
                opt_critic.step()
        with torch.no_grad():
            for p_t, p in zip(critic_target.parameters(), critic.parameters()):
                p_t.lerp_(p, tau)
        return {"actor": loss.detach(), "critic": v_loss.detach(), "grad_norm": norm.detach(), "sigma": torch.tensor(sigma())}

    remaining = t.remaining_frames()
    stopped = t.train(batches() if remaining > 0 else None, update, lambda: {k: m.state_dict() for k, m in modules.items()})
    if stopped:
        return {"run_dir": str(t.run), "stopped": True, "counters": t.counters}
    return t.finish()


if __name__ == "__main__":
    C.main_guard(main)
