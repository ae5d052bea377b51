"""DQN on batched line following with a discrete set of wheel commands, with TorchRL.

    python recipes/dqn_line.py                         # course track, 7 wheel-speed pairs, CPU
    python recipes/dqn_line.py task.track=oval "task.action.discrete_set=[[1,1],[1,0.3],[0.3,1]]"
    python recipes/dqn_line.py --resume                # continue the newest run

Reads top to bottom: config and env (``LineEnv`` with ``action.mode=discrete``,
one-hot actions over ``task.action.discrete_set``) -> Q-network (normalised
observations, MLP) -> ``DQNLoss`` (double DQN, soft target updates) -> epsilon-
greedy collector -> replay updates shared with TD3/SAC (``recipes/_train.py``).
The saved ``actor.pt`` holds the Q-network and the action table of (left, right)
commands, so ``python -m torchnav.export`` writes C that returns wheel commands.
Every config key is documented in recipes/configs/dqn_line.yaml.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from tensordict.nn import TensorDictSequential
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.modules import EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, SoftUpdate

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as C  # noqa: E402
from _train import ReplayState, Trainer, replay_update  # noqa: E402
from ppo_lidar import observation_stats  # noqa: E402

from torchnav.policy import Actor  # noqa: E402


def main(argv: list[str]) -> dict:
    t = Trainer("dqn_line", argv, ckpt_format="torchnav-dqn-line-v1", action_mode="discrete")
    tc, env, device = t.cfg.train, t.env, t.device
    table = torch.tensor(t.task.config.action.discrete_set, dtype=torch.float32)

    # -- Q-network, loss and exploration -------------------------------------------------------
    qnet = Actor(env.task.obs_size, len(table), tc.hidden, tc.activation, output="argmax").to(device)
    if t.fresh:
        qnet.set_normalization(*observation_stats(env, int(tc.obs_stats_steps)))
    qvalue = QValueActor(qnet, in_keys=["observation"], spec=env.action_spec_unbatched)
    loss = DQNLoss(qvalue, loss_function="l2", delay_value=True, double_dqn=True, action_space=env.action_spec_unbatched)
    loss.make_value_estimator(gamma=tc.gamma)
    target_update = SoftUpdate(loss, tau=tc.tau)
    optim = C.adam(loss.parameters(), lr=tc.lr)
    exploration = EGreedyModule(env.action_spec_unbatched, eps_init=float(tc.eps_init), eps_end=float(tc.eps_end),
                                annealing_num_steps=int(tc.eps_anneal_frames), device=device)
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(tc.buffer_size, device=device), batch_size=tc.batch_size)
    t.restore({"loss": loss, "optim": optim, "exploration": exploration, "replay": ReplayState(buffer)})
    t.export_actor = lambda: qnet

    def step(sample):
        lv = loss(sample)
        optim.zero_grad(set_to_none=True)
        lv["loss"].backward()
        torch.nn.utils.clip_grad_norm_(loss.parameters(), float(tc.max_grad_norm))
        optim.step()
        target_update.step()
        return {"qvalue": lv["loss"].detach(), "epsilon": exploration.eps.detach()}  # read only when logged

    return t.train(t.collector(TensorDictSequential(qvalue, exploration), random_start=True), replay_update(t, buffer, step),
                   meta=t.policy_meta(action_table=table), on_frames=exploration.step)


if __name__ == "__main__":
    C.main_guard(main)
