"""The multi-robot classical baseline (ORCA, torchnav/controllers/orca.py) and its evaluation through
recipes/evaluate.py, beside a tiny MAPPO checkpoint, on the same seeded episodes."""

from __future__ import annotations

import importlib
import json
import math
import sys
from pathlib import Path

import pytest
import torch
from tensordict.nn import TensorDictModuleBase

from torchnav.config import ConfigError
from torchnav.controllers import CONTROLLERS, MULTI_CONTROLLERS, ORCA, make_controller
from torchnav.controllers.orca import orca_half_planes, solve_velocities
from torchnav.envs import make_multi_nav_env
from torchnav.evaluation import FINAL_EVAL_SEED
from torchnav.protocol import MultiNavProtocol, task_protocol
from torchnav.tasks import MultiNavConfig
from torchnav.record.reader import read_recording

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "recipes"))
OUTCOMES = ("team_success", "at_goal", "robot_collision", "collision", "timeout")


class GoStraight(TensorDictModuleBase):
    """Every robot drives at its goal, blind to the others (the single-robot go_to_goal, per robot)."""

    in_keys, out_keys = ["pose", "goal"], ["action"]

    def __init__(self, cfg):
        super().__init__()
        self.ctrl = make_controller("go_to_goal", nav=cfg)

    def forward(self, group):
        flat = group.select("pose", "goal").reshape(-1)
        group.set("action", self.ctrl(flat)["action"].reshape(*group.batch_size, 2))
        return group


def test_head_on_swap_orca_passes_where_go_straight_collides():
    # two robots facing each other across an empty map, each with its goal at the other's start
    cfg = MultiNavConfig.from_dict({"map": "empty", "max_steps": 200, "robots": {"n": 2, "scenario": "circle_swap", "circle_radius": 3.0}})
    task = task_protocol(cfg)
    orca = task.evaluate(make_controller("orca"), 8, FINAL_EVAL_SEED, "cpu")
    assert orca["team_success"]["count"] == 8 and orca["at_goal"]["count"] == 16
    assert orca["collision"]["count"] == 0
    straight = task.evaluate(GoStraight(cfg), 8, FINAL_EVAL_SEED, "cpu")
    assert straight["robot_collision"]["count"] == 16 and straight["team_success"]["count"] == 0


def test_orca_is_a_torchrl_policy_of_the_env():
    env = make_multi_nav_env("arena", 3, 4, robots={"min_n": 2}, max_steps=30)
    ctrl = make_controller("orca").bind(env)
    assert ctrl.out_keys == [("agents", "action")] and ("agents", "ranges") in ctrl.in_keys
    r = env.rollout(40, ctrl, break_when_any_done=False)
    a = r["agents", "action"]
    assert a.shape == (3, 40, 4, 2) and a.abs().max() <= 1.0
    # the agent group alone (as MultiNavProtocol passes it) gets the same actions
    td = env.reset()
    group = td["agents"].exclude("action")
    assert torch.equal(ctrl(group)["action"], ctrl(td)["agents", "action"])


def test_orca_half_plane_and_solver():
    # a robot at the origin driving at 1 m/s towards a static point 2 m ahead (radius 0.5, horizon 1 s):
    # it is outside the velocity obstacle, so its velocity stays allowed and the nearest allowed is itself
    rel_pos, vel = torch.tensor([[[2.0, 0.0]]]), torch.tensor([[[1.0, 0.0]]])
    point, normal = orca_half_planes(rel_pos, vel, vel, torch.tensor([[0.5]]), torch.tensor([[1.0]]), torch.tensor([[1.0]]), 0.1)
    assert float((normal * (vel - point)).sum()) >= -1e-6
    # ... with a 4 s horizon it would hit it: the constraint now excludes straight on at 1 m/s
    point, normal = orca_half_planes(rel_pos, vel, vel, torch.tensor([[0.5]]), torch.tensor([[1.0]]), torch.tensor([[4.0]]), 0.1)
    assert float((normal * (vel - point)).sum()) < 0
    v = solve_velocities(vel[:, 0], point, normal, torch.ones(1, 1, dtype=torch.bool), 1.0, 16)
    assert float((normal[:, 0] * (v - point[:, 0])).sum()) >= -1e-5 and v.norm() <= 1.0 + 1e-6
    # the nearest feasible velocity to (1, 0) in {v_x <= 0.5} within the unit disc is (0.5, 0)
    line_point, line_normal = torch.tensor([[[0.5, 0.0]]]), torch.tensor([[[-1.0, 0.0]]])
    v = solve_velocities(torch.tensor([[1.0, 0.0]]), line_point, line_normal, torch.ones(1, 1, dtype=torch.bool), 1.0, 16)
    assert torch.allclose(v, torch.tensor([[0.5, 0.0]]), atol=1e-6)
    # two lines whose intersection is the optimum: v_x <= 0.5 and v_y >= 0.2, from pref (1, 0)
    pts, nrm = torch.tensor([[[0.5, 0.0], [0.0, 0.2]]]), torch.tensor([[[-1.0, 0.0], [0.0, 1.0]]])
    v = solve_velocities(torch.tensor([[1.0, 0.0]]), pts, nrm, torch.ones(1, 2, dtype=torch.bool), 1.0, 16)
    assert torch.allclose(v, torch.tensor([[0.5, 0.2]]), atol=1e-6)


