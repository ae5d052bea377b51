"""Episodes from given starts and goals: ``NavTask.place_episodes``, ``NavEnv.reset_to`` and Gymnasium's reset options."""

import math

import numpy as np
import pytest
import torch

from torchnav.envs import NavEnv, make_line_env, make_nav_env
from torchnav.tasks import NavConfig
from torchnav.sim.geometry import points_clearance

# warehouse: a shelf (box) centred at (-7.5, -3.3), half extents 1.6 x 0.5; the aisle y = -1.9 between shelf rows is free.
SHELF = (-7.5, -3.3)
STARTS = [[-8.0, -1.9, 0.0], [-2.0, -1.9, math.pi / 2], [3.0, -1.9, -1.0], [8.0, -1.9, math.pi]]
GOALS = [[-5.0, -1.9], [0.5, -1.9], [6.0, -1.9], [4.0, -1.9]]


def _env(n=4, **kw):
    return make_nav_env("warehouse", n, seed=3, **kw)


def test_reset_to_starts_and_aims_each_env_where_told():
    env = _env()
    env.reset()
    radius = env.curriculum.radius.clone()
    td = env.reset_to(torch.tensor(STARTS), torch.tensor(GOALS))
    s = env.state
    assert torch.allclose(s.sim.pose, torch.tensor(STARTS)) and torch.allclose(s.start, torch.tensor(STARTS))
    assert torch.allclose(s.goal, torch.tensor(GOALS)) and torch.allclose(td["goal"], torch.tensor(GOALS))
    assert torch.allclose(s.goal_dist, (torch.tensor(GOALS) - torch.tensor(STARTS)[:, :2]).norm(dim=-1))
    assert (s.steps == 0).all() and not s.sim.collided.any()
    # the map's random objects were placed around the given start (the task's start clearance kept)
    need = env.task.max_radius + env.cfg.reset.start_clearance
    assert (points_clearance(s.sim.pose[:, None, :2], s.world)[:, 0] >= need - 1e-5).all()
    assert torch.equal(env.curriculum.radius, radius)  # the curriculum did not move


def test_reset_to_with_a_mask_leaves_the_other_envs_alone_and_later_episodes_are_sampled():
    env = _env(max_steps=3)
    env.reset()
    before = env.state.clone()
    mask = torch.tensor([True, False, True, False])
    env.reset_to(torch.tensor(STARTS), torch.tensor(GOALS), mask)
    s = env.state
    assert torch.allclose(s.sim.pose[mask], torch.tensor(STARTS)[mask])
    assert torch.equal(s.sim.pose[~mask], before.sim.pose[~mask]) and torch.equal(s.goal[~mask], before.goal[~mask])
    td = env.reset()  # no starts given: sampled again
    assert not torch.allclose(env.state.goal, torch.tensor(GOALS))
    assert td["observation"].isfinite().all()


def test_reset_options_are_reset_to_and_go_through_a_transformed_env():
    """``reset_to`` is ``env.reset(td, start=, goal=)``: TorchRL passes the options on to ``_reset``,
    so a TransformedEnv's reset places them too; unknown options and a lone start are named."""
    from torchrl.envs import StepCounter, TransformedEnv

    a, b = _env(), TransformedEnv(_env(), StepCounter())
    ta = a.reset_to(torch.tensor(STARTS), torch.tensor(GOALS))
    tb = b.reset(start=torch.tensor(STARTS), goal=torch.tensor(GOALS))
    assert torch.equal(ta["observation"], tb["observation"]) and torch.equal(a.state.world.boxes, b.base_env.state.world.boxes)
    assert (tb["step_count"] == 0).all()
    with pytest.raises(ValueError, match=r"NavEnv.reset: unknown options \['speed'\]; it takes \['start', 'goal'\]"):
        a.reset(speed=1.0)
    with pytest.raises(ValueError, match="'start' and 'goal' go together"):
        a.reset(start=torch.tensor(STARTS))
    with pytest.raises(ValueError, match=r"LineEnv.reset: unknown options \['start'\]; it takes none"):
        make_line_env(num_envs=2).reset(start=torch.zeros(2, 3))


def test_reset_to_is_reproducible_by_seed():
    worlds = []
    for _ in range(2):
        env = _env()
        env.reset_to(torch.tensor(STARTS), torch.tensor(GOALS))
        worlds.append(env.state.world.boxes.clone())
    assert torch.equal(*worlds)


@pytest.mark.parametrize("start,goal,message", [
    ([[*SHELF, 0.0]] + STARTS[1:], GOALS, r"start of envs \[0\] lies closer than the robot's radius"),
    (STARTS, [list(SHELF)] + GOALS[1:], r"goal of envs \[0\] lies inside an obstacle"),
    ([[20.0, 0.0, 0.0]] + STARTS[1:], GOALS, r"start of envs \[0\].*or its edge"),
    (STARTS[:3], GOALS, r"start must be \(4, 3\)"),
    (STARTS, [[float("nan"), 0.0]] + GOALS[1:], r"goal is not finite in envs \[0\]"),
])
def test_reset_to_refuses_bad_starts_and_goals_before_changing_anything(start, goal, message):
    env = _env()
    env.reset()
    before = env.state.clone()
    with pytest.raises(ValueError, match=message):
        env.reset_to(torch.tensor(start), torch.tensor(goal))
    assert torch.equal(env.state.sim.pose, before.sim.pose)


def test_a_masked_out_env_may_hold_a_bad_start():
    env = _env()
    env.reset()
    start = torch.tensor([[*SHELF, 0.0]] + STARTS[1:])
    env.reset_to(start, torch.tensor(GOALS), torch.tensor([False, True, True, True]))  # env 0 keeps its episode
    assert torch.allclose(env.state.sim.pose[1:], start[1:])


