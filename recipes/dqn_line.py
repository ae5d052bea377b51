"""DQN on batched line following with a discrete set of wheel commands, with TorchRL.

    python recipes/dqn_line.py                         # course track, 7 wheel-speed pairs, CPU
    python recipes/dqn_line.py task.track=oval "task.action.discrete_set=[[1,1],[1,0.3],[0.3,1]]"
    python recipes/dqn_line.py --resume                # continue the newest run

Reads top to bottom: config and env (``LineEnv`` with ``action.mode=discrete``,
one-hot actions over ``task.action.discrete_set``) -> Q-network (normalised
observations, MLP) -> ``DQNLoss`` (double DQN, soft target updates) -> epsilon-
greedy collector -> the loop (replay updates as TD3's and SAC's) -> the final evaluation.
The saved ``actor.pt`` holds the Q-network and the action table of (left, right)
commands, so ``python -m torchnav.export`` writes C that returns wheel commands.
Every config key, its default and its documentation: torchnav/train_config.py;
recipes/configs/dqn_line.yaml holds what this recipe changes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from tensordict.nn import TensorDictSequential
from torchrl.modules import EGreedyModule, QValueActor
from torchrl.objectives import DQNLoss, SoftUpdate

sys.path.insert(0, str(Path(__file__).resolve().parent))
import builders as B  # noqa: E402

from torchnav.policy import Actor  # noqa: E402


def main(argv: list[str]) -> dict:
    run = B.setup("dqn_line", argv, ckpt_format="torchnav-dqn-line-v1", action_mode="discrete")
    tc, env, device = run.cfg.train, run.env, run.device
    table = torch.tensor(run.task.config.action.discrete_set, dtype=torch.float32)
    run.meta["action_table"] = table  # the saved policy returns wheel commands

    # -- Q-network, loss and exploration -------------------------------------------------------
    qnet = Actor(env.task.obs_size, len(table), tc.hidden, tc.activation, output="argmax").to(device)
    if run.fresh:
        qnet.set_normalization(*B.observation_stats(env, int(tc.obs_stats_steps)))
    qvalue = QValueActor(qnet, in_keys=["observation"], spec=env.action_spec_unbatched)
    loss = DQNLoss(qvalue, loss_function="l2", delay_value=True, double_dqn=True, action_space=env.action_spec_unbatched)
    loss.make_value_estimator(gamma=tc.gamma)
    target_update = SoftUpdate(loss, tau=tc.tau)
    optim = B.adam(loss.parameters(), lr=tc.lr)
    exploration = EGreedyModule(env.action_spec_unbatched, eps_init=float(tc.eps_init), eps_end=float(tc.eps_end),
                                annealing_num_steps=int(tc.eps_anneal_frames), device=device)
    buffer = B.make_replay_buffer(run)
    state = {"loss": loss, "optim": optim, "exploration": exploration, "replay": B.ReplayState(buffer)}
    collector = B.make_collector(run, TensorDictSequential(qvalue, exploration), random_start=True)
    B.restore(run, state, collector)

    def step(sample):
        lv = loss(sample)
        optim.zero_grad(set_to_none=True)
        lv["loss"].backward()
        torch.nn.utils.clip_grad_norm_(loss.parameters(), float(tc.max_grad_norm))
        optim.step()
        target_update.step()
        return {"qvalue": lv["loss"].detach(), "epsilon": exploration.eps.detach()}  # read only when logged

    # -- the loop ------------------------------------------------------------------------------------
    with B.Progress(run, state, lambda: qnet) as progress:
        for data in collector or ():
            progress.collected(data)
            exploration.step(data.numel())
            losses = B.replay_updates(run, buffer, data, step)
            progress.updated(losses)  # progress output, logs, periodic evaluation and checkpoints
            if progress.stop:
                break
    if collector is not None:
        collector.shutdown()
    return B.stopped(run) if progress.stop else B.finish(run, qnet)


if __name__ == "__main__":
    B.main_guard(main)
