"""The recurrent PPO option (``train.recurrent: gru``): the GRU actor, its per-env state through
collection and evaluation, whole-sequence training, the v3 policy file and config errors.
(The recipe's smoke run and resume are in tests/test_recipes.py, case ``ppo_lidar_gru``.)"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest
import torch
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp
from torchrl.modules import set_recurrent_mode

from torchnav.config import ConfigError
from torchnav.envs import NavEnv
from torchnav.policy import RECURRENT_FORMAT, STATE_KEY, Actor, RecurrentActor, RecurrentStep, load_policy, save_policy, to_policy, with_state
from torchnav.tasks import NavConfig

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "recipes"))

SHORT = NavConfig.from_dict({"max_steps": 5, "curriculum": {"mode": "off"}})  # episodes end inside a batch's rows


def _actor(env, output="linear", seed=0):
    torch.manual_seed(seed)
    return RecurrentActor(env.task.obs_size, 2, [16], "relu", output=output, state_size=8)


def test_unroll_is_step_after_step():
    actor = _actor(NavEnv(SHORT, num_envs=2))
    obs, h0 = torch.randn(3, 6, actor.obs_size), torch.randn(3, actor.state_size)
    is_init = torch.zeros(3, 6, dtype=torch.bool)
    is_init[0, 2] = is_init[2, 0] = is_init[2, 4] = True
    out, hs = actor.unroll(obs, h0, is_init)
    h = h0
    for t in range(6):
        o, h = actor.step(obs[:, t], h, is_init[:, t])
        assert torch.allclose(o, out[:, t], atol=1e-6) and torch.allclose(h, hs[:, t], atol=1e-6)


def test_collected_log_probs_equal_the_sequence_mode_log_probs():
    """What PPO's first minibatch sees: the policy unrolled over each env's row of a collected batch
    (from the state stored at its first step, reset where an episode starts) gives the log-probs
    the collector recorded step by step."""
    ppo = importlib.import_module("ppo_lidar")
    env = NavEnv(SHORT, num_envs=4, seed=3)
    policy, _ = ppo.gaussian_policy(_actor(env), 2, -0.5, env.action_spec_unbatched)
    collector = Collector(with_state(env, policy.module[0].module[0].actor), policy, frames_per_batch=4 * 12, total_frames=2 * 4 * 12, auto_register_policy_transforms=False)
    batches = [b.clone() for b in collector]
    batch = batches[1]  # the second batch starts mid-episode, from a carried state
    assert batch.shape == (4, 12)
    starts = batch["episode", "length"].squeeze(-1) == 0
    assert starts[:, 1:].any(), "no episode started inside a row: the reset inside a sequence is untested"
    assert batch[STATE_KEY][:, 0].abs().sum() > 0, "the second batch should start from a non-zero carried state"
    # the state stored at each step is the one the previous step wrote (zeros where an episode starts)
    cont = ~starts[:, 1:]
    assert torch.equal(batch[STATE_KEY][:, 1:][cont], batch["next", STATE_KEY][:, :-1][cont])
    assert not batch[STATE_KEY][:, 1:][~cont].any()
    with torch.no_grad(), set_recurrent_mode(True):
        dist = policy.get_dist(batch.select("observation", STATE_KEY, ("episode", "length")).clone())
        lp = dist.log_prob(batch["action"])
    assert torch.allclose(lp, batch["action_log_prob"], atol=1e-4), float((lp - batch["action_log_prob"]).abs().max())


@torch.no_grad()
def test_state_resets_at_episode_start():
    """An env's action at its episode's first step is that of a fresh policy on the same observation,
    though the state it carries in is the previous episode's."""
    env = NavEnv(SHORT, num_envs=3, seed=1)
    step = RecurrentStep(_actor(env, output="tanh"))
    td = env.reset()
    starts = 0
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for t in range(12):
            td = step(td)
            fresh = step(td.select("observation", ("episode", "length")).clone())["action"]  # no carried state: zeros
            new = td["episode", "length"].squeeze(-1) == 0
            assert torch.equal(td["action"][new], fresh[new])
            if t > 0 and new.any():
                starts += int(new.sum())
                assert not torch.equal(td[STATE_KEY][new], torch.zeros_like(td[STATE_KEY][new])), "the state before the reset was already zero"
            td = env.maybe_reset(step_mdp(env.step(td)))  # as recording does (torchnav.record.record_rollout)
    assert starts > 0


