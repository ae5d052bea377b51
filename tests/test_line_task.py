"""The line-following task and env: observation history, progress that rocking cannot farm,
termination, laps, the PD baseline, TorchRL contract (specs, masked resets, seeds)."""

from __future__ import annotations


import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded, OneHot
from torchrl.envs.utils import check_env_specs, step_mdp

from torchnav.config import ConfigError
from torchnav.controllers.line_follower import LineFollower
from torchnav.envs import make_line_env
from torchnav.envs.line_env import EPISODE_KEYS, FLAG_KEYS
from torchnav.tasks import LineConfig
from torchnav.tracks import TrackError


def constant(action):
    def policy(td):
        td["action"] = torch.as_tensor(action, dtype=torch.float32).expand(td.batch_size[0], -1).clone()
        return td

    return policy


def run(env, policy, steps):
    td = env.reset()
    out = []
    for _ in range(steps):
        td = env.step(policy(td))
        out.append(td["next"].clone())
        td = step_mdp(td)
    return torch.stack(out, 1)


# --------------------------------------------------------------------------- contract


@pytest.mark.parametrize("num_envs", [1, 3, 16])
def test_check_env_specs_at_several_batch_sizes(num_envs):
    env = make_line_env("course", num_envs=num_envs)
    check_env_specs(env)
    assert env.observation_spec["observation"].shape == (num_envs, 30)
    assert isinstance(env.action_spec, Bounded) and env.action_spec.shape == (num_envs, 2)
    keys = set(env.observation_spec["episode"].keys())
    assert keys == set(EPISODE_KEYS) | {"term_progress", "term_off_line", "term_failure"}


@pytest.mark.parametrize(
    "overrides",
    [
        {"action": {"mode": "discrete"}},
        {"sensors": {"mode": "binary", "noise_std": 0.1, "count": 8, "spacing": 0.01}},
        {"sensors": {"mode": "smooth"}, "observation": {"history": 1}},
        {"distance_sensor": {"enabled": True}, "reward": {"weights": {"turning": -0.01, "lap": 10.0}}},
        {"action": {"forward_only": True}, "robot": {"lin_acc_max": 2.0}},
    ],
    ids=["discrete", "binary8", "smooth", "range+terms", "forward+acc"],
)
def test_check_env_specs_for_options(overrides):
    env = make_line_env("loop", num_envs=2, **overrides)
    check_env_specs(env)
    td = env.rollout(15, break_when_any_done=False)
    for t in range(15):
        assert env.observation_spec.is_in(td["next"][:, t].select(*env.observation_spec.keys()))


def test_output_keys():
    env = make_line_env("oval", num_envs=2)
    td = env.reset()
    assert set(td.keys()) == {"observation", "sensors", "pose", "ranges", "lap_s", *FLAG_KEYS, "reward_terms", "episode",
                              "done", "terminated", "truncated"}
    assert td["on_line"].all()  # starts put the array over the line


def test_discrete_actions_are_one_hot_wheel_pairs():
    env = make_line_env("oval", num_envs=2, action={"mode": "discrete"})
    assert isinstance(env.action_spec, OneHot) and env.action_spec.shape == (2, 7)
    a = torch.nn.functional.one_hot(torch.tensor([0, 3]), 7)
    wheels = env.task.command(a)
    torch.testing.assert_close(wheels, torch.tensor([[0.5, 0.5], [0.5, 0.0]]))


def test_nan_actions_raise_a_clear_error():
    env = make_line_env("oval", num_envs=3)
    td = env.reset()
    td["action"] = torch.tensor([[0.0, 0.0], [float("nan"), 0.0], [0.0, 0.0]])
    with pytest.raises(ValueError, match=r"NaN or inf in envs \[1\]"):
        env.step(td)


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match=r"env.sensors: unknown key 'cont' \(did you mean 'count'\?\)"):
        make_line_env("oval", num_envs=1, sensors={"cont": 3})
    with pytest.raises(ConfigError, match="unknown term 'speed'"):
        LineConfig.from_dict({"reward": {"weights": {"speed": 1.0}}})
    with pytest.raises(TrackError, match="unknown track"):
        make_line_env("ovl", num_envs=1)


