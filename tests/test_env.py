"""The TorchRL environment: specs, resets, flags, statistics, seeding, checkpoints and
composition with TorchRL collectors and transforms."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.data import Bounded, OneHot
from torchrl.envs import CatFrames, Compose, ObservationNorm, RewardSum, StepCounter, TransformedEnv
from torchrl.envs.utils import RandomPolicy, check_env_specs

from torchnav.config import ConfigError
from torchnav.envs import NavEnv, make_nav_env
from torchnav.maps import MapError, available_maps
from torchnav.sim import sectorize
from torchnav.tasks import PRESETS, NavConfig

# The keys of every reset and step output (docs/tasks.md lists them).
OUTPUT_KEYS = {
    "observation", "pose", "goal", "ranges", "success", "collision", "curriculum_radius",
    "reward_terms", "episode", "done", "terminated", "truncated",
}
EPISODE_KEYS = {"return", "length", "path_length", "straight_line", "speed_change", "turn_change"}



class SeededPolicy:
    """Uniform random actions from its own generator (never the global RNG)."""

    def __init__(self, seed: int, lo: float = -1.0, hi: float = 1.0):
        self.gen = torch.Generator().manual_seed(seed)
        self.lo, self.hi = lo, hi

    def __call__(self, td):
        b = td.batch_size[0]
        td["action"] = self.lo + (self.hi - self.lo) * torch.rand(b, 2, generator=self.gen)
        return td


def constant(action):
    def policy(td):
        td["action"] = torch.as_tensor(action, dtype=torch.float32).expand(td.batch_size[0], -1).clone()
        return td

    return policy


def masked(mask: torch.Tensor) -> TensorDict:
    return TensorDict({"_reset": mask[:, None]}, batch_size=[mask.shape[0]])


# --------------------------------------------------------------------------- specs


@pytest.mark.parametrize("num_envs", [1, 3, 16])
def test_check_env_specs_at_several_batch_sizes(num_envs):
    env = make_nav_env("arena", num_envs=num_envs)
    assert env.batch_size == (num_envs,) and env.num_envs == num_envs
    check_env_specs(env)
    b = num_envs
    assert env.observation_spec["observation"].shape == (b, 24)
    assert isinstance(env.action_spec, Bounded) and env.action_spec.shape == (b, 2)
    assert (env.action_spec.space.low == -1).all() and (env.action_spec.space.high == 1).all()
    assert env.reward_spec.shape == (b, 1)
    for k in ("done", "terminated", "truncated"):
        assert env.full_done_spec[k].shape == (b, 1) and env.full_done_spec[k].dtype == torch.bool
    assert set(env.observation_spec["episode"].keys()) == EPISODE_KEYS | {f"term_{k}" for k in PRESETS["classic"]}
    assert set(env.observation_spec["reward_terms"].keys()) == set(PRESETS["classic"])


@pytest.mark.parametrize(
    "overrides",
    [
        {"action": {"mode": "discrete"}},
        {"observation": {"history": 3, "normalize": False}},
        {"reward": {"preset": "shaped"}},
        {"reward": {"preset": "progress", "weights": {"step": -0.1}}},
        {"lidar": {"noise_std": 0.5, "n_rays": 40}, "robot": {"odom_v_noise": 0.2}, "observation": {"goal_from_odom": True}},
        {"action": {"forward_only": False}, "robot": {"lin_acc_max": 2.0}},
    ],
    ids=["discrete", "history", "shaped", "progress+step", "noise", "reverse+acc"],
)
def test_check_env_specs_for_options(overrides):
    env = make_nav_env("warehouse", num_envs=2, **overrides)
    check_env_specs(env)
    td = env.rollout(12, break_when_any_done=False)
    for t in range(12):
        assert env.observation_spec.is_in(td["next"][:, t].select(*env.observation_spec.keys()))


@pytest.mark.parametrize("name", available_maps())
def test_every_shipped_map_makes_a_working_env(name):
    env = make_nav_env(name, num_envs=2)
    check_env_specs(env)
    td = env.rollout(5, break_when_any_done=False)
    assert torch.isfinite(td["next", "observation"]).all()


def test_unknown_map_lists_the_available_maps():
    with pytest.raises(MapError) as e:
        make_nav_env("areena", num_envs=2)
    msg = str(e.value)
    assert "areena" in msg and all(n in msg for n in available_maps())


def test_malformed_map_file_names_the_key(tmp_path):
    p = tmp_path / "lab.yaml"
    p.write_text("size: [10, 10]\nwalls: boundary\nrandom_boxes: {count: 2, size_x: [0.4, 0.6], sise_y: [0.3, 0.5]}\n")
    with pytest.raises(MapError, match=r"random_boxes\.sise_y.*did you mean 'size_y'"):
        make_nav_env(str(p), num_envs=2)


def test_reset_and_step_output_keys():
    env = make_nav_env("arena", num_envs=2)
    td = env.reset()
    assert set(td.keys()) == OUTPUT_KEYS
    td["action"] = torch.zeros(2, 2)
    out = env.step(td)["next"]
    assert set(out.keys()) == OUTPUT_KEYS | {"reward"}
    assert td["curriculum_radius"].shape == (2, 1)


# --------------------------------------------------------------------------- observation, actions


def test_observation_matches_pose_goal_and_ranges():
    env = make_nav_env("street", num_envs=3)
    td = env.rollout(6, SeededPolicy(0), break_when_any_done=False)["next"]
    pose, goal = td["pose"], td["goal"]
    dist = (goal - pose[..., :2]).norm(dim=-1)
    obs = td["observation"]
    torch.testing.assert_close(obs[..., :20], sectorize(td["ranges"].reshape(-1, 20), 20).reshape(3, 6, 20) / 10.0)
    torch.testing.assert_close(obs[..., 20], dist / 10.0)
    assert (obs[..., 21].abs() <= 1.0).all()  # bearing / pi
    assert (obs[..., 22] >= 0).all() and (obs[..., 22] <= 1).all()  # forward-only v / v_max


def test_discrete_action_mode_uses_a_one_hot_spec():
    env = make_nav_env("empty", num_envs=3, action={"mode": "discrete"}, observation={"normalize": False})
    assert isinstance(env.action_spec, OneHot) and env.action_spec.shape == (3, 7)
    td = env.reset()
    idx = torch.tensor([0, 3, 6])
    td["action"] = torch.nn.functional.one_hot(idx, 7).bool()
    out = env.step(td)["next"]
    expected = torch.tensor(NavConfig().action.discrete_set)[idx]  # v_max = omega_max = 1
    torch.testing.assert_close(out["observation"][:, -2:], expected)


def test_history_observation_size():
    env = make_nav_env("arena", num_envs=2, observation={"history": 4})
    assert env.observation_spec["observation"].shape == (2, 96)
    td = env.reset()
    assert torch.equal(td["observation"][:, :24], td["observation"][:, -24:])  # k copies at reset
    td["action"] = torch.ones(2, 2)
    out = env.step(td)["next"]
    torch.testing.assert_close(out["observation"][:, :72], td["observation"][:, 24:])  # shifted left
    assert not torch.equal(out["observation"][:, -24:], td["observation"][:, -24:])  # newest last


# --------------------------------------------------------------------------- termination and statistics


def test_goal_sets_terminated_and_success():
    env = make_nav_env("arena", num_envs=3, goal_tolerance=50.0)  # every goal is within 50 m
    td = env.reset()
    td["action"] = torch.zeros(3, 2)
    out = env.step(td)["next"]
    assert out["success"].all() and out["terminated"].all() and out["done"].all()
    assert not out["truncated"].any() and not out["collision"].any()
    torch.testing.assert_close(out["reward_terms", "goal"], torch.full((3, 1), 100.0))


def test_collision_sets_terminated_without_success():
    # Full speed straight ahead in a walled room always ends in a wall or a box within ~15 m.
    env = make_nav_env("arena", num_envs=4, goal_tolerance=1e-3, max_steps=400)
    td = env.rollout(160, constant([1.0, 0.0]), break_when_any_done=False)["next"]
    for i in range(4):
        first = td["done"][i, :, 0].nonzero()[0, 0]
        step = td[i, first]
        assert step["collision"].item() and step["terminated"].item()
        assert not step["success"].item() and not step["truncated"].item()
        assert step["reward_terms", "collision"].item() == -100.0
        assert not td["collision"][i, :first].any()


def test_step_limit_sets_truncated():
    env = make_nav_env("arena", num_envs=2, max_steps=5)
    td = env.rollout(12, constant([-1.0, 0.0]), break_when_any_done=False)["next"]  # v = 0, omega = 0
    done = td["done"][..., 0]
    assert done[:, 4].all() and done[:, 9].all() and done.sum() == 4
    assert td["truncated"][..., 0].equal(done) and not td["terminated"].any()
    assert (td["episode", "length"][:, 4] == 5).all()


def test_episode_statistics_at_done():
    env = make_nav_env("warehouse", num_envs=4, max_steps=12)
    r = env.rollout(40, SeededPolicy(1, lo=-0.2, hi=1.0), break_when_any_done=False)
    nxt = r["next"]
    torch.testing.assert_close(nxt["reward"][..., 0], sum(nxt["reward_terms", k][..., 0] for k in PRESETS["classic"]))
    for i in range(4):
        ends = nxt["done"][i, :, 0].nonzero()[:, 0].tolist()
        assert ends
        begin = 0
        for e in ends:
            ep = nxt[i, begin : e + 1]
            stats = nxt["episode"][i, e]
            assert stats["length"].item() == e + 1 - begin
            torch.testing.assert_close(stats["return"], ep["reward"].sum(0), atol=1e-4, rtol=1e-5)
            for k in PRESETS["classic"]:
                torch.testing.assert_close(stats[f"term_{k}"], ep["reward_terms", k].sum(0), atol=1e-4, rtol=1e-5)
            steps = (ep["pose"][1:, :2] - ep["pose"][:-1, :2]).norm(dim=-1).sum()
            first = (ep["pose"][0, :2] - r["pose"][i, begin, :2]).norm()
            torch.testing.assert_close(stats["path_length"][0], steps + first, atol=1e-4, rtol=1e-4)
            torch.testing.assert_close(stats["straight_line"][0], (r["goal"][i, begin] - r["pose"][i, begin, :2]).norm())
            # The root of the next step is a fresh episode.
            if e + 1 < r.shape[1]:
                assert r["episode", "length"][i, e + 1].item() == 0
            begin = e + 1


def test_speed_and_turn_change_sum_the_driven_velocity_changes_from_rest():
    env = make_nav_env("empty", num_envs=3, seed=4, curriculum={"mode": "off"})  # goals anywhere, not a step away
    td = env.reset()
    vel = [env.state.sim.vel.clone()]
    assert vel[0].abs().max() == 0  # every episode starts from rest
    g = torch.Generator().manual_seed(0)
    for _ in range(15):
        td["action"] = torch.rand(3, 2, generator=g) * 2 - 1
        td = env.step(td)
        if td["next", "done"].any():  # the next state is a new episode's
            break
        vel.append(env.state.sim.vel.clone())
        td = td["next"]
    assert len(vel) > 5
    change = (torch.stack(vel)[1:] - torch.stack(vel)[:-1]).abs().sum(0)
    assert change.min() > 0
    torch.testing.assert_close(td["episode", "speed_change"][:, 0], change[:, 0].float())
    torch.testing.assert_close(td["episode", "turn_change"][:, 0], change[:, 1].float())


# --------------------------------------------------------------------------- resets and curriculum


def test_partial_reset_leaves_other_envs_bit_identical():
    env = make_nav_env("street", num_envs=5)
    td = env.reset()
    for _ in range(4):
        td["action"] = torch.full((5, 2), 0.5)
        td = env.step(td)["next"]
    old_state = env.state.to_tensordict().clone()
    mask = torch.tensor([True, False, False, True, False])
    # TorchRL keeps the input's values for envs that are not reset, so pass the last outputs.
    td["_reset"] = mask[:, None]
    out = env.reset(td.clone())
    new_state = env.state.to_tensordict()
    for key, v in old_state.items(True, True):
        assert torch.equal(v[~mask], new_state[key][~mask]), key
    for key in ("observation", "pose", "goal", "ranges", ("episode", "return"), ("episode", "length")):
        assert torch.equal(out[key][~mask], td[key][~mask]), key
    assert (out["episode", "length"][mask] == 0).all()
    assert not torch.equal(out["goal"][mask], td["goal"][mask])


def test_curriculum_radius_follows_placements_in_a_rollout():
    env = make_nav_env("arena", num_envs=4, max_steps=6, curriculum={"growth": 0.01})
    r = env.rollout(30, SeededPolicy(0), break_when_any_done=False)
    # One placement per env at the first reset, and one per finished episode (auto reset;
    # rollout does not reset after its last step).
    dones = int(r["next", "done"][:, :-1].sum())
    assert dones >= 16
    assert int(env.curriculum.placements) == 4 + dones
    assert env.curriculum.radius.item() == pytest.approx(1.0 + 0.01 * (4 + dones))
    env.reset(masked(torch.tensor([True, True, False, False])))
    assert int(env.curriculum.placements) == 6 + dones
    # The radius is reported in every output.
    assert r["next", "curriculum_radius"][:, -1].unique().numel() == 1


def test_success_gated_curriculum_in_the_env():
    gated = {"mode": "success", "success_threshold": 0.8, "success_step": 0.25, "success_smoothing": 0.5}
    win = make_nav_env("arena", num_envs=4, goal_tolerance=50.0, curriculum=gated)
    win.rollout(3, constant([0.0, 0.0]), break_when_any_done=False)
    assert win.curriculum.success_rate.item() > 0.8
    assert win.curriculum.radius.item() == pytest.approx(1.0 + 3 * 0.25)  # grew after each step
    lose = make_nav_env("arena", num_envs=4, max_steps=2, curriculum=gated)  # time-outs only
    lose.rollout(6, constant([-1.0, 0.0]), break_when_any_done=False)
    assert lose.curriculum.success_rate.item() == 0.0 and lose.curriculum.radius.item() == 1.0
    assert int(lose.curriculum.placements) == 4 + 8  # 12 time-outs, the last 4 not yet reset


def test_state_dict_round_trip_through_torch_save(tmp_path):
    env = make_nav_env("warehouse", num_envs=3, max_steps=5)
    env.rollout(17, SeededPolicy(0), break_when_any_done=False)
    path = tmp_path / "ckpt.pt"
    torch.save({"env": env.state_dict()}, path)
    sd = torch.load(path, weights_only=True)["env"]
    restored = make_nav_env("warehouse", num_envs=3, max_steps=5, seed=123)
    restored.load_state_dict(sd)
    for k in ("radius", "placements", "success_rate"):
        assert torch.equal(getattr(restored.curriculum, k), getattr(env.curriculum, k)), k
    # Same curriculum and generator: the next episodes are the same.
    a, b = env.reset(), restored.reset()
    assert torch.equal(a["goal"], b["goal"]) and torch.equal(a["pose"], b["pose"])
    assert torch.equal(a["curriculum_radius"], b["curriculum_radius"])


# --------------------------------------------------------------------------- seeding


def test_same_seed_same_episodes_and_global_rng_untouched():
    def run(seed):
        env = make_nav_env("street", num_envs=3, seed=seed, max_steps=8, lidar={"noise_std": 0.05}, robot={"odom_v_noise": 0.1})
        return env.rollout(20, SeededPolicy(9), break_when_any_done=False)

    torch.manual_seed(0)
    rng = torch.get_rng_state()
    a, b, c = run(7), run(7), run(8)
    assert torch.equal(torch.get_rng_state(), rng)  # the env draws only from its own generator
    for key in ("observation", "pose", "goal", "ranges"):
        assert torch.equal(a[key], b[key]) and torch.equal(a["next", key], b["next", key]), key
    assert torch.equal(a["next", "reward"], b["next", "reward"])
    assert not torch.equal(a["goal"], c["goal"])


def test_set_seed_reseeds_the_generator():
    env = make_nav_env("arena", num_envs=2, seed=0)
    env.set_seed(5)
    fresh = make_nav_env("arena", num_envs=2, seed=5)
    assert torch.equal(env.reset()["goal"], fresh.reset()["goal"])


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_action_raises_by_default(bad):
    env = make_nav_env("arena", num_envs=3)
    td = env.reset()
    td["action"] = torch.tensor([[0.0, 0.0], [bad, 0.0], [0.0, 0.0]])
    with pytest.raises(ValueError, match=r"NaN or inf in envs \[1\].*check_actions=False"):
        env.step(td)


@pytest.mark.parametrize("env_kind", ["nav", "line"])
def test_action_of_the_wrong_shape_is_refused_by_both_envs(env_kind):
    from torchnav.envs import LineEnv
    from torchnav.tasks import LineConfig

    env = make_nav_env("arena", num_envs=3) if env_kind == "nav" else LineEnv(LineConfig(), num_envs=3)
    td = env.reset()
    td["action"] = torch.zeros(3, 3)  # one value too many per env: once silently ignored by NavEnv
    with pytest.raises(ValueError, match=r"action has shape \(3, 3\), expected \(3, 2\)"):
        env.step(td)
    for shape in [(3, 1), (2, 2), (3,)]:  # shapes a tensordict of batch (3,) cannot hold, as a caller's own may
        with pytest.raises(ValueError, match=r"action has shape .*expected \(3, 2\)"):
            env._step(TensorDict({"action": torch.zeros(shape)}, batch_size=[]))


def test_non_finite_action_without_the_check_stops_the_robot():
    env = make_nav_env("arena", num_envs=2, check_actions=False)
    td = env.reset()
    td["action"] = torch.full((2, 2), math.nan)
    out = env.step(td)["next"]
    for key in ("observation", "pose", "ranges", "reward"):
        assert torch.isfinite(out[key]).all(), key
    torch.testing.assert_close(out["pose"], td["pose"])
    assert torch.isfinite(env.state.sim.pose).all() and (env.state.sim.vel == 0).all()


def test_unknown_override_key_names_the_key():
    with pytest.raises(ConfigError, match="grwth.*did you mean 'growth'"):
        make_nav_env("arena", num_envs=2, curriculum={"grwth": 0.01})
    with pytest.raises(ConfigError, match="curriculum.grwth"):
        make_nav_env("arena", num_envs=2, **{"curriculum.grwth": 0.01})
    with pytest.raises(ConfigError, match="env.max_steps"):
        make_nav_env("arena", num_envs=2, max_steps="100")


# --------------------------------------------------------------------------- TorchRL composition


def test_collector_collects_a_couple_of_batches():
    env = make_nav_env("arena", num_envs=4, max_steps=7)
    collector = Collector(env, RandomPolicy(env.action_spec), frames_per_batch=40, total_frames=80)
    batches = []
    for batch in collector:
        batches.append(batch)
    collector.shutdown()
    assert len(batches) == 2
    for batch in batches:
        assert batch.shape == (4, 10) and batch.numel() == 40
        assert torch.isfinite(batch["next", "observation"]).all()
    # Episodes continue across batches and are reset when done.
    assert batches[1]["next", "done"].any() and (batches[1]["next", "episode", "length"] <= 7).all()


def test_a_loaded_env_continues_its_episodes_and_pool_exactly():
    kw = dict(num_envs=4, max_steps=20, worlds={"families": {"rooms": 1.0, "forest": 1.0}, "difficulty": 0.3},
              reset={"pool": 8, "reuse": 2})
    env = make_nav_env("arena", seed=3, **kw)
    env.rollout(25, SeededPolicy(1), break_when_any_done=False)  # episodes mid-way, the pool part-used
    sd = env.state_dict()
    assert int(sd["_extra_state"]["pool"]["pos"]) > 0
    other = make_nav_env("arena", seed=99, **kw)  # another seed: everything must come from the state dict
    other.load_state_dict(sd)
    torch.testing.assert_close(other.state.sim.pose, env.state.sim.pose, rtol=0, atol=0)
    pa, pb = SeededPolicy(2), SeededPolicy(2)
    ta = tb = TensorDict({}, batch_size=[4])
    for _ in range(30):  # through episode ends: resets draw from the restored pool and generator
        out_a, ta = env.step_and_maybe_reset(pa(ta))
        out_b, tb = other.step_and_maybe_reset(pb(tb))
        for key in ("observation", "reward", "done", "pose"):
            assert torch.equal(out_a["next", key], out_b["next", key]), key
    assert int(env.curriculum.placements) > int(sd["_extra_state"]["curriculum"]["placements"])  # episodes were reset on the way


def test_transforms_compose():
    env = TransformedEnv(make_nav_env("arena", num_envs=3, max_steps=6), Compose(StepCounter(), RewardSum()))
    check_env_specs(env)
    r = env.rollout(10, SeededPolicy(0), break_when_any_done=False)
    torch.testing.assert_close(r["next", "step_count"][..., 0].float(), r["next", "episode", "length"][..., 0])
    # TorchRL's TransformedEnv.state_dict() holds its transforms only; the curriculum and the
    # generator round-trip through the base env's nn.Module state_dict (its "_extra_state").
    sd = env.base_env.state_dict()
    assert int(sd["_extra_state"]["curriculum"]["placements"]) == int(env.base_env.curriculum.placements) > 3
    fresh = TransformedEnv(make_nav_env("arena", num_envs=3, max_steps=6, seed=9), Compose(StepCounter(), RewardSum()))
    fresh.base_env.load_state_dict(sd)
    assert torch.equal(fresh.base_env.curriculum.radius, env.base_env.curriculum.radius)
    assert torch.equal(fresh.base_env.generator.get_state(), env.base_env.generator.get_state())
    torch.testing.assert_close(r["next", "episode_reward"], r["next", "episode", "return"], atol=1e-4, rtol=1e-5)
    frames = TransformedEnv(
        make_nav_env("arena", num_envs=2),
        Compose(CatFrames(N=3, dim=-1, in_keys=["observation"]), ObservationNorm(in_keys=["observation"], loc=0.5, scale=2.0)),
    )
    check_env_specs(frames)
    r = frames.rollout(4, SeededPolicy(0), break_when_any_done=False)
    assert r["observation"].shape == (2, 4, 72)


def test_nav_env_from_config():
    cfg = NavConfig.from_dict({"map": "maze", "max_steps": 50, "reward": {"preset": "progress"}})
    env = NavEnv(cfg, num_envs=2, device="cpu", seed=3)
    check_env_specs(env)
    assert env.cfg is cfg and env.task.spec.name == "maze"
    assert set(env.observation_spec["reward_terms"].keys()) == set(PRESETS["progress"])


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_env_on_cuda():
    env = make_nav_env("warehouse", num_envs=8, device="cuda")
    check_env_specs(env)
    r = env.rollout(20, break_when_any_done=False)
    assert r.device.type == "cuda" and torch.isfinite(r["next", "observation"]).all()


@pytest.mark.slow
def test_compiled_step_matches_eager():
    """NavEnv(compile_step=True) runs the simulator step through torch.compile: same episodes."""
    from torchnav.envs import make_nav_env

    runs = []
    for compiled in (False, True):
        env = make_nav_env("arena", num_envs=8, seed=3)
        if compiled:
            env.task.compile_step()
        td = env.reset()
        gen = torch.Generator().manual_seed(0)
        obs = []
        for _ in range(30):
            td["action"] = torch.rand(8, 2, generator=gen) * 2 - 1
            _, td = env.step_and_maybe_reset(td)
            obs.append(td["observation"].clone())
        runs.append(torch.stack(obs))
    torch.testing.assert_close(runs[1], runs[0], atol=1e-4, rtol=1e-4)


def test_state_dict_taken_and_loaded_back_undoes_a_run():
    """``sd = env.state_dict()``, any run of the env, ``env.load_state_dict(sd)``: the env goes on as if
    that run never happened (generator, episodes in flight, curriculum and episode pool), e.g. for
    observation statistics gathered on the training env itself."""
    kw = dict(num_envs=4, max_steps=6, reset={"pool": 6}, curriculum={"mode": "growth", "growth": 0.05})

    def steps(env, n):  # from the episodes in flight, or from a reset before the first one
        pol, out = SeededPolicy(5), []
        td = env.reset() if env.state is None else TensorDict({}, batch_size=[4])
        for _ in range(n):
            o, td = env.step_and_maybe_reset(pol(td))
            out.append(torch.cat([o["next", "observation"], o["next", "pose"], o["next", "curriculum_radius"]], -1))
        return torch.stack(out)

    for started in (False, True):  # before the first reset, and with episodes and a pool in flight
        env, ref = make_nav_env("arena", seed=4, **kw), make_nav_env("arena", seed=4, **kw)
        if started:
            steps(env, 9), steps(ref, 9)
        sd = env.state_dict()
        env.rollout(20, SeededPolicy(1), break_when_any_done=False)  # moves the curriculum, the generator and the pool
        assert int(env.curriculum.placements) > int(ref.curriculum.placements)
        env.load_state_dict(sd)
        assert (env.state is None) == (not started) and int(env.curriculum.placements) == int(ref.curriculum.placements)
        assert torch.equal(steps(env, 15), steps(ref, 15))


def test_a_saved_env_state_missing_a_part_is_refused():
    env = make_nav_env("arena", num_envs=2, max_steps=5)
    env.rollout(3, SeededPolicy(0), break_when_any_done=False)
    sd = env.state_dict()
    del sd["_extra_state"]["pool"]
    with pytest.raises(ValueError, match=r"lacks \['pool'\]"):
        make_nav_env("arena", num_envs=2, max_steps=5).load_state_dict(sd)