"""TD3 on batched lidar navigation, with TorchRL's collector and replay buffer.

    python recipes/td3_lidar.py                       # arena, classic curriculum, CPU, a few minutes
    python recipes/td3_lidar.py task.map=warehouse env.num_envs=256 task.curriculum.growth=0.01
    python recipes/td3_lidar.py --resume              # continue the newest run

Reads top to bottom: the run (config, env, run directory: ``builders.setup``) -> actor, twin
critics and their target copies -> replay buffer and collector (actor plus annealed Gaussian
noise) -> the loop: store each batch as 3-step transitions (``train.n_steps``: each sums the rewards
of up to 3 steps and bootstraps from the third), then per gradient step the critics towards the
clipped double-Q target with target-policy smoothing, and every `policy_delay` steps the actor and a soft
update of the targets -> the final evaluation. The update is plain PyTorch, as in CleanRL's TD3:
at this network size TorchRL's ``TD3Loss`` spends most of a gradient step in bookkeeping
(docs/performance.md). Every config key, its default and its documentation: torchnav/train_config.py;
recipes/configs/td3_lidar.yaml holds what this recipe changes.
"""

from __future__ import annotations

import copy
import sys
from pathlib import Path
from typing import Callable

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.modules import AdditiveGaussianModule

sys.path.insert(0, str(Path(__file__).resolve().parent))
import builders as B  # noqa: E402

from torchnav.policy import Actor  # noqa: E402


def make_step(tc, actor, critic, actor_target, critic_target, opt_actor, opt_critic, updates_done: Callable[[], int]):
    """One gradient step ``step(sample) -> {name: loss}``: the critics every step, the actor and the targets
    every ``tc.policy_delay`` steps (``updates_done()``: the steps before this one). ``bench/replay_update.py``
    times it too."""
    gamma, tau, noise, clip = float(tc.gamma), float(tc.tau), float(tc.policy_noise), float(tc.noise_clip)

    def step(sample):
        obs, action, nxt = sample["observation"], sample["action"], sample["next"]
        with torch.no_grad():
            smoothing = (torch.randn_like(action) * noise).clamp(-clip, clip)
            next_action = (actor_target(nxt["observation"]) + smoothing).clamp(-1.0, 1.0)
            q_next = torch.minimum(*critic_target(nxt["observation"], next_action))
            discount = nxt["discount"] if int(tc.n_steps) > 1 else gamma  # gamma ** (steps summed) with n-step returns
            target = nxt["reward"] + discount * (~nxt["terminated"]) * q_next  # truncation still bootstraps
        q1, q2 = critic(obs, action)
        q_loss = (q1 - target).pow(2).mean() + (q2 - target).pow(2).mean()
        opt_critic.zero_grad(set_to_none=True)
        q_loss.backward()
        opt_critic.step()
        if (updates_done() + 1) % int(tc.policy_delay) == 0:
            critic.requires_grad_(False)  # the actor's loss needs no gradients of the critic's weights: a third fewer matmuls
            a_loss = -critic.q1(obs, actor(obs)).mean()
            opt_actor.zero_grad(set_to_none=True)
            a_loss.backward()
            critic.requires_grad_(True)
            opt_actor.step()
            B.soft_update(actor_target, actor, tau)
            B.soft_update(critic_target, critic, tau)
        return {"qvalue": q_loss.detach()}  # read (a host sync) only when the loop logs it

    return step


def main(argv: list[str]) -> dict:
    run = B.setup("td3_lidar", argv, ckpt_format="torchnav-td3-v5", action_mode="continuous")
    tc, env, device = run.cfg.train, run.env, run.device

    # -- networks, optimisers, exploration noise, replay buffer -----------------------------------
    obs_size, act_size = env.task.obs_size, 2
    actor = Actor(obs_size, act_size, tc.hidden).to(device)
    critic = B.TwinQ(obs_size, act_size, tc.hidden).to(device)
    actor_target, critic_target = copy.deepcopy(actor).requires_grad_(False), copy.deepcopy(critic).requires_grad_(False)
    opt_actor = B.adam(actor.parameters(), lr=tc.lr_actor)
    opt_critic = B.adam(critic.parameters(), lr=tc.lr_critic)
    exploration = AdditiveGaussianModule(
        spec=env.action_spec_unbatched, sigma_init=float(tc.expl_sigma_init), sigma_end=float(tc.expl_sigma_end),
        annealing_num_steps=int(tc.expl_anneal_frames), device=device,
    )
    buffer = B.make_replay_buffer(run)
    state = {"actor": actor, "critic": critic, "actor_target": actor_target, "critic_target": critic_target,
             "opt_actor": opt_actor, "opt_critic": opt_critic, "exploration": exploration, "replay": B.ReplayState(buffer)}
    policy = TensorDictSequential(TensorDictModule(actor, in_keys=["observation"], out_keys=["action"]), exploration)
    collector = B.make_collector(run, policy, random_start=True)
    B.restore(run, state, collector)
    step = make_step(tc, actor, critic, actor_target, critic_target, opt_actor, opt_critic, lambda: run.counters["updates"])

    # -- the loop ------------------------------------------------------------------------------------
    with B.Progress(run, state, lambda: actor) as progress:
        for data in collector or ():
            progress.collected(data)
            exploration.step(data.numel())
            losses = B.replay_updates(run, buffer, data, step)
            progress.updated(losses)  # progress output, logs, periodic evaluation and checkpoints
            if progress.stop:
                break
    if collector is not None:
        collector.shutdown()
    return B.stopped(run) if progress.stop else B.finish(run, actor)


if __name__ == "__main__":
    B.main_guard(main)
