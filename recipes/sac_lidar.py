"""SAC on batched lidar navigation, with TorchRL.

    python recipes/sac_lidar.py                        # arena, 64 envs, CPU
    python recipes/sac_lidar.py task.map=warehouse train.total_frames=500000
    python recipes/sac_lidar.py --resume               # continue the newest run

Reads top to bottom: the run (``builders.setup``) -> a tanh-squashed Gaussian actor with
state-dependent scale, twin Q-networks -> ``SACLoss`` with a learned temperature -> replay buffer
and collector -> the loop (store the batch; `updates_per_batch` gradient steps on sampled
minibatches, soft target updates) -> the final evaluation. Every config key, its default and its documentation: torchnav/train_config.py;
recipes/configs/sac_lidar.yaml holds what this recipe changes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import SACLoss, SoftUpdate

sys.path.insert(0, str(Path(__file__).resolve().parent))
import builders as B  # noqa: E402

from torchnav.policy import Actor  # noqa: E402


def make_critic(obs_size: int, act_size: int, hidden) -> ValueOperator:
    """Q(s, a): an MLP over the concatenated observation and action."""
    net = MLP(in_features=obs_size + act_size, out_features=1, num_cells=list(hidden), activation_class=nn.ReLU)
    return ValueOperator(net, in_keys=["observation", "action"])


def main(argv: list[str]) -> dict:
    run = B.setup("sac_lidar", argv, ckpt_format="torchnav-sac-v1", action_mode="continuous")
    tc, env, device = run.cfg.train, run.env, run.device

    # -- networks and loss: the actor's linear head emits (loc, raw scale) --------------------
    obs_size, act_size = env.task.obs_size, 2
    net = Actor(obs_size, 2 * act_size, tc.hidden, output="linear").to(device)
    params = TensorDictModule(nn.Sequential(net, NormalParamExtractor(scale_mapping="biased_softplus_1.0", scale_lb=1e-4)),
                              in_keys=["observation"], out_keys=["loc", "scale"])
    actor = ProbabilisticActor(params, in_keys=["loc", "scale"], spec=env.action_spec_unbatched, distribution_class=TanhNormal,
                               return_log_prob=False)
    critic = make_critic(obs_size, act_size, tc.hidden).to(device)
    loss = SACLoss(actor_network=actor, qvalue_network=critic, num_qvalue_nets=2, loss_function="l2",
                   alpha_init=float(tc.alpha_init), action_spec=env.action_spec_unbatched, delay_qvalue=True)
    loss.make_value_estimator(gamma=tc.gamma)
    target_update = SoftUpdate(loss, tau=tc.tau)
    opt_actor = B.adam(loss.actor_network_params.flatten_keys().values(), lr=tc.lr_actor)
    opt_critic = B.adam(loss.qvalue_network_params.flatten_keys().values(), lr=tc.lr_critic)
    opt_alpha = B.adam([loss.log_alpha], lr=tc.lr_alpha)
    buffer = B.make_replay_buffer(run)
    state = {"loss": loss, "opt_actor": opt_actor, "opt_critic": opt_critic, "opt_alpha": opt_alpha, "replay": B.ReplayState(buffer)}
    collector = B.make_collector(run, actor, random_start=True)
    B.restore(run, state, collector)

    # -- one gradient step on actor, twin critics and temperature; then soft target update -----
    opts = (opt_actor, opt_critic, opt_alpha)

    def step(sample):
        lv = loss(sample)
        total = lv["loss_actor"] + lv["loss_qvalue"] + lv["loss_alpha"]
        for o in opts:
            o.zero_grad(set_to_none=True)
        total.backward()
        for o in opts:
            o.step()
        target_update.step()
        return {k: lv[k].detach() for k in ("loss_actor", "loss_qvalue", "alpha", "entropy")}  # read only when logged

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