def test_determinism_under_seed_and_masked_reset():
    a = make_line_env("course", num_envs=4, seed=5, sensors={"noise_std": 0.05})
    b = make_line_env("course", num_envs=4, seed=5, sensors={"noise_std": 0.05})
    ra, rb = a.rollout(20, constant([0.6, 0.5]), break_when_any_done=False), b.rollout(20, constant([0.6, 0.5]), break_when_any_done=False)
    torch.testing.assert_close(ra["next", "observation"], rb["next", "observation"])
    c = make_line_env("course", num_envs=4, seed=6, sensors={"noise_std": 0.05})
    assert not torch.equal(c.reset()["pose"], a.reset()["pose"])
    # masked reset: envs 0 and 2 restart, 1 and 3 are left bit-identical
    before = a.state.clone()
    a.reset(TensorDict({"_reset": torch.tensor([[True], [False], [True], [False]])}, batch_size=[4]))
    after = a.state
    for i in (1, 3):
        assert (after[i] == before[i]).all()
    assert not torch.equal(after.sim.pose[0], before.sim.pose[0]) and after.steps[0] == 0


def test_state_dict_restores_the_generator():
    env = make_line_env("oval", num_envs=3, seed=1)
    sd = env.state_dict()
    p1 = env.reset()["pose"]
    env.load_state_dict(sd)
    torch.testing.assert_close(env.reset()["pose"], p1)


# --------------------------------------------------------------------------- task behaviour


def test_observation_is_the_sensor_history_oldest_first():
    env = make_line_env("course", num_envs=3, seed=2, sensors={"noise_std": 0.05})
    gen = torch.Generator().manual_seed(0)

    def policy(td):
        td["action"] = torch.rand(3, 2, generator=gen) * 0.6 + 0.2
        return td

    td0 = env.reset()
    sensors = [td0["sensors"]] * 5
    td = td0
    for _ in range(8):
        td = env.step(policy(td))
        nxt = td["next"]
        sensors.append(nxt["sensors"])
        if nxt["done"].any():
            break
        expected = torch.cat(sensors[-6:], dim=-1)  # (B, 30): frame t-5 first, current last
        torch.testing.assert_close(nxt["observation"], expected)
        td = step_mdp(td)
    assert td0["observation"].shape == (3, 30)
    torch.testing.assert_close(td0["observation"], td0["sensors"].repeat(1, 6))


def test_rocking_back_and_forth_earns_nothing():
    env = make_line_env("oval", num_envs=4, seed=0, reset={"start": 0.3, "heading_noise": 0.0, "lateral_noise": 0.0})
    fwd, back = [0.6, 0.6], [-0.6, -0.6]
    steps = [fwd] * 5 + [back] * 5
    td = env.reset()
    total = torch.zeros(4)
    for a in steps * 4:
        td = env.step(constant(a)(td))
        total += td["next", "reward_terms", "progress"][:, 0]
        td = step_mdp(td)
    assert total.abs().max() < 1e-3
    assert td["episode", "progress_m"].abs().max() < 1e-4


def test_stopping_terminates_after_stop_time():
    env = make_line_env("oval", num_envs=2, termination={"stop_time": 0.5})  # 10 steps at dt = 0.05
    out = run(env, constant([0.0, 0.0]), 10)
    assert not out["done"][:, :9].any() and out["terminated"][:, 9].all() and out["stalled"][:, 9].all()
    assert (out["reward_terms", "failure"][:, 9] == -5.0).all()


def test_leaving_the_line_terminates_after_the_grace_period():
    env = make_line_env("oval", num_envs=1, reset={"start": 0.3, "heading_noise": 0.0, "lateral_noise": 0.0},
                        termination={"off_line_time": 0.25})  # 5 steps
    out = run(env, constant([1.0, 0.2]), 40)[0]  # hard right turn off a straight
    off = ~out["on_line"][:, 0]
    first_off = int(off.nonzero()[0])
    end = int(out["done"][:, 0].nonzero()[0])
    assert end == first_off + 4 and out["left_line"][end, 0] and off[first_off:end + 1].all()
    assert out["episode", "time_off_line"][end, 0].item() == pytest.approx(5 * 0.05)


def lap_with_pd_follower(track: str, n: int, max_steps: int = 700):
    """Final state of ``n`` PD-followed episodes (task level, no TorchRL overhead) and whether any ended."""
    from torchnav.tasks import LineTask

    cfg = LineConfig.from_dict({"track": track, "max_steps": max_steps})
    task = LineTask(cfg, n)
    gen = torch.Generator().manual_seed(3)
    state = task.initial_state(gen)
    pol = LineFollower(cfg)
    td = TensorDict({"observation": task.observe(state.history, state.sim)}, batch_size=[n])
    ended = torch.zeros(n, dtype=torch.bool)
    for _ in range(max_steps):
        state, out = task.step(state, pol(td)["action"], gen)
        ended |= out["terminated"]
        td = TensorDict({"observation": out["observation"]}, batch_size=[n])
        if (state.laps >= 1).all():
            break
    return task, state, ended


