"""SAC on batched lidar navigation, with TorchRL's collector and replay buffer.

    python recipes/sac_lidar.py                        # arena, 64 envs, CPU
    python recipes/sac_lidar.py task.map=warehouse train.total_frames=500000
    python recipes/sac_lidar.py --resume               # continue the newest run

Reads top to bottom: the run (``builders.setup``) -> a tanh-squashed Gaussian actor whose linear head
emits the mean and a state-dependent scale, twin critics and their target copy, a learned temperature
-> replay buffer and collector (the actor samples) -> the loop: store each batch, then per gradient
step the critics towards the soft clipped double-Q target, the actor against the smaller critic and the
temperature towards the target entropy (minus the action size), and a soft update of the target critics
-> the final evaluation of the mean action. The update is plain PyTorch, as in td3_lidar.py (TorchRL's
``SACLoss`` spends most of a gradient step in bookkeeping at this network size). Every config key, its
default and its documentation: torchnav/train_config.py; recipes/configs/sac_lidar.yaml holds what this
recipe changes.
"""

from __future__ import annotations

import copy
import math
import sys
from pathlib import Path

import torch
import torch.nn.functional as F
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.modules import ProbabilisticActor, TanhNormal

sys.path.insert(0, str(Path(__file__).resolve().parent))
import builders as B  # noqa: E402

from torchnav.policy import Actor  # noqa: E402


class Temperature(nn.Module):
    """The entropy temperature ``alpha = exp(log_alpha)``, learned; a module so that checkpoints hold it."""

    def __init__(self, alpha: float) -> None:
        super().__init__()
        self.log_alpha = nn.Parameter(torch.tensor(math.log(alpha)))


def main(argv: list[str]) -> dict:
    run = B.setup("sac_lidar", argv, ckpt_format="torchnav-sac-v3", action_mode="continuous")
    tc, env, device = run.cfg.train, run.env, run.device

    # -- networks: the actor's linear head emits (loc, raw scale); the collector samples TanhNormal(loc, scale)
    obs_size, act_size = env.task.obs_size, 2
    net = Actor(obs_size, 2 * act_size, tc.hidden, output="linear").to(device)
    extract = NormalParamExtractor(scale_mapping="biased_softplus_1.0", scale_lb=1e-4)
    actor = ProbabilisticActor(TensorDictModule(nn.Sequential(net, extract), in_keys=["observation"], out_keys=["loc", "scale"]),
                               in_keys=["loc", "scale"], spec=env.action_spec_unbatched, distribution_class=TanhNormal, return_log_prob=False)
    critic = B.TwinQ(obs_size, act_size, tc.hidden).to(device)
    critic_target = copy.deepcopy(critic).requires_grad_(False)
    temperature = Temperature(float(tc.alpha_init)).to(device)
    opt_actor = B.adam(net.parameters(), lr=tc.lr_actor)
    opt_critic = B.adam(critic.parameters(), lr=tc.lr_critic)
    opt_alpha = B.adam(temperature.parameters(), lr=tc.lr_alpha)
    buffer = B.make_replay_buffer(run)
    state = {"actor": net, "critic": critic, "critic_target": critic_target, "temperature": temperature,
             "opt_actor": opt_actor, "opt_critic": opt_critic, "opt_alpha": opt_alpha, "replay": B.ReplayState(buffer)}
    collector = B.make_collector(run, actor, random_start=True)
    B.restore(run, state, collector)
    gamma, tau, target_entropy = float(tc.gamma), float(tc.tau), -float(act_size)

    def sample(obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparametrised action ``tanh(u)``, ``u ~ N(loc, scale)``, and its log-density (with the tanh's Jacobian)."""
        loc, scale = extract(net(obs))
        u = loc + scale * torch.randn_like(loc)
        log_prob = (-0.5 * ((u - loc) / scale).pow(2) - scale.log() - 0.5 * math.log(2 * math.pi)).sum(-1, keepdim=True)
        log_prob = log_prob - (2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))).sum(-1, keepdim=True)  # log(1 - tanh(u)^2)
        return torch.tanh(u), log_prob

    # -- one gradient step: critics, actor, temperature, then the target critics -------------------
    def step(sample_td):
        obs, action, nxt = sample_td["observation"], sample_td["action"], sample_td["next"]
        alpha = temperature.log_alpha.exp().detach()
        with torch.no_grad():
            next_action, next_log_prob = sample(nxt["observation"])
            q_next = torch.minimum(*critic_target(nxt["observation"], next_action)) - alpha * next_log_prob
            target = nxt["reward"] + gamma * (~nxt["terminated"]) * q_next  # truncation still bootstraps
        q1, q2 = critic(obs, action)
        q_loss = (q1 - target).pow(2).mean() + (q2 - target).pow(2).mean()
        opt_critic.zero_grad(set_to_none=True)
        q_loss.backward()
        opt_critic.step()
        critic.requires_grad_(False)  # the actor's loss needs no gradients of the critics' weights
        new_action, log_prob = sample(obs)
        a_loss = (alpha * log_prob - torch.minimum(*critic(obs, new_action))).mean()
        opt_actor.zero_grad(set_to_none=True)
        a_loss.backward()
        critic.requires_grad_(True)
        opt_actor.step()
        alpha_loss = -(temperature.log_alpha * (log_prob.detach() + target_entropy)).mean()
        opt_alpha.zero_grad(set_to_none=True)
        alpha_loss.backward()
        opt_alpha.step()
        B.soft_update(critic_target, critic, tau)
        return {"loss_actor": a_loss.detach(), "loss_qvalue": q_loss.detach(), "alpha": alpha, "entropy": -log_prob.detach().mean()}

    # -- the loop ------------------------------------------------------------------------------------
    deterministic = lambda: net.squashed(act_size)  # noqa: E731  (the saved policy: the action tanh(loc))
    with B.Progress(run, state, deterministic) as progress:
        for data in collector or ():
            progress.collected(data)
            losses = B.replay_updates(run, buffer, data, step)
            progress.updated(losses)  # progress output, logs, periodic evaluation and checkpoints
            if progress.stop:
                break
    if collector is not None:
        collector.shutdown()
    return B.stopped(run) if progress.stop else B.finish(run, deterministic())


if __name__ == "__main__":
    B.main_guard(main)
