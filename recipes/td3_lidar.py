"""TD3 on batched lidar navigation, with TorchRL's collector and replay buffer.

    python recipes/td3_lidar.py                       # arena, classic curriculum, CPU, about 2 minutes
    python recipes/td3_lidar.py task.map=warehouse env.num_envs=256 task.curriculum.growth=0.01
    python recipes/td3_lidar.py --resume              # continue the newest run

Reads top to bottom: config and env (``_train.Trainer``) -> actor, twin critics and
their target copies -> collector (actor plus annealed Gaussian noise) -> update (store
the batch; per gradient step: critics towards the clipped double-Q target with
target-policy smoothing, and every `policy_delay` steps the actor and a soft update of
the targets). The update is plain PyTorch, as in CleanRL's TD3: at this network size
TorchRL's ``TD3Loss`` spends about 60% of a gradient step in bookkeeping
(docs/performance.md#where-the-training-time-goes). The shared loop in
``recipes/_train.py`` does progress output, periodic evaluation, checkpoints and the
final evaluation on `eval.final_episodes` episodes with goals anywhere. Every config
key is documented in recipes/configs/td3_lidar.yaml.
"""

from __future__ import annotations

import copy
import sys
from pathlib import Path

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.modules import MLP, AdditiveGaussianModule

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as C  # noqa: E402
from _train import ReplayState, Trainer, replay_update  # noqa: E402

from torchnav.policy import Actor  # noqa: E402


class TwinQ(nn.Module):
    """Two independent critics ``Q1(s, a), Q2(s, a)``, each an MLP over the concatenated observation and action."""

    def __init__(self, obs_size: int, act_size: int, hidden) -> None:
        super().__init__()
        make = lambda: MLP(in_features=obs_size + act_size, out_features=1, num_cells=list(hidden), activation_class=nn.ReLU)  # noqa: E731
        self.q1, self.q2 = make(), make()

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.cat((obs, action), dim=-1)
        return self.q1(x), self.q2(x)


@torch.no_grad()
def soft_update(target: nn.Module, source: nn.Module, tau: float) -> None:
    """``target <- (1 - tau) target + tau source``, parameter by parameter."""
    for t, s in zip(target.parameters(), source.parameters()):
        t.lerp_(s, tau)


def main(argv: list[str]) -> dict:
    t = Trainer("td3_lidar", argv, ckpt_format="torchnav-td3-v3", action_mode="continuous")
    tc, env, device = t.cfg.train, t.env, t.device

    # -- networks ------------------------------------------------------------------------------
    obs_size, act_size = env.task.obs_size, 2
    actor = Actor(obs_size, act_size, tc.hidden).to(device)
    critic = TwinQ(obs_size, act_size, tc.hidden).to(device)
    actor_target, critic_target = copy.deepcopy(actor).requires_grad_(False), copy.deepcopy(critic).requires_grad_(False)
    opt_actor = C.adam(actor.parameters(), lr=tc.lr_actor)
    opt_critic = C.adam(critic.parameters(), lr=tc.lr_critic)
    exploration = AdditiveGaussianModule(
        spec=env.action_spec_unbatched, sigma_init=float(tc.expl_sigma_init), sigma_end=float(tc.expl_sigma_end),
        annealing_num_steps=int(tc.expl_anneal_frames), device=device,
    )
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(tc.buffer_size, device=device), batch_size=tc.batch_size)
    t.restore({"actor": actor, "critic": critic, "actor_target": actor_target, "critic_target": critic_target,
              "opt_actor": opt_actor, "opt_critic": opt_critic, "exploration": exploration, "replay": ReplayState(buffer)})
    t.export_actor = lambda: actor
    gamma, tau, noise, clip = float(tc.gamma), float(tc.tau), float(tc.policy_noise), float(tc.noise_clip)

    # -- one gradient step: critics every step, actor and targets every `policy_delay` steps ---
    def step(sample):
        obs, action, nxt = sample["observation"], sample["action"], sample["next"]
        with torch.no_grad():
            smoothing = (torch.randn_like(action) * noise).clamp(-clip, clip)
            next_action = (actor_target(nxt["observation"]) + smoothing).clamp(-1.0, 1.0)
            q_next = torch.minimum(*critic_target(nxt["observation"], next_action))
            target = nxt["reward"] + gamma * (~nxt["terminated"]) * q_next  # truncation still bootstraps
        q1, q2 = critic(obs, action)
        q_loss = (q1 - target).pow(2).mean() + (q2 - target).pow(2).mean()
        opt_critic.zero_grad(set_to_none=True)
        q_loss.backward()
        opt_critic.step()
        out = {"qvalue": q_loss.detach()}  # read (a host sync) only when the loop logs it
        if (t.counters["updates"] + 1) % int(tc.policy_delay) == 0:
            a_loss = -critic.q1(torch.cat((obs, actor(obs)), dim=-1)).mean()
            opt_actor.zero_grad(set_to_none=True)
            a_loss.backward()
            opt_actor.step()
            soft_update(actor_target, actor, tau)
            soft_update(critic_target, critic, tau)
        return out

    # -- collection and the shared loop ----------------------------------------------------
    policy = TensorDictSequential(TensorDictModule(actor, in_keys=["observation"], out_keys=["action"]), exploration)
    return t.train(t.collector(policy, random_start=True), replay_update(t, buffer, step), on_frames=exploration.step)


if __name__ == "__main__":
    C.main_guard(main)
