"""MAPPO / IPPO on the multi-robot navigation task (``MultiNavEnv``), with TorchRL.

    python recipes/mappo_nav.py                              # arena, circle_swap, 4 robots, 256 envs
    python recipes/mappo_nav.py train.critic=local           # IPPO: each robot's value from its own observation
    python recipes/mappo_nav.py task.robots.scenario=crossing task.robots.n=6
    python recipes/mappo_nav.py --resume                     # continue the newest run

Reads top to bottom as ``ppo_lidar.py``, on the agent group ``("agents", ...)`` of batch
``(envs, robots)``: one policy network (a torchnav ``Actor``, applied to every robot's observation:
parameters shared, any robot count) gives a tanh-squashed Gaussian with a state-independent
log-std; the value network is TorchRL's ``MultiAgentMLP`` with shared parameters, centralised
(``train.critic: central``, MAPPO: every robot slot's observation in, one value per robot out) or
not (``local``, IPPO). ``GAE`` and ``ClipPPOLoss`` read the per-robot reward, done and terminated
(``loss.set_keys``), so each robot has its own advantages; a robot parked at its goal or after a
collision is done from then on (reward 0, no bootstrap) until its env resets. The saved actor.pt is
the shared network's mean action, run per robot (``torchnav.policy.load_policy``; task ``multi_nav``).
Every config key, its default and its documentation: torchnav/train_config.py;
recipes/configs/mappo_nav.yaml holds what this recipe changes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

sys.path.insert(0, str(Path(__file__).resolve().parent))
import builders as B  # noqa: E402
from ppo_lidar import GaussianParams  # noqa: E402

from torchnav.policy import Actor  # noqa: E402

AGENT_KEYS = {k: ("agents", k) for k in ("action", "reward", "done", "terminated")}
LOG_PROB, VALUE, ADVANTAGE, TARGET = ("agents", "action_log_prob"), ("agents", "state_value"), ("agents", "advantage"), ("agents", "value_target")


class AgentsValue(nn.Module):
    """``obs (..., N, D) -> value (..., N, 1)``: the observation normalised as the policy's, then a
    parameter-shared ``MultiAgentMLP``, centralised (every robot slot's observation) or local."""

    def __init__(self, obs_size: int, n_agents: int, centralised: bool, hidden: tuple[int, ...], activation: str) -> None:
        super().__init__()
        self.register_buffer("obs_loc", torch.zeros(obs_size))
        self.register_buffer("obs_scale", torch.ones(obs_size))
        act = {"relu": nn.ReLU, "tanh": nn.Tanh}[activation]
        self.mlp = MultiAgentMLP(n_agent_inputs=obs_size, n_agent_outputs=1, n_agents=n_agents, centralised=centralised,
                                 share_params=True, num_cells=list(hidden), activation_class=act)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.mlp((obs - self.obs_loc) / self.obs_scale)


def main(argv: list[str], name: str = "mappo_nav") -> dict:
    run = B.setup(name, argv, ckpt_format="torchnav-mappo-nav-v1", action_mode="continuous")
    tc, env, device = run.cfg.train, run.env, run.device

    # -- networks: both normalise observations with statistics of a random-action rollout ---------
    obs_size, act_size, n = env.task.obs_size, 2, env.n_robots
    loc_net = Actor(obs_size, act_size, tc.hidden, tc.activation, output="linear").to(device)  # every robot's, shared
    value_net = AgentsValue(obs_size, n, tc.critic == "central", tc.hidden, tc.activation).to(device)
    if run.fresh:
        loc, scale = B.observation_stats(env, int(tc.obs_stats_steps), key=("agents", "observation"))
        loc_net.set_normalization(loc, scale)
        value_net.obs_loc.copy_(loc)
        value_net.obs_scale.copy_(scale)
    std = GaussianParams(loc_net, act_size, tc.init_log_std).to(device)
    params = TensorDictModule(std, in_keys=[("agents", "observation")], out_keys=[("agents", "loc"), ("agents", "scale")])
    policy = ProbabilisticActor(params, in_keys={"loc": ("agents", "loc"), "scale": ("agents", "scale")}, out_keys=[AGENT_KEYS["action"]],
                                spec=env.full_action_spec_unbatched, distribution_class=TanhNormal, return_log_prob=True, log_prob_key=LOG_PROB)
    critic = ValueOperator(value_net, in_keys=[("agents", "observation")], out_keys=[VALUE])

    loss = ClipPPOLoss(policy, critic, clip_epsilon=tc.clip_epsilon, entropy_coeff=tc.entropy_coeff,
                       critic_coeff=tc.critic_coeff, loss_critic_type="l2", normalize_advantage=True)
    loss.set_keys(**AGENT_KEYS, sample_log_prob=LOG_PROB, value=VALUE, advantage=ADVANTAGE, value_target=TARGET)
    gae = GAE(gamma=tc.gamma, lmbda=tc.lmbda, value_network=critic, average_gae=False)
    gae.set_keys(reward=AGENT_KEYS["reward"], done=AGENT_KEYS["done"], terminated=AGENT_KEYS["terminated"],
                 value=VALUE, advantage=ADVANTAGE, value_target=TARGET)
    optim = B.adam(loss.parameters(), lr=tc.lr, eps=1e-5)
    state = {"loss": loss, "optim": optim}
    collector = B.make_collector(run, policy)
    B.restore(run, state, collector)

    # -- update: per-robot advantages over the batch (envs, steps), then `epochs` passes of shuffled
    # minibatches of env steps, each with all its robots (the centralised critic reads them all) ------
    mb = int(tc.minibatch_size)
    keys = (("agents", "observation"), AGENT_KEYS["action"], LOG_PROB,
            *(("next", "agents", k) for k in ("observation", "reward", "done", "terminated")))

    def update(batch):
        if tc.lr_decay:
            B.decay_lr(optim, tc.lr, run.counters["frames"] - int(tc.frames_per_batch), int(tc.total_frames))
        batch = batch.select(*keys)
        with torch.no_grad():
            gae(batch)
        rows = batch.reshape(-1)
        for _ in range(int(tc.epochs)):
            for idx in torch.randperm(rows.shape[0], device=device).split(mb):
                lv = loss(rows[idx])
                total = lv["loss_objective"] + lv["loss_critic"] + lv["loss_entropy"]
                optim.zero_grad(set_to_none=True)
                total.backward()
                torch.nn.utils.clip_grad_norm_(loss.parameters(), float(tc.max_grad_norm))
                optim.step()
                run.counters["updates"] += 1
        out = {k: lv[k].detach() for k in ("loss_objective", "loss_critic", "loss_entropy")}
        out["log_std"] = std.log_std.detach().mean()
        return out

    # -- the loop --------------------------------------------------------------------------------------
    deterministic = loc_net.squashed  # the saved policy: every robot's mean action tanh(loc)
    with B.Progress(run, state, deterministic) as progress:
        for data in collector or ():
            progress.collected(data)
            losses = update(data)
            progress.updated(losses)
            if progress.stop:
                break
    if collector is not None:
        collector.shutdown()
    return B.stopped(run) if progress.stop else B.finish(run, deterministic())


if __name__ == "__main__":
    B.main_guard(main)
