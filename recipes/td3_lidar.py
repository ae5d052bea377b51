"""TD3 on batched lidar navigation, with TorchRL.

    python recipes/td3_lidar.py                       # arena, classic curriculum, CPU, a few minutes
    python recipes/td3_lidar.py env.map=warehouse env.num_envs=256 curriculum.growth=0.01
    python recipes/td3_lidar.py --resume              # continue the newest run

Reads top to bottom: config and env (``_train.Trainer``) -> networks -> loss ->
collector -> update (store the batch, update critics every step and the actor
every `policy_delay` steps, soft-update targets). The shared loop in
``recipes/_train.py`` does progress output, periodic evaluation, checkpoints and
the final evaluation on `eval.final_episodes` episodes with goals anywhere. Every
config key is documented in recipes/configs/td3_lidar.yaml.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.modules import MLP, AdditiveGaussianModule, ValueOperator
from torchrl.objectives import SoftUpdate, TD3Loss

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as C  # noqa: E402
from _train import Trainer, main_guard, replay_update  # noqa: E402

from torchnav.policy import Actor  # noqa: E402

def make_critic(obs_size: int, act_size: int, hidden) -> ValueOperator:
    """Q(s, a): an MLP over the concatenated observation and action."""
    net = MLP(in_features=obs_size + act_size, out_features=1, num_cells=list(hidden), activation_class=nn.ReLU)
    return ValueOperator(net, in_keys=["observation", "action"])


def main(argv: list[str]) -> dict:
    t = Trainer("td3_lidar", argv, ckpt_format="torchnav-td3-v2")
    tc, env, device = t.cfg.train, t.env, t.device
    if t.task.config.action.mode != "continuous":
        raise C.ConfigError("TD3 needs task.action.mode=continuous")

    # -- networks and loss -------------------------------------------------------------------
    obs_size, act_size = env.task.obs_size, 2
    actor_net = Actor(obs_size, act_size, tc.hidden).to(device)
    actor = TensorDictModule(actor_net, in_keys=["observation"], out_keys=["action"])
    critic = make_critic(obs_size, act_size, tc.hidden).to(device)
    exploration = AdditiveGaussianModule(
        spec=env.action_spec_unbatched, sigma_init=float(tc.expl_sigma_init), sigma_end=float(tc.expl_sigma_end),
        annealing_num_steps=int(tc.expl_anneal_frames), device=device,
    )
    loss = TD3Loss(
        actor_network=actor, qvalue_network=critic, action_spec=env.action_spec_unbatched, num_qvalue_nets=2,
        policy_noise=tc.policy_noise, noise_clip=tc.noise_clip, loss_function="l2", delay_actor=True, delay_qvalue=True,
    )
    loss.make_value_estimator(gamma=tc.gamma)
    target_update = SoftUpdate(loss, tau=tc.tau)
    opt_actor = torch.optim.Adam(loss.actor_network_params.flatten_keys().values(), lr=tc.lr_actor)
    opt_critic = torch.optim.Adam(loss.qvalue_network_params.flatten_keys().values(), lr=tc.lr_critic)
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(tc.buffer_size, device=device), batch_size=tc.batch_size)
    modules = {"loss": loss, "opt_actor": opt_actor, "opt_critic": opt_critic, "exploration": exploration}
    t.restore(modules)
    t.export_actor = lambda: actor_net

    # -- one gradient step: critics every step, actor and targets every `policy_delay` steps ---
    def step(sample):
        q_loss, _ = loss.value_loss(sample)
        opt_critic.zero_grad(set_to_none=True)
        q_loss.backward()
        opt_critic.step()
        out = {"qvalue": q_loss.item()} if t.counters["batches"] % 10 == 0 else {}
        if (t.counters["updates"] + 1) % int(tc.policy_delay) == 0:
            a_loss, _ = loss.actor_loss(sample)
            opt_actor.zero_grad(set_to_none=True)
            a_loss.backward()
            opt_actor.step()
            target_update.step()
        return out

    # -- collection and the shared loop ----------------------------------------------------
    remaining = t.remaining_frames()
    collector = Collector(
        env, TensorDictSequential(actor, exploration), frames_per_batch=int(tc.frames_per_batch),
        total_frames=max(remaining, int(tc.frames_per_batch)), init_random_frames=int(tc.init_random_frames) if t.fresh else 0,
        device=device, auto_register_policy_transforms=False,
    ) if remaining > 0 else None
    stopped = t.train(collector, replay_update(t, buffer, step), lambda: {k: m.state_dict() for k, m in modules.items()},
                      on_frames=exploration.step)
    if stopped:
        return {"run_dir": str(t.run), "stopped": True, "counters": t.counters}
    return t.finish()


if __name__ == "__main__":
    main_guard(main)
