"""The MAPPO / IPPO recipe (recipes/mappo_nav.py) with tiny budgets: both critics, evaluation, checkpoints, resume."""

from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "recipes"))

TINY = ["threads=1", "env.num_envs=8", "task.max_steps=20", "train.frames_per_batch=64", "train.minibatch_size=32", "train.epochs=2",
        "train.hidden=[32,32]", "train.obs_stats_steps=2", "eval.interval_frames=64", "eval.episodes=4", "eval.final_episodes=8",
        "checkpoint.interval_frames=64", "logger.progress=false"]
OUTCOMES = ("team_success", "at_goal", "robot_collision", "collision", "timeout")


def _mappo(args):
    return importlib.import_module("mappo_nav").main(args)


@pytest.mark.parametrize("critic", ["central", "local"])
def test_mappo_smoke_and_resume(tmp_path, critic):
    run = tmp_path / "run"
    args = TINY + [f"train.critic={critic}"]
    res = _mappo(args + ["train.total_frames=128", f"logger.run_dir={run}"])
    assert res["frames"] == 128
    for f in ("config.yaml", "checkpoint.pt", "actor.pt", "summary.json"):
        assert (run / f).is_file(), f
    s = json.loads((run / "summary.json").read_text())["eval"]
    assert s["episodes"] == 8 and s["robots"] == 32  # circle_swap with 4 robots, every slot present
    for k in OUTCOMES:
        assert 0.0 <= s[k]["rate"] <= 1.0
    assert s["at_goal"]["count"] + s["collision"]["count"] <= s["robots"]  # a robot parks at its first goal or collision
    ck = torch.load(run / "checkpoint.pt", weights_only=True)
    assert ck["counters"]["frames"] == 128 and ck["counters"]["updates"] == 2 * 2 * 2  # 2 batches x 2 epochs x 2 minibatches
    assert ck["policy"]["algorithm"] == "mappo" and ck["policy"]["task"] == "multi_nav"
    # the value network is the MultiAgentMLP the critic asked for
    value_keys = [k for k in ck["loss"] if "critic_network" in k and k.endswith("weight")]
    first = ck["loss"][value_keys[0]]
    assert first.shape[-1] == (4 if critic == "central" else 1) * ck["policy"]["obs_size"], (value_keys[0], first.shape)

    # actor.pt is the shared deterministic policy the final evaluation ran: evaluating it again gives the same counts
    from torchnav.evaluation import FINAL_EVAL_SEED
    from torchnav.policy import load_policy
    from torchnav.protocol import task_protocol

    sp = load_policy(run / "actor.pt")
    again = task_protocol(sp.config()).evaluate(sp.policy, 8, FINAL_EVAL_SEED, "cpu")
    assert {k: again[k]["count"] for k in OUTCOMES} == {k: s[k]["count"] for k in OUTCOMES}

    # resume: continues from the checkpoint exactly as an uninterrupted run of the same length
    res2 = _mappo(args + ["train.total_frames=192", f"checkpoint.resume={run}"])
    assert res2["frames"] == 192
    whole = tmp_path / "whole"
    _mappo(args + ["train.total_frames=192", f"logger.run_dir={whole}"])
    a, b = (torch.load(r / "checkpoint.pt", weights_only=True) for r in (run, whole))
    assert a["counters"]["updates"] == b["counters"]["updates"] == 12
    for k, v in b["loss"].items():
        assert torch.equal(a["loss"][k], v), k


def test_mappo_refuses_what_it_cannot_do(tmp_path):
    from torchnav.config import ConfigError

    with pytest.raises(ConfigError, match="train.critic"):
        _mappo(TINY + ["train.critic=global", f"logger.run_dir={tmp_path / 'a'}"])
    with pytest.raises(ConfigError, match="train.recurrent='gru'"):
        _mappo(TINY + ["train.recurrent=gru", f"logger.run_dir={tmp_path / 'c'}"])