def test_pd_follower_completes_laps_of_the_oval():
    task, state, ended = lap_with_pd_follower("oval", 8)
    assert not ended.any() and (state.laps >= 1).all()
    assert ((state.lap_time > 0) & (state.lap_time < 700 * 0.05)).all()
    assert (state.progress >= task.tt.length).all()


@pytest.mark.slow
@pytest.mark.parametrize("track", ["loop", "course"])
def test_pd_follower_completes_laps(track):
    task, state, ended = lap_with_pd_follower(track, 64)
    assert not ended.any() and (state.laps >= 1).all()


def test_env_episode_statistics_of_a_lap():
    env = make_line_env("oval", num_envs=2, seed=3, max_steps=400)
    pol = LineFollower().bind(env)
    td = env.reset()
    for _ in range(400):
        td = env.step(pol(td))
        if (td["next", "episode", "laps"] >= 1).all() or td["next", "done"].any():
            break
        td = step_mdp(td)
    nxt = td["next"]
    assert not nxt["terminated"].any() and (nxt["episode", "laps"] == 1).all()
    assert (nxt["lap_completed"] | (nxt["episode", "lap_time"] < nxt["episode", "length"] * 0.05 - 1e-6)).all()
    torch.testing.assert_close(nxt["episode", "lap_fraction"], nxt["episode", "progress_m"] / env.track.length)
    assert (nxt["episode", "lap_fraction"] >= 1).all() and (nxt["episode", "lap_time"] > 0).all()


def test_forward_distance_sensor_reads_a_wall(tmp_path):
    p = tmp_path / "walled.yaml"
    p.write_text("width: 0.025\nwalls: [[0.5, -1, 0.5, 1]]\nlines:\n  - points: [[-1, 0], [0, -0.5], [0, 0.5]]\n    closed: true\n")
    env = make_line_env(str(p), num_envs=1, distance_sensor={"enabled": True, "max_range": 2.0})
    env.reset()
    from torchnav.sim import init_state

    s = env.state.clone()
    s.sim = init_state(torch.tensor([[0.1, 0.0, 0.0]]), env.task.world, env.task.params)
    assert s.sim.ranges[0, 0].item() == pytest.approx(0.5 - 0.1 - 0.07, abs=1e-5)  # mounted 7 cm ahead
    obs = env.task.observe(s.history, s.sim)
    assert obs.shape == (1, 31) and obs[0, -1].item() == pytest.approx(0.33 / 2.0, abs=1e-5)


def test_lap_evaluation_of_the_pd_follower():
    from torchnav.evaluation import format_lap_summary, run_line_episodes, summarize_laps

    cfg = LineConfig.from_dict({"track": "oval", "max_steps": 400})
    res = run_line_episodes(LineFollower(), cfg, n_episodes=6, seed=1, max_batch=4)
    assert res["lap_complete"].all() and res["lap_complete"].shape == (6,)
    assert (torch.stack([res[k] for k in ("left_line", "stalled", "collision", "timeout")]).sum(0) == 0).all()
    s = summarize_laps(res, cfg.robot.dt)
    assert s["lap_complete"]["rate"] == 1.0 and 0.5 < s["lap_complete"]["ci95"][0] < 1.0
    assert 5.0 < s["lap_time"]["mean"] < 20.0
    assert "lap_complete" in format_lap_summary(s, "oval")
    # a policy that drives off the line never completes a lap
    bad = run_line_episodes(constant([1.0, 0.0]), cfg, n_episodes=3, seed=1)
    assert bad["left_line"].all() and torch.isnan(bad["lap_time"]).all()


def test_on_line_at_reset_is_the_noise_free_flag_of_every_step():
    """The reset output's on_line comes from the same noise-free coverage as every step's, not from noisy readings."""
    noisy = make_line_env("oval", num_envs=64, seed=3, sensors={"noise_std": 0.5}, reset={"lateral_noise": 0.2})
    td = noisy.reset()
    expected = noisy.task.on_line(noisy.state.sim.pose)
    noisy_flag = (noisy.state.readings > noisy.cfg.sensors.threshold).any(-1)
    assert not torch.equal(noisy_flag, expected), "the case must tell the two flags apart"
    assert torch.equal(td["on_line"][:, 0], expected)