def test_policy_file_round_trips_and_evaluates(tmp_path):
    from torchnav.evaluation import run_episodes

    env = NavEnv(SHORT, num_envs=2)
    actor = _actor(env, output="tanh")
    actor.set_normalization(torch.randn(actor.obs_size), torch.rand(actor.obs_size) + 0.5)
    save_policy(tmp_path / "actor.pt", actor, task="nav", task_config={"max_steps": 5}, algorithm="ppo")
    sp = load_policy(tmp_path / "actor.pt")
    assert isinstance(sp.actor, RecurrentActor) and sp.actor.spec() == actor.spec()
    assert torch.load(tmp_path / "actor.pt", weights_only=True)["format"] == RECURRENT_FORMAT
    for k, v in actor.state_dict().items():
        assert torch.equal(sp.actor.state_dict()[k], v), k
    obs, h = torch.randn(4, actor.obs_size), actor.initial_state(4)
    assert torch.equal(sp.actor.step(obs, h)[0], actor.step(obs, h)[0])
    assert isinstance(sp.policy, RecurrentStep)
    res = run_episodes(sp.policy, SHORT, 6, seed=2)
    assert res["success"].numel() == 6
    assert torch.equal(res["length"], run_episodes(to_policy(actor), SHORT, 6, seed=2)["length"])


def test_inconsistent_recurrent_file_is_named(tmp_path):
    from torchnav.checkpoint import save_checked
    from torchnav.policy import policy_payload

    actor = _actor(NavEnv(SHORT, num_envs=2), output="tanh")
    payload = policy_payload(actor, task="nav", task_config={}, algorithm="ppo")
    del payload["state_size"]
    save_checked(tmp_path / "bad.pt", payload)
    with pytest.raises(ValueError, match="bad.pt: policy checkpoint is inconsistent"):
        load_policy(tmp_path / "bad.pt")


def test_export_refuses_a_recurrent_policy(tmp_path):
    from torchnav.export.common import network_of

    actor = _actor(NavEnv(SHORT, num_envs=2), output="tanh")
    save_policy(tmp_path / "actor.pt", actor, task="nav", task_config={}, algorithm="ppo")
    with pytest.raises(ValueError, match="recurrent .GRU. policies cannot be exported"):
        network_of(load_policy(tmp_path / "actor.pt"))


def test_recurrent_actor_refuses_bad_arguments():
    with pytest.raises(ValueError, match="not 'argmax'"):
        RecurrentActor(4, 3, [8], output="argmax")
    with pytest.raises(ValueError, match="state_size must be >= 1"):
        RecurrentActor(4, 2, [8], state_size=0)
    assert not Actor(4, 2, [8]).recurrent


@pytest.mark.parametrize("override,message", [
    ("train.recurrent=lstm", "train.recurrent='lstm': must be off or gru"),
    ("train.recurrent_hidden=0", "train.recurrent_hidden=0: must be an integer >= 1"),
    ("train.minibatch_size=100", "train.minibatch_size=100 must be a multiple of the 8 steps per env"),
])
def test_bad_recurrent_config_is_named(tmp_path, override, message):
    ppo = importlib.import_module("ppo_lidar")
    args = ["env.num_envs=16", "train.frames_per_batch=128", "train.recurrent=gru", override, f"logger.run_dir={tmp_path / 'run'}"]
    with pytest.raises(ConfigError) as e:
        ppo.main(args)
    assert message in str(e.value)
    assert not (tmp_path / "run").exists()


def test_unquoted_off_in_a_config_file_is_explained(tmp_path):
    import yaml

    from torchnav.train_config import build

    data = yaml.safe_load((ROOT / "recipes" / "configs" / "ppo_lidar.yaml").read_text())
    data["train"] = {"recurrent": False}  # what `recurrent: off` reads as
    with pytest.raises(ConfigError, match='quote "off"'):
        build("ppo_lidar", data, [], "x.yaml")
