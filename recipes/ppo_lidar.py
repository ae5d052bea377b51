"""PPO on batched lidar navigation, with TorchRL.

    python recipes/ppo_lidar.py                        # arena, 4096 envs, CPU, under a minute
    python recipes/ppo_lidar.py task.map=warehouse train.total_frames=20000000
    python recipes/ppo_lidar.py --resume               # continue the newest run

Reads top to bottom: the run (``builders.setup``) -> observation statistics from a
random-action rollout (baked into both networks as normalisation) -> a tanh-squashed Gaussian
policy with a state-independent log-std and a value network -> ``ClipPPOLoss`` with GAE ->
collector -> the loop (advantages over the whole batch, then `epochs` passes of shuffled
minibatches) -> the final evaluation. With ``train.recurrent: gru`` the policy is a
``RecurrentActor`` (MLP -> GRU cell -> head; the value network stays feed-forward) whose state
each env carries through collection, and minibatches are whole per-env sequences. Every config
key, its default and its documentation: torchnav/train_config.py; recipes/configs/ppo_lidar.yaml
holds what this recipe changes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator, set_recurrent_mode
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

sys.path.insert(0, str(Path(__file__).resolve().parent))
import builders as B  # noqa: E402

from torchnav.policy import STATE_KEY, Actor, RecurrentActor, RecurrentStep, with_state  # noqa: E402


def scale_of(log_std: torch.Tensor, loc: torch.Tensor) -> torch.Tensor:
    """The Gaussian's ``scale = exp(log_std)``, the same for every state, shaped like ``loc``."""
    return log_std.clamp(-5.0, 1.0).exp().expand_as(loc)


class GaussianParams(nn.Module):
    """``obs -> (loc, scale)``: ``loc`` from the network, ``scale = exp(log_std)`` shared by all states."""

    def __init__(self, net: Actor, act_size: int, init_log_std: float) -> None:
        super().__init__()
        self.net = net
        self.log_std = nn.Parameter(torch.full((act_size,), float(init_log_std)))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self.net(obs)
        return loc, scale_of(self.log_std, loc)


class GaussianScale(nn.Module):
    """``loc -> scale = exp(log_std)``: the recurrent policy's scale (its ``loc`` comes from a ``RecurrentStep``)."""

    def __init__(self, act_size: int, init_log_std: float) -> None:
        super().__init__()
        self.log_std = nn.Parameter(torch.full((act_size,), float(init_log_std)))

    def forward(self, loc: torch.Tensor) -> torch.Tensor:
        return scale_of(self.log_std, loc)


def gaussian_policy(loc_net: Actor | RecurrentActor, act_size: int, init_log_std: float, action_spec) -> tuple[ProbabilisticActor, nn.Module]:
    """The tanh-squashed Gaussian policy of ``loc_net`` (a ``RecurrentActor`` through a ``RecurrentStep``)
    and the module holding its ``log_std``."""
    if loc_net.recurrent:
        std = GaussianScale(act_size, init_log_std).to(loc_net.obs_loc.device)
        params = TensorDictSequential(RecurrentStep(loc_net, out_key="loc"), TensorDictModule(std, in_keys=["loc"], out_keys=["scale"]))
    else:
        std = GaussianParams(loc_net, act_size, init_log_std).to(loc_net.obs_loc.device)
        params = TensorDictModule(std, in_keys=["observation"], out_keys=["loc", "scale"])
    return ProbabilisticActor(params, in_keys=["loc", "scale"], spec=action_spec, distribution_class=TanhNormal, return_log_prob=True), std


