"""SAC on batched lidar navigation, with TorchRL.

    python recipes/sac_lidar.py                        # arena, 64 envs, CPU
    python recipes/sac_lidar.py task.map=warehouse train.total_frames=500000
    python recipes/sac_lidar.py --resume               # continue the newest run

Reads top to bottom: config and env (``_train.Trainer``) -> a tanh-squashed
Gaussian actor with state-dependent scale, twin Q-networks -> ``SACLoss`` with a
learned temperature -> collector -> update (store the batch; `updates_per_batch`
gradient steps on sampled minibatches, soft target updates). Replay, progress,
evaluation and checkpoints are shared with TD3 (``recipes/_train.py``). Every
config key is documented in recipes/configs/sac_lidar.yaml.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import SACLoss, SoftUpdate

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as C  # noqa: E402
from _train import ReplayState, Trainer, replay_update  # noqa: E402

from torchnav.policy import Actor  # noqa: E402


def make_critic(obs_size: int, act_size: int, hidden) -> ValueOperator:
    """Q(s, a): an MLP over the concatenated observation and action."""
    net = MLP(in_features=obs_size + act_size, out_features=1, num_cells=list(hidden), activation_class=nn.ReLU)
    return ValueOperator(net, in_keys=["observation", "action"])


def main(argv: list[str]) -> dict:
    t = Trainer("sac_lidar", argv, ckpt_format="torchnav-sac-v1", action_mode="continuous")
    tc, env, device = t.cfg.train, t.env, t.device

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
    opt_actor = C.adam(loss.actor_network_params.flatten_keys().values(), lr=tc.lr_actor)
    opt_critic = C.adam(loss.qvalue_network_params.flatten_keys().values(), lr=tc.lr_critic)
    opt_alpha = C.adam([loss.log_alpha], lr=tc.lr_alpha)
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(tc.buffer_size, device=device), batch_size=tc.batch_size)
    t.restore({"loss": loss, "opt_actor": opt_actor, "opt_critic": opt_critic, "opt_alpha": opt_alpha, "replay": ReplayState(buffer)})
    t.export_actor = lambda: net.squashed(act_size)  # deterministic action tanh(loc)

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

    return t.train(t.collector(actor, random_start=True), replay_update(t, buffer, step))


if __name__ == "__main__":
    C.main_guard(main)