def test_reset_to_needs_a_map():
    env = NavEnv(NavConfig.from_dict({"worlds": {"families": {"rooms": 1.0}}}), num_envs=2)
    with pytest.raises(ValueError, match="generates its worlds"):
        env.reset_to(torch.zeros(2, 3), torch.ones(2, 2))


def test_gymnasium_reset_options_place_the_episodes():
    tg = pytest.importorskip("torchnav.gym")
    vec = tg.navigation_vector_env(num_envs=4, map="warehouse", seed=3)
    obs, _ = vec.reset(options={"start": np.array(STARTS), "goal": np.array(GOALS)})
    assert torch.allclose(vec.env.state.sim.pose, torch.tensor(STARTS)) and obs.shape[0] == 4
    one = tg.navigation_env(map="warehouse")
    one.reset(seed=1, options={"start": STARTS[1], "goal": GOALS[1]})
    assert torch.allclose(one.env.state.goal, torch.tensor([GOALS[1]]))
    with pytest.raises(ValueError, match=r"unknown options \['speed'\]"):
        vec.reset(options={"start": STARTS, "goal": GOALS, "speed": 1})
    with pytest.raises(ValueError, match="go together"):
        one.reset(options={"start": STARTS[1]})
    with pytest.raises(ValueError, match="takes no options"):
        tg.TorchnavVectorEnv(make_line_env(num_envs=2)).reset(options={"start": [[0, 0, 0]] * 2})


# -- evaluation on given episodes: torchnav.evaluation.load_episodes and recipes/evaluate.py --episodes-file ------------

EPISODES_YAML = """map: arena
episodes:
  - start: [-2.0, 0.0, 0.0]
    goal: [2.0, 0.0]
  - start: [0.0, -2.0, 1.57]
    goal: [0.0, 2.5]
  - start: [1.0, 1.0, 3.14]
    goal: [-3.0, -3.0]
"""


@pytest.mark.parametrize("text,message", [
    (None, "no such episodes file"),
    ("episodes: [", "not valid YAML"),
    ("map: arena\n", "non-empty list 'episodes'"),
    ("episodes: [{start: [0, 0, 0], goal: [1, 1]}]\nseed: 3\n", r"unknown keys \['seed'\]"),
    ("episodes: [{start: [0, 0], goal: [1, 1]}]\n", r"episodes\[0\].start must be 3 finite numbers"),
    ("episodes: [{start: [0, 0, 0], goal: [.nan, 1]}]\n", r"episodes\[0\].goal must be 2 finite numbers"),
    ("episodes: [{start: [0, 0, 0], goal: [1, 1], speed: 2}]\n", r"episodes\[0\] must be"),
    ("map: 3\nepisodes: [{start: [0, 0, 0], goal: [1, 1]}]\n", "'map' must be a map name"),
])
def test_load_episodes_names_what_is_wrong(tmp_path, text, message):
    from torchnav.evaluation import load_episodes

    path = tmp_path / "eps.yaml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(ValueError, match=message):
        load_episodes(path)


def test_run_episodes_plays_the_given_episodes_in_order_across_batches():
    from torchnav.envs import make_nav_env
    from torchnav.evaluation import eval_config, run_episodes

    cfg = eval_config(make_nav_env("warehouse", 1).cfg)
    starts, goals = torch.tensor(STARTS + STARTS[:1]), torch.tensor(GOALS + GOALS[:1])
    zero = lambda td: td.set("action", torch.zeros(td.batch_size[0], 2))  # noqa: E731
    res = run_episodes(zero, cfg, 5, max_batch=2, given=(starts, goals))  # batches of 2, 2 and 1
    torch.testing.assert_close(res["straight_line"], (goals - starts[:, :2]).norm(dim=-1))
    assert (res["success"].int() + res["collision"].int() + res["timeout"].int() == 1).all()
    with pytest.raises(ValueError, match="5 episodes, but 4 starts"):
        run_episodes(zero, cfg, 5, given=(starts[:4], goals[:4]))


def test_evaluate_plays_an_episodes_file(tmp_path):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "recipes"))
    import evaluate

    eps = tmp_path / "eps.yaml"
    eps.write_text(EPISODES_YAML)
    out = evaluate.main(["--episodes-file", str(eps), "--threads", "1", "--json", str(tmp_path / "e.json")])
    assert out["episodes"] == 3 and out["map"] == "arena" and len(out["outcomes"]) == 3 and set(out["outcomes"]) <= set("SCT")
    assert out["success"]["rate"] == out["outcomes"].count("S") / 3
    mcap = tmp_path / "eps.mcap"
    evaluate.main(["--episodes-file", str(eps), "--threads", "1", "--record", "2", "--record-path", str(mcap)])
    from torchnav.record.reader import read_recording
    from torchnav.record.replay import episode_frames

    rec = read_recording(mcap)
    starts = [episode_frames(rec, ep)["pose"][0] for ep in sorted(rec.episodes(), key=lambda e: e.env)]
    np.testing.assert_allclose(starts, [[-2.0, 0.0, 0.0], [0.0, -2.0, 1.57]], atol=1e-5)  # the file's first two episodes
    for extra in (["--episodes", "5"], ["--record", "4"], ["--curriculum"], ["--map", "maze"]):
        with pytest.raises(SystemExit):
            evaluate.main(["--episodes-file", str(eps), "--threads", "1", *extra])
    eps.write_text(EPISODES_YAML.replace("[-2.0, 0.0, 0.0]", "[-20.0, 0.0, 0.0]"))  # outside the arena
    with pytest.raises(ValueError, match=r"start of episodes \[0\]"):  # checked for every episode before any runs
        evaluate.main(["--episodes-file", str(eps), "--threads", "1"])
