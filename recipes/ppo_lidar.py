"""PPO on batched lidar navigation, with TorchRL.

    python recipes/ppo_lidar.py                        # arena, 4096 envs, CPU, under a minute
    python recipes/ppo_lidar.py task.map=warehouse train.total_frames=20000000
    python recipes/ppo_lidar.py --resume               # continue the newest run

Reads top to bottom: config and env (``_train.Trainer``) -> observation statistics
from a random-action rollout (baked into both networks as normalisation) -> a
tanh-squashed Gaussian policy with a state-independent log-std and a value
network -> ``ClipPPOLoss`` with GAE -> collector -> update (advantages over the
whole batch, then `epochs` passes of shuffled minibatches). The shared loop in
``recipes/_train.py`` does progress output, periodic evaluation, checkpoints and
the final evaluation. Every config key is documented in recipes/configs/ppo_lidar.yaml.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as C  # noqa: E402
from _train import Trainer  # noqa: E402

from torchnav.policy import Actor  # noqa: E402


class GaussianParams(nn.Module):
    """``obs -> (loc, scale)``: ``loc`` from the network, ``scale = exp(log_std)`` shared by all states."""

    def __init__(self, net: Actor, act_size: int, init_log_std: float) -> None:
        super().__init__()
        self.net = net
        self.log_std = nn.Parameter(torch.full((act_size,), float(init_log_std)))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self.net(obs)
        return loc, self.log_std.clamp(-5.0, 1.0).exp().expand_as(loc)


@torch.no_grad()
def observation_stats(env, steps: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and standard deviation ``(obs_size,)`` of the observation under random actions for ``steps`` steps."""
    td = env.rollout(steps, break_when_any_done=False)
    obs = td["observation"].reshape(-1, td["observation"].shape[-1]).double()
    return obs.mean(0).float(), obs.std(0).clamp(min=1e-2).float()


def main(argv: list[str], name: str = "ppo_lidar") -> dict:
    """Train; ``name`` picks ``configs/<name>.yaml``, whose ``task`` section picks the task (``ppo_line.py`` reuses this)."""
    t = Trainer(name, argv, ckpt_format=f"torchnav-{name.replace('_', '-')}-v1", action_mode="continuous")
    tc, env, device = t.cfg.train, t.env, t.device

    # -- networks: both normalise observations with statistics of a random-action rollout -----
    obs_size, act_size = env.task.obs_size, 2
    loc_net = Actor(obs_size, act_size, tc.hidden, tc.activation, output="linear").to(device)
    value_net = Actor(obs_size, 1, tc.hidden, tc.activation, output="linear").to(device)
    if t.fresh:
        loc, scale = observation_stats(env, int(tc.obs_stats_steps))
        loc_net.set_normalization(loc, scale)
        value_net.set_normalization(loc, scale)
    params = TensorDictModule(GaussianParams(loc_net, act_size, tc.init_log_std).to(device), in_keys=["observation"], out_keys=["loc", "scale"])
    policy = ProbabilisticActor(params, in_keys=["loc", "scale"], spec=env.action_spec_unbatched, distribution_class=TanhNormal,
                                return_log_prob=True)
    critic = ValueOperator(value_net, in_keys=["observation"])

    loss = ClipPPOLoss(policy, critic, clip_epsilon=tc.clip_epsilon, entropy_coeff=tc.entropy_coeff,
                       critic_coeff=tc.critic_coeff, loss_critic_type="l2", normalize_advantage=True)
    gae = GAE(gamma=tc.gamma, lmbda=tc.lmbda, value_network=critic, average_gae=False)
    optim = torch.optim.Adam(loss.parameters(), lr=tc.lr, eps=1e-5)
    t.restore({"loss": loss, "optim": optim})
    t.export_actor = lambda: loc_net.squashed()

    # -- update: advantages over the batch, then `epochs` passes of shuffled minibatches -------
    mb = int(tc.minibatch_size)
    # what GAE and the loss read; indexing minibatches out of the whole batch (poses, reward
    # terms, episode statistics) cost more than the gradient steps themselves
    keys = ("observation", "action", "action_log_prob", *(("next", k) for k in ("observation", "reward", "done", "terminated")))

    def update(batch):
        batch = batch.select(*keys)
        with torch.no_grad():
            gae(batch)
        flat = batch.reshape(-1)
        for _ in range(int(tc.epochs)):
            for idx in torch.randperm(flat.numel(), device=device).split(mb):
                lv = loss(flat[idx])
                total = lv["loss_objective"] + lv["loss_critic"] + lv["loss_entropy"]
                optim.zero_grad(set_to_none=True)
                total.backward()
                torch.nn.utils.clip_grad_norm_(loss.parameters(), float(tc.max_grad_norm))
                optim.step()
                t.counters["updates"] += 1
        out = {k: lv[k].detach() for k in ("loss_objective", "loss_critic", "loss_entropy")}  # read only when logged
        out["log_std"] = params.module.log_std.detach().mean()
        return out

    return t.train(t.collector(policy), update)


if __name__ == "__main__":
    C.main_guard(main)