def test_orca_gains_are_validated():
    assert "orca" in MULTI_CONTROLLERS and "orca" not in CONTROLLERS  # compare.py's single-robot list stays as it was
    assert isinstance(make_controller("orca", time_horizon=3.0), ORCA)
    for gains, match in [({"time_horizon": 0.0}, "orca.time_horizon must be > 0"), ({"obstacle_horizon": -1.0}, "orca.obstacle_horizon must be > 0"),
                         ({"margin": -0.1}, "orca.margin must be >= 0"), ({"neighbours": -1}, "orca.neighbours must be a whole number"),
                         ({"neighbours": 1.5}, "orca.neighbours"), ({"keep_right": math.pi}, r"orca.keep_right must be in \[0, pi/2\)"),
                         ({"horizon": 1.0}, "unknown key 'horizon' \\(did you mean 'time_horizon'\\?\\)")]:
        with pytest.raises(ConfigError, match=match):
            make_controller("orca", **gains)
    with pytest.raises(ConfigError, match="unknown controller 'orc'.*did you mean 'orca'"):
        make_controller("orc")
    with pytest.raises(ConfigError, match="continuous"):
        make_controller("orca", nav=MultiNavConfig.from_dict({"action": {"mode": "discrete"}}))


# -- recipes/evaluate.py on a multi_nav checkpoint and on the controller -----------------------------------

TINY = ["threads=1", "env.num_envs=8", "task.max_steps=40", "train.frames_per_batch=64", "train.minibatch_size=32", "train.epochs=1",
        "train.hidden=[16,16]", "train.obs_stats_steps=2", "eval.interval_frames=0", "eval.final_episodes=4", "logger.progress=false",
        "train.total_frames=64"]


@pytest.fixture(scope="module")
def mappo_actor(tmp_path_factory):
    run = tmp_path_factory.mktemp("mappo") / "run"
    importlib.import_module("mappo_nav").main(TINY + [f"logger.run_dir={run}"])
    return run / "actor.pt"


def _evaluate(args):
    return importlib.import_module("evaluate").main(args + ["--threads", "1"])


def test_evaluate_multi_nav_checkpoint_on_other_robot_counts(mappo_actor, tmp_path):
    out = _evaluate([str(mappo_actor), "--episodes", "3", "--seed", "7", "--set", "robots.n=8", "--json", str(tmp_path / "e.json")])
    assert out["task"] == "multi_nav" and out["episodes"] == 3 and out["robots"] == 24 and out["task_config"]["robots"]["n"] == 8
    saved = json.loads((tmp_path / "e.json").read_text())
    for k in OUTCOMES:
        assert 0.0 <= saved[k]["rate"] <= 1.0
    with pytest.raises(SystemExit):  # --curriculum is navigation's
        _evaluate([str(mappo_actor), "--episodes", "2", "--curriculum"])
    with pytest.raises(ConfigError, match="robots.n"):
        _evaluate([str(mappo_actor), "--episodes", "2", "--set", "robots.n=40"])
    for who in ([str(mappo_actor)], ["--controller", "orca", "--set", "robots.n=3"]):  # --record writes every robot
        path = tmp_path / f"{len(who)}.mcap"
        _evaluate([*who, "--episodes", "2", "--record", "1", "--record-path", str(path)])
        (episode,) = read_recording(path).episodes()
        assert len(episode.robots) == (4 if len(who) == 1 else 3)


def test_controller_and_checkpoint_play_the_same_episodes(mappo_actor, monkeypatch):
    # every method builds its evaluation env from the same config and seed: the same starts and goals
    envs = []
    make = MultiNavProtocol.eval_env

    def spy(self, *args):
        envs.append(make(self, *args))
        return envs[-1]

    monkeypatch.setattr(MultiNavProtocol, "eval_env", spy)
    common = ["--episodes", "4", "--set", "robots.n=3", "robots.scenario=random", "curriculum.mode=off"]
    learned = _evaluate([str(mappo_actor), *common])
    orca = _evaluate([str(mappo_actor), "--controller", "orca", *common])
    assert learned["robots"] == orca["robots"] == 12 and orca["controller"] == "orca" and learned["checkpoint"] == orca["checkpoint"]
    a, b = (e.state for e in envs)
    assert torch.equal(a.start, b.start) and torch.equal(a.goal, b.goal) and torch.equal(a.world.boxes, b.world.boxes)
    # a third run with another seed plays other episodes
    _evaluate([str(mappo_actor), "--controller", "orca", *common, "--seed", "1"])
    assert not torch.equal(envs[2].state.start, a.start)


def test_evaluate_controller_without_checkpoint(tmp_path):
    out = _evaluate(["--controller", "orca", "--episodes", "4", "--set", "robots.n=4", "robots.scenario=circle_swap",
                     "--gains", "time_horizon=2.5", "--json", str(tmp_path / "o.json")])
    assert out["checkpoint"] is None and out["controller"] == "orca" and out["robots"] == 16
    assert out["team_success"]["count"] == 4 and out["collision"]["count"] == 0  # circle_swap in the open arena: solved
    nav = _evaluate(["--controller", "reactive", "--episodes", "3", "--map", "empty"])
    assert nav["task"] == "nav" and nav["episodes"] == 3
    for bad in (["--controller", "orcas"], ["--gains", "k_v=1"], ["--controller", "orca", "--curriculum"]):
        with pytest.raises(SystemExit):
            _evaluate(bad)
    with pytest.raises(ConfigError, match="orca.k_v must be > 0"):
        _evaluate(["--controller", "orca", "--episodes", "1", "--gains", "k_v=0"])


def test_evaluate_controller_refuses_another_tasks_checkpoint(mappo_actor):
    with pytest.raises(SystemExit):
        _evaluate([str(mappo_actor), "--controller", "reactive"])
