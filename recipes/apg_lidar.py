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
``tanh`` (reparameterised, so it does not block the gradient). ``torchnav.apg`` holds the
horizon's rollout, its loss, the TD(lambda) targets and the smoothed terms. The saved
``actor.pt`` is ``tanh`` of the policy network, like PPO's. Every config key, its default and
its documentation: torchnav/train_config.py (recipes/configs/apg_lidar.yaml holds what this recipe
changes); docs/training.md#analytic-policy-gradients-apg describes what is differentiated and
where it fails.
"""

from __future__ import annotations

import copy
import math
import sys
from pathlib import Path
from typing import Iterator

import torch
from tensordict import TensorDict
from torch import Tensor

sys.path.insert(0, str(Path(__file__).resolve().parent))
import builders as B  # noqa: E402

from torchnav.apg import horizon_loss, lambda_returns, make_smooth, rollout  # noqa: E402,F401  (tests/test_apg.py reads them here)
from torchnav.policy import Actor  # noqa: E402


def main(argv: list[str], name: str = "apg_lidar") -> dict:
    """Train; ``name`` picks ``configs/<name>.yaml``, whose ``task`` section picks the task (``apg_line.py`` reuses this)."""
    run = B.setup(name, argv, ckpt_format=f"torchnav-{name.replace('_', '-')}-v1", action_mode="continuous")
    tc, env, device = run.cfg.train, run.env, run.device
    horizon, gamma, lmbda, tau = int(tc.horizon), float(tc.gamma), float(tc.lmbda), float(tc.tau)

    # -- networks: the policy (pre-tanh mean), a critic and its frozen target copy -------------
    obs_size = env.task.obs_size
    loc_net = Actor(obs_size, 2, tc.hidden, tc.activation, output="linear").to(device)
    critic = Actor(obs_size, 1, tc.hidden, tc.activation, output="linear").to(device)
    critic_target = copy.deepcopy(critic).requires_grad_(False)
    opt_actor = B.adam(loc_net.parameters(), lr=float(tc.lr_actor))
    opt_critic = B.adam(critic.parameters(), lr=float(tc.lr_critic))
    state = {"actor": loc_net, "critic": critic, "critic_target": critic_target, "opt_actor": opt_actor, "opt_critic": opt_critic}
    B.restore(run, state)
    run.counters.setdefault("skipped_updates", 0)
    term = make_smooth(run.task.name, run.cfg.smooth, env)
    ramp = int(run.cfg.smooth.ramp_frames)
    if run.fresh:  # a resumed run continues the checkpoint's episodes
        env.reset()

    def smooth(state) -> Tensor:
        """The smoothed terms, their weight ramped from 0 over ``smooth.ramp_frames`` (continuation:
        learn to move before learning to keep away; a full weight at once can teach standing still)."""
        return term(state) * (min(1.0, run.counters["frames"] / ramp) if ramp else 1.0)

    def sigma() -> float:
        """Exploration noise, annealed linearly over ``train.expl_anneal_frames``."""
        frac = min(1.0, run.counters["frames"] / max(int(tc.expl_anneal_frames), 1))
        return float(tc.expl_sigma_init) + frac * (float(tc.expl_sigma_end) - float(tc.expl_sigma_init))

    def batches() -> Iterator[TensorDict]:
        for _ in range(math.ceil(run.remaining_frames() / (env.num_envs * horizon))):
            yield rollout(env, loc_net, critic_target, smooth, horizon, gamma, sigma(), run.task.outcome_keys)

    mb = int(tc.minibatch_size)

    def update(batch: TensorDict) -> dict[str, Tensor]:
        if tc.lr_decay:  # linearly to 0 at train.total_frames, as SHAC
            for opt, lr in ((opt_actor, tc.lr_actor), (opt_critic, tc.lr_critic)):
                B.decay_lr(opt, lr, run.counters["frames"], int(tc.total_frames))
        # actor: backpropagate the horizon's return through the simulator
        loss = horizon_loss(batch, float(tc.action_reg))
        opt_actor.zero_grad(set_to_none=True)
        loss.backward()
        norm = torch.nn.utils.clip_grad_norm_(loc_net.parameters(), float(tc.max_grad_norm))
        if torch.isfinite(norm) and norm <= float(tc.skip_grad_norm):
            opt_actor.step()
        else:  # an exploding or non-finite gradient: drop this update rather than the policy
            run.counters["skipped_updates"] += 1
        run.counters["updates"] += 1
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

    # -- the loop ------------------------------------------------------------------------------------
    deterministic = loc_net.squashed  # the saved policy: the mean action tanh(loc)
    with B.Progress(run, state, deterministic) as progress:
        for data in batches():
            progress.collected(data)
            losses = update(data)
            progress.updated(losses)  # progress output, logs, periodic evaluation and checkpoints
            if progress.stop:
                break
    return B.stopped(run) if progress.stop else B.finish(run, deterministic())


if __name__ == "__main__":
    B.main_guard(main)