def main(argv: list[str], name: str = "ppo_lidar") -> dict:
    """Train; ``name`` picks ``configs/<name>.yaml``, whose ``task`` section picks the task (``ppo_line.py`` reuses this)."""
    run = B.setup(name, argv, ckpt_format=f"torchnav-{name.replace('_', '-')}-v1", action_mode="continuous")
    tc, env, device = run.cfg.train, run.env, run.device

    # -- networks: both normalise observations with statistics of a random-action rollout -----
    obs_size, act_size = env.task.obs_size, 2
    recurrent = tc.recurrent != "off"
    if recurrent:
        loc_net = RecurrentActor(obs_size, act_size, tc.hidden, tc.activation, output="linear", state_size=tc.recurrent_hidden).to(device)
    else:
        loc_net = Actor(obs_size, act_size, tc.hidden, tc.activation, output="linear").to(device)
    value_net = Actor(obs_size, 1, tc.hidden, tc.activation, output="linear").to(device)
    if run.fresh:
        loc, scale = B.observation_stats(env, int(tc.obs_stats_steps))
        loc_net.set_normalization(loc, scale)
        value_net.set_normalization(loc, scale)
    policy, std = gaussian_policy(loc_net, act_size, tc.init_log_std, env.action_spec_unbatched)
    critic = ValueOperator(value_net, in_keys=["observation"])

    loss = ClipPPOLoss(policy, critic, clip_epsilon=tc.clip_epsilon, entropy_coeff=tc.entropy_coeff,
                       critic_coeff=tc.critic_coeff, loss_critic_type="l2", normalize_advantage=True)
    gae = GAE(gamma=tc.gamma, lmbda=tc.lmbda, value_network=critic, average_gae=False)
    optim = B.adam(loss.parameters(), lr=tc.lr, eps=1e-5)
    state = {"loss": loss, "optim": optim}
    if recurrent:  # each env carries the policy's state from step to step, and a checkpoint saves it
        carry = state["recurrent"] = B.RecurrentCarry(env.num_envs, tc.recurrent_hidden, device)
        collector = B.make_collector(run, policy, env=with_state(env, loc_net, start=carry))
    else:
        collector = B.make_collector(run, policy)
    B.restore(run, state, collector)

    # -- update: advantages over the batch, then `epochs` passes of shuffled minibatches -------
    # (the batch is (envs, steps); a recurrent policy's minibatches are whole rows: each env's
    # steps in order, from the state stored at its first step, reset where an episode starts)
    mb = int(tc.minibatch_size)
    # what GAE and the loss read; indexing minibatches out of the whole batch (poses, reward
    # terms, episode statistics) cost more than the gradient steps themselves
    keys = ("observation", "action", "action_log_prob", *(("next", k) for k in ("observation", "reward", "done", "terminated")),
            *((STATE_KEY, ("episode", "length")) if recurrent else ()))

    def update(batch):
        if tc.lr_decay:  # linearly towards 0 at train.total_frames: the first batch at train.lr, the last at lr / batches
            B.decay_lr(optim, tc.lr, run.counters["frames"] - int(tc.frames_per_batch), int(tc.total_frames))
        batch = batch.select(*keys)
        with torch.no_grad():
            gae(batch)
        rows, per = (batch, mb // batch.shape[-1]) if recurrent else (batch.reshape(-1), mb)
        for _ in range(int(tc.epochs)):
            for idx in torch.randperm(rows.shape[0], device=device).split(per):
                with set_recurrent_mode(recurrent):
                    lv = loss(rows[idx])
                total = lv["loss_objective"] + lv["loss_critic"] + lv["loss_entropy"]
                optim.zero_grad(set_to_none=True)
                total.backward()
                torch.nn.utils.clip_grad_norm_(loss.parameters(), float(tc.max_grad_norm))
                optim.step()
                run.counters["updates"] += 1
        out = {k: lv[k].detach() for k in ("loss_objective", "loss_critic", "loss_entropy")}  # read only when logged
        out["log_std"] = std.log_std.detach().mean()
        return out

    # -- the loop ------------------------------------------------------------------------------------
    deterministic = loc_net.squashed  # the saved policy: the mean action tanh(loc)
    with B.Progress(run, state, deterministic) as progress:
        for data in collector or ():
            progress.collected(data)
            if recurrent:
                carry.keep(data)
            losses = update(data)
            progress.updated(losses)  # progress output, logs, periodic evaluation and checkpoints
            if progress.stop:
                break
    if collector is not None:
        collector.shutdown()
    return B.stopped(run) if progress.stop else B.finish(run, deterministic())


if __name__ == "__main__":
    B.main_guard(main)
