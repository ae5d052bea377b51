"""Bad inputs get a named error before any work: recipe overrides, maps, tracks, actions, checkpoints.

Each case asserts the error type and that its message names the culprit; recipe cases
also assert that no run directory was created.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "recipes"))

from torchnav.config import ConfigError  # noqa: E402
from torchnav.maps import MapError  # noqa: E402
from torchnav.tracks import TrackError  # noqa: E402

# (recipe, override, what the message must contain)
BAD_OVERRIDES = [
    ("td3_lidar", "env.num_envs=0", "env.num_envs=0: must be an integer >= 1"),
    ("td3_lidar", "env.num_envs=2.5", "env.num_envs=2.5"),
    ("td3_lidar", "train.lr_actor=nan", "train.lr_actor"),
    ("td3_lidar", "train.lr_critic=-1e-3", "train.lr_critic=-0.001: must be a finite number > 0"),
    ("td3_lidar", "train.frames_per_batch=0", "train.frames_per_batch=0"),
    ("td3_lidar", "train.frames_per_batch=1000", "must be a multiple of env.num_envs=128"),
    ("td3_lidar", "train.policy_delay=0", "train.policy_delay=0"),
    ("td3_lidar", "train.total_frames=-1000", "train.total_frames=-1000"),
    ("td3_lidar", "train.batch_size=2000000", "train.batch_size=2000000 must be at most train.buffer_size"),
    ("td3_lidar", "train.gamma=1.5", "train.gamma=1.5: must be a number in (0, 1]"),
    ("td3_lidar", "train.hidden=[]", "train.hidden=[]"),
    ("td3_lidar", "train.hidden=[64,-1]", "train.hidden"),
    ("td3_lidar", "eval.episodes=0", "eval.episodes=0"),
    ("td3_lidar", "eval.record_episodes=5000", "eval.record_episodes=5000 must be at most eval.final_episodes"),
    ("td3_lidar", "eval.target_success=2", "eval.target_success=2"),
    ("td3_lidar", "seed=abc", "seed='abc'"),
    ("td3_lidar", "seed=-1", "seed=-1"),
    ("td3_lidar", "device=cuda:7", "device='cuda:7'"),
    ("td3_lidar", "device=tpu", "device='tpu': must be cpu, cuda or cuda:N"),
    ("td3_lidar", "env.compile_step=maybe", "env.compile_step"),
    ("td3_lidar", "logger.progress=2", "logger.progress=2: must be true or false"),
    ("td3_lidar", "checkpoint.interval_frames=0", "checkpoint.interval_frames=0"),
    ("td3_lidar", "task.curriculum.growth=fast", "task.curriculum.growth='fast': must be a finite number >= 0"),
    ("td3_lidar", "task.map=nonexistent", "unknown map 'nonexistent'"),
    ("td3_lidar", "task.lidar.n_rays=0", "lidar.n_rays"),
    ("td3_lidar", "threads=0", "threads=0: must be 'auto' or an int >= 1"),
    ("ppo_lidar", "train.minibatch_size=100000", "train.minibatch_size=100000 must be at most train.frames_per_batch"),
    ("ppo_lidar", "train.epochs=0", "train.epochs=0"),
    ("ppo_lidar", "train.lmbda=-0.1", "train.lmbda=-0.1"),
    ("ppo_lidar", "train.activation=gelu", "train.activation='gelu': must be relu or tanh"),
    ("sac_lidar", "train.lr_alpha=0", "train.lr_alpha=0"),
    ("dqn_line", "train.eps_end=1.5", "train.eps_end=1.5"),
    ("ppo_line", "task.track=nope", "unknown track 'nope'"),
    ("ppo_line", "eval.laps=0", "eval.laps=0"),
]


@pytest.mark.parametrize("recipe,override,message", BAD_OVERRIDES, ids=[f"{r}:{o}" for r, o, _ in BAD_OVERRIDES])
def test_bad_override_is_named_before_the_run_directory(tmp_path, recipe, override, message):
    run = tmp_path / "run"
    with pytest.raises((ConfigError, MapError, TrackError)) as e:
        importlib.import_module(recipe).main([override, f"logger.run_dir={run}", "logger.progress=false"] if not override.startswith("logger.progress")
                                             else [override, f"logger.run_dir={run}"])
    assert message in str(e.value)
    assert not run.exists(), f"{override}: the run directory was created before the error"


def test_every_error_is_listed_at_once(tmp_path):
    with pytest.raises(ConfigError) as e:
        importlib.import_module("td3_lidar").main(["env.num_envs=0", "train.gamma=2", f"logger.run_dir={tmp_path / 'r'}"])
    assert "env.num_envs=0" in str(e.value) and "train.gamma=2" in str(e.value)


@pytest.mark.parametrize("kind", ["nav", "line"])
def test_envs_refuse_wrong_action_shape_dtype_and_nan(kind):
    from tensordict import TensorDict

    from torchnav.envs import make_nav_env, make_line_env

    env = make_nav_env("arena", num_envs=4) if kind == "nav" else make_line_env("oval", num_envs=4)
    td = env.reset()
    td["action"] = torch.zeros(4, 3)
    with pytest.raises(ValueError, match=r"action has shape \(4, 3\), expected \(4, 2\)"):
        env.step(td)
    td["action"] = torch.zeros(4, 2, dtype=torch.int64)
    with pytest.raises(ValueError, match="must be a floating-point tensor, got torch.int64"):
        env.step(td)
    bad = TensorDict({"action": torch.full((4, 2), float("nan"))}, batch_size=[4])
    with pytest.raises(ValueError, match="NaN or inf in envs"):
        env.step(bad)


BAD_ACTIONS = [  # for an 8-env continuous batch: (action, what the message must contain)
    (torch.zeros(8), r"action has shape \(8,\), expected \(8, 2\)"),
    (torch.zeros(8, 3), r"action has shape \(8, 3\)"),
    (torch.zeros(8, 2, 1), r"action has shape \(8, 2, 1\)"),
    (torch.zeros(8, 2, dtype=torch.int32), "floating-point tensor, got torch.int32"),
    (torch.zeros(8, 2, dtype=torch.bool), "floating-point tensor, got torch.bool"),
    (torch.zeros(8, 2, dtype=torch.complex64), "floating-point tensor, got torch.complex64"),
    (torch.zeros(8, 2, device="meta"), "action is on device meta, expected the env's device cpu"),
    (torch.full((8, 2), float("inf")), "NaN or inf in envs"),
]


@pytest.mark.parametrize("action,message", BAD_ACTIONS, ids=[m for _, m in BAD_ACTIONS])
def test_env_step_names_every_bad_action(action, message):
    from tensordict import TensorDict

    from torchnav.envs import make_nav_env

    env = make_nav_env("arena", num_envs=8)
    env.reset()
    with pytest.raises(ValueError, match=message):
        env.step(TensorDict({"action": action}, batch_size=[8]))


@pytest.mark.parametrize("batch", [[4], [1], [], [8, 1]])
def test_env_step_names_a_batch_of_another_size(batch):
    from tensordict import TensorDict

    from torchnav.envs import make_nav_env

    env = make_nav_env("arena", num_envs=8)
    env.reset()
    td = TensorDict({"action": torch.zeros(*batch, 2)}, batch_size=batch)
    with pytest.raises(ValueError) as e:
        env.step(td)
    assert f"batch size {tuple(batch)}, expected (8,)" in str(e.value) and "an action is (8, 2)" in str(e.value)
    with pytest.raises(ValueError, match=r"expected \(8,\)"):
        env.reset(td)
    env.step(TensorDict({"action": torch.zeros(8, 2)}, batch_size=[8]))  # still steps after the refusals


GYM_BAD_ACTIONS = [  # (vector actions for 8 envs, single-env action, what the message must contain)
    (np.zeros((4, 2)), np.zeros((1, 2)), "must have shape"),
    (np.zeros((1, 2)), np.zeros(3), "must have shape"),
    (np.zeros(8), np.zeros((2, 1)), "must have shape"),
    (np.zeros((8, 2), dtype=bool), np.zeros(2, dtype=bool), "real numbers"),
    (np.zeros((8, 2), dtype=complex), np.zeros(2, dtype=complex), "real numbers"),
    (torch.zeros(8, 2, device="meta"), torch.zeros(2, device="meta"), "meta device"),
    ("ab", "ab", "real numbers"),
    (None, None, "real numbers"),
    ([[0, 0], [0]], [0, [0]], "must be an array"),
    (np.full((8, 2), np.nan), np.full(2, np.nan), "NaN or inf"),
]


@pytest.mark.parametrize("vector,single,message", GYM_BAD_ACTIONS, ids=[f"{i}-{m}" for i, (_, _, m) in enumerate(GYM_BAD_ACTIONS)])
def test_gym_and_sb3_adapters_name_every_bad_action(vector, single, message):
    from torchnav.gym import navigation_env, navigation_vector_env, sb3_vec_env

    vec = navigation_vector_env(num_envs=8)
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        vec.step(vector)
    one = navigation_env()
    one.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        one.step(single)
    pytest.importorskip("stable_baselines3")
    sb3 = sb3_vec_env(vec)
    sb3.reset()
    with pytest.raises(ValueError, match=message):
        sb3.step(vector)


DISCRETE_BAD = [  # for an 8-env batch over the 7 default discrete actions: (action, what the message must contain)
    (torch.zeros(8, 7), "must be one-hot over the 7 entries"),
    (torch.ones(8, 7, dtype=torch.int64), "must be one-hot"),
    (torch.eye(7)[torch.zeros(8, dtype=torch.long)] * 0.5, "must be one-hot"),
    (-torch.eye(7)[torch.zeros(8, dtype=torch.long)], "must be one-hot"),
    (torch.eye(7)[torch.zeros(8, dtype=torch.long)].to(torch.complex64), "must be a real tensor, got torch.complex64"),
    (torch.full((8, 7), float("nan")), "NaN or inf in envs"),
    (torch.zeros(8, 2), r"action has shape \(8, 2\), expected \(8, 7\)"),
    (torch.zeros(8, 7, device="meta"), "action is on device meta"),
]


@pytest.mark.parametrize("kind", ["nav", "line"])
@pytest.mark.parametrize("action,message", DISCRETE_BAD, ids=[str(i) for i in range(len(DISCRETE_BAD))])
def test_discrete_envs_refuse_what_is_not_one_hot(kind, action, message):
    from tensordict import TensorDict

    from torchnav.envs import make_line_env, make_nav_env

    env = (make_nav_env("arena", 8, action={"mode": "discrete"}) if kind == "nav" else make_line_env("oval", 8, action={"mode": "discrete"}))
    env.reset()
    with pytest.raises(ValueError, match=message):
        env.step(TensorDict({"action": action}, batch_size=[8]))
    for dtype in (torch.float32, torch.float16, torch.int64, torch.uint8, torch.bool):  # a one-hot of any real dtype is an action
        env.step(TensorDict({"action": torch.nn.functional.one_hot(torch.arange(8) % 7, 7).to(dtype)}, batch_size=[8]))


@pytest.mark.parametrize("kind", ["nav", "line"])
def test_advance_checks_the_action_layout(kind):
    from torchnav.envs import make_line_env, make_nav_env

    env = make_nav_env("arena", 8) if kind == "nav" else make_line_env("oval", 8)
    env.reset()
    for action, message in [(torch.zeros(4, 2), r"action has shape \(4, 2\), expected \(8, 2\)"), (torch.zeros(8, 2, dtype=torch.int64), "floating-point"),
                            (torch.zeros(8, 2, device="meta"), "device meta")]:
        with pytest.raises(ValueError, match=message):
            env.advance(action)
    env.advance(torch.zeros(8, 2))


MULTI_BAD = [  # for 8 envs of 3 robots, continuous: (action, what the message must contain)
    (torch.zeros(8, 2, 2), r"\('agents', 'action'\) has shape \(8, 2, 2\), expected \(8, 3, 2\)"),
    (torch.zeros(8, 3, 3), r"has shape \(8, 3, 3\)"),
    (torch.zeros(8, 3, 2, dtype=torch.int64), "floating-point tensor, got torch.int64"),
    (torch.zeros(8, 3, 2, dtype=torch.bool), "floating-point tensor, got torch.bool"),
    (torch.zeros(8, 3, 2, dtype=torch.complex64), "floating-point tensor, got torch.complex64"),
    (torch.zeros(8, 3, 2, device="meta"), "is on device meta, expected the env's device cpu"),
    (torch.full((8, 3, 2), float("nan")), "NaN or inf in envs"),
]


@pytest.mark.parametrize("action,message", MULTI_BAD, ids=[str(i) for i in range(len(MULTI_BAD))])
def test_multi_robot_env_names_every_bad_action(action, message):
    from tensordict import TensorDict

    from torchnav.envs import make_multi_nav_env

    env = make_multi_nav_env("arena", 8, 3)
    env.reset()
    with pytest.raises(ValueError, match=message):
        env.step(TensorDict({"agents": TensorDict({"action": action}, batch_size=action.shape[:2])}, batch_size=[8]))


def test_multi_robot_env_names_a_missing_action_a_batch_and_a_discrete_one():
    from tensordict import TensorDict

    from torchnav.envs import make_multi_nav_env

    env = make_multi_nav_env("arena", 8, 3)
    with pytest.raises(ValueError, match=r"needs an \('agents', 'action'\) tensor of shape \(8, 3, 2\), got NoneType"):
        env.step(env.reset().set("action", torch.zeros(8, 2)))  # the single-robot key
    with pytest.raises(ValueError, match=r"batch size \(4,\), expected \(8,\)"):
        env.step(TensorDict({"agents": TensorDict({"action": torch.zeros(4, 3, 2)}, [4, 3])}, [4]))
    env = make_multi_nav_env("arena", 8, 3, action={"mode": "discrete"})
    env.reset()
    with pytest.raises(ValueError, match="must be one-hot over the 7 entries of action.discrete_set \\(one 1 per robot"):
        env.step(TensorDict({"agents": TensorDict({"action": torch.ones(8, 3, 7)}, [8, 3])}, [8]))
    env.step(TensorDict({"agents": TensorDict({"action": torch.nn.functional.one_hot(torch.arange(24).reshape(8, 3) % 7, 7)}, [8, 3])}, [8]))


@pytest.mark.parametrize("kind", ["line", "discrete"])
def test_gym_line_and_discrete_adapters_name_bad_actions(kind):
    from torchnav.gym import line_env, line_vector_env, navigation_env, navigation_vector_env

    if kind == "line":
        vec, one = line_vector_env(num_envs=8), line_env()
        cases = [(np.zeros((4, 2)), np.zeros((1, 2)), "must have shape"), (np.zeros((8, 2), dtype=bool), np.zeros(2, dtype=bool), "real numbers"),
                 (torch.zeros(8, 2, device="meta"), torch.zeros(2, device="meta"), "meta device"), (np.full((8, 2), -np.inf), np.full(2, np.inf), "NaN or inf")]
    else:
        vec, one = navigation_vector_env(num_envs=8, action={"mode": "discrete"}), navigation_env(action={"mode": "discrete"})
        cases = [(np.full(8, 7), 7, r"integers in \[0, 7\)"), (np.full(8, -1), -1, r"integers in \[0, 7\)"), (np.zeros(8) + 0.5, 0.5, "must be integers"),
                 (np.eye(7)[[0] * 8], np.eye(7)[0], "must be integers"), (np.zeros((8, 1), int), np.zeros(1, int), "must have shape"),
                 (np.zeros(8, bool), True, "must be integers")]
    vec.reset(seed=0)
    one.reset(seed=0)
    for vector, single, message in cases:
        with pytest.raises(ValueError, match=message):
            vec.step(vector)
        with pytest.raises(ValueError, match=message):
            one.step(single)
    vec.step(np.zeros(8, int) if kind == "discrete" else np.zeros((8, 2)))  # still steps after the refusals


PZ_BAD = [  # (mode, one robot's action, what the message must contain)
    ("continuous", np.zeros(3), r"robot_0: actions must have shape \(2,\)"),
    ("continuous", np.zeros((1, 2)), r"must have shape \(2,\) \(two values in \[-1, 1\] per robot\)"),
    ("continuous", np.zeros(2, dtype=bool), "real numbers"),
    ("continuous", np.zeros(2, dtype=complex), "real numbers"),
    ("continuous", "ab", "real numbers"),
    ("continuous", None, "real numbers"),
    ("continuous", [0, [0]], "must be an array"),
    ("continuous", torch.zeros(2, device="meta"), "meta device"),
    ("continuous", np.full(2, np.nan), "NaN or inf"),
    ("discrete", 99, r"integers in \[0, 7\)"),
    ("discrete", -1, r"integers in \[0, 7\)"),
    ("discrete", 0.5, "must be integers"),
    ("discrete", np.zeros(2, int), r"must have shape \(\)"),
    ("discrete", None, "must be integers"),
    ("discrete", True, "must be integers"),
]


@pytest.mark.parametrize("mode,action,message", PZ_BAD, ids=[f"{m}-{i}" for i, (m, _, _) in enumerate(PZ_BAD)])
def test_pettingzoo_adapter_names_every_bad_action(mode, action, message):
    pytest.importorskip("pettingzoo")
    from torchnav.pettingzoo import parallel_env

    env = parallel_env(n_robots=3, action={"mode": mode})
    env.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        env.step({a: action for a in env.agents})
    with pytest.raises(ValueError, match="must be a dict of agent name to action, got list"):
        env.step([action])
    env.step({a: (1 if mode == "discrete" else np.zeros(2)) for a in env.agents})  # still steps after the refusals


# --------------------------------------------------------------------------- checkpoints


def _saved_policy(tmp_path):
    from torchnav.policy import Actor, save_policy

    torch.manual_seed(0)
    actor = Actor(6, 2, [16, 16], "relu", "tanh")
    path = tmp_path / "actor.pt"
    save_policy(path, actor, task="nav", task_config={}, algorithm="td3")
    return actor, path


def test_damaged_checkpoint_never_loads_other_weights(tmp_path):
    from torchnav.checkpoint import CheckpointError
    from torchnav.policy import load_policy

    actor, path = _saved_policy(tmp_path)
    data = path.read_bytes()
    want = {k: v.clone() for k, v in actor.state_dict().items()}
    refused = 0
    for i in range(0, len(data), max(1, len(data) // 97)):
        bad = bytearray(data)
        bad[i] ^= 0x5A
        path.write_bytes(bytes(bad))
        try:
            got = load_policy(path).actor.state_dict()
        except (CheckpointError, ValueError):
            refused += 1
            continue
        assert all(torch.equal(got[k], want[k]) for k in want), f"flipping byte {i} loaded other weights silently"
    assert refused > 50, "most flipped bytes must be refused"


def test_truncated_nan_and_foreign_checkpoints_are_refused(tmp_path):
    from torchnav.checkpoint import CheckpointError, save_checked
    from torchnav.policy import load_policy

    actor, path = _saved_policy(tmp_path)
    path.write_bytes(path.read_bytes()[:500])
    with pytest.raises(CheckpointError, match="damaged or not a torch file"):
        load_policy(path)
    nan = tmp_path / "nan.pt"
    sd = actor.state_dict()
    sd["net.0.weight"] = sd["net.0.weight"].clone().fill_(float("nan")) if "net.0.weight" in sd else sd[next(iter(sd))].clone().fill_(float("nan"))
    save_checked(nan, {"format": "torchnav-actor-v2", "state": sd})
    with pytest.raises(CheckpointError, match=r"state\..* holds NaN or inf"):
        load_policy(nan)
    lst = tmp_path / "list.pt"
    torch.save([1, 2, 3], lst)
    with pytest.raises(CheckpointError, match="not a torchnav checkpoint"):
        load_policy(lst)
    with pytest.raises(FileNotFoundError, match="checkpoint not found"):
        load_policy(tmp_path / "missing.pt")


def test_recipe_refuses_to_resume_a_damaged_checkpoint(tmp_path):
    from torchnav.checkpoint import CheckpointError

    td3 = importlib.import_module("td3_lidar")
    tiny = ["threads=1", "env.num_envs=16", "task.max_steps=60", "eval.interval_frames=0", "eval.final_episodes=4", "eval.record_episodes=0",
            "checkpoint.interval_frames=128", "logger.progress=false", "train.frames_per_batch=128", "train.init_random_frames=128",
            "train.updates_per_batch=2", "train.batch_size=32", "train.hidden=[16,16]", "train.buffer_size=1000"]
    run = tmp_path / "run"
    td3.main(tiny + ["train.total_frames=128", f"logger.run_dir={run}"])
    ck = run / "checkpoint.pt"
    ck.write_bytes(ck.read_bytes()[:-300])
    with pytest.raises(CheckpointError, match="checkpoint.pt"):
        td3.main(tiny + ["train.total_frames=256", f"checkpoint.resume={run}"])


# --------------------------------------------------------------------------- runs and resume

TINY_TD3 = ["threads=1", "env.num_envs=16", "task.max_steps=60", "eval.interval_frames=0", "eval.final_episodes=4", "eval.record_episodes=0",
            "checkpoint.interval_frames=128", "logger.progress=false", "train.frames_per_batch=128", "train.init_random_frames=128",
            "train.updates_per_batch=2", "train.batch_size=32", "train.hidden=[16,16]", "train.buffer_size=1000"]


def test_resume_keeps_the_saved_config_and_refuses_other_changes(tmp_path, capsys):
    td3 = importlib.import_module("td3_lidar")
    run = tmp_path / "run"
    td3.main(TINY_TD3 + ["train.total_frames=128", "train.lr_actor=0.001", f"logger.run_dir={run}"])
    # defaults on the command line do not matter: the run's own config is continued
    with pytest.raises(ConfigError, match=r"cannot change train\.lr_actor \(0\.001 -> 0\.0005\)"):
        td3.main(["train.lr_actor=0.0005", f"--resume={run}"])
    capsys.readouterr()
    res = td3.main(["train.total_frames=256", "logger.progress=false", f"--resume={run}"])
    assert res["frames"] == 256
    out = capsys.readouterr().out
    assert "resume: train.total_frames: 128 -> 256" in out
    import yaml

    saved = yaml.safe_load((run / "config.yaml").read_text())
    assert saved["train"]["lr_actor"] == 0.001 and saved["env"]["num_envs"] == 16, "resume went back to the defaults"


def test_resume_without_a_path_takes_only_this_recipes_runs(tmp_path):
    td3 = importlib.import_module("td3_lidar")
    td3.main(TINY_TD3 + ["train.total_frames=128", f"logger.root={tmp_path}"])
    with pytest.raises(FileNotFoundError, match=f"no ppo_lidar run with a checkpoint.pt under {tmp_path}"):
        importlib.import_module("ppo_lidar").main(["--resume", f"logger.root={tmp_path}"])


def test_run_directories_are_never_shared(tmp_path):
    from types import SimpleNamespace

    import builders

    cfg = SimpleNamespace(seed=0, logger=SimpleNamespace(root=str(tmp_path), run_dir=None))
    runs = {builders.make_run_dir(cfg, "td3_lidar") for _ in range(3)}  # same second, same seed
    assert len(runs) == 3 and all(r.is_dir() for r in runs)
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "config.yaml").write_text("seed: 0\n")
    cfg.logger.run_dir = str(taken)
    with pytest.raises(ConfigError, match="already holds a run"):
        builders.make_run_dir(cfg, "td3_lidar")


CLAIMER = """
import sys
sys.path.insert(0, sys.argv[1])
from pathlib import Path
import builders
builders.claim_run_dir(Path(sys.argv[2]), fresh=True)
print("claimed", flush=True)
sys.stdin.readline()  # hold the run directory until the parent says so
"""


def test_two_runs_never_write_into_one_run_directory(tmp_path):
    import subprocess
    from types import SimpleNamespace

    import builders

    run = tmp_path / "shared"
    child = subprocess.Popen([sys.executable, "-c", CLAIMER, str(ROOT / "recipes"), str(run)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "claimed"
        cfg = SimpleNamespace(seed=0, logger=SimpleNamespace(root=str(tmp_path), run_dir=str(run)))
        # the other run has written nothing yet (no config.yaml): its claim alone keeps this one out
        with pytest.raises(builders.RunDirError, match="already holds a run"):
            builders.make_run_dir(cfg, "td3_lidar")
        with pytest.raises(builders.RunDirError, match=r"in use by another process \(its .torchnav_run is locked\)"):
            builders.make_run_dir(cfg, "td3_lidar", resuming=True)
    finally:
        child.communicate("\n", timeout=30)
    assert builders.make_run_dir(cfg, "td3_lidar", resuming=True) == run  # the lock went with the process
    # the same race in one process: both passed the "holds a run" check before either wrote
    other = tmp_path / "raced"
    builders.claim_run_dir(other, fresh=True)
    with pytest.raises(builders.RunDirError, match="another run is starting in it"):
        builders.claim_run_dir(other, fresh=True)


def test_an_unwritable_run_directory_is_named_before_training(tmp_path, monkeypatch):
    import builders

    td3 = importlib.import_module("td3_lidar")
    blocker = tmp_path / "file.txt"
    blocker.write_text("a regular file")
    with pytest.raises(builders.RunDirError, match=r"file\.txt/run: cannot create it \(NotADirectoryError"):
        td3.main(TINY_TD3 + ["train.total_frames=128", f"logger.run_dir={blocker / 'run'}"])
    with pytest.raises(builders.RunDirError, match=r"logger.root=.*file\.txt/runs: cannot create it"):
        td3.main(TINY_TD3 + ["train.total_frames=128", f"logger.root={blocker / 'runs'}"])

    def read_only(path, exclusive):  # what os.open says in a read-only directory (root ignores chmod, so it is simulated)
        raise OSError(30, "Read-only file system", str(path))

    monkeypatch.setattr(builders, "_open_claim", read_only)
    run = tmp_path / "ro"
    with pytest.raises(builders.RunDirError, match=r"ro is not writable \(OSError: \[Errno 30\] Read-only file system"):
        td3.main(TINY_TD3 + ["train.total_frames=128", f"logger.run_dir={run}"])
    assert not (run / "config.yaml").exists() and not (run / "logs").exists(), "the run went on after the probe failed"


def test_sweep_workers_never_share_a_run_directory(tmp_path, monkeypatch):
    import builders
    import sweep

    with pytest.raises(ConfigError, match=r"seed=0 \{\} and seed=0 \{\} both run in .*seed0; every seed and grid value must be distinct"):
        sweep.main(["run", "td3_lidar", "--seeds", "0", "0", "--out", str(tmp_path / "s")])
    with pytest.raises(ConfigError, match="both run in"):
        sweep.main(["run", "td3_lidar", "--seeds", "0", "--grid", "train.lr_actor=0.001,0.001", "--out", str(tmp_path / "s")])
    assert not (tmp_path / "s").exists()
    out = tmp_path / "race"
    out.mkdir()
    sweep.claim_sweep_dir(out, {"recipe": "td3_lidar"})
    monkeypatch.setattr(sweep.Path, "iterdir", lambda self: iter(()))  # the second sweep looked while the folder was still empty
    with pytest.raises(ConfigError, match="another sweep started in this folder at the same time"):
        sweep.claim_sweep_dir(out, {"recipe": "td3_lidar"})
    monkeypatch.undo()
    blocker = tmp_path / "file.txt"
    blocker.write_text("")
    with pytest.raises(builders.RunDirError, match="sweep folder .*file.txt/sweep is not writable"):
        sweep.main(["run", "td3_lidar", "--seeds", "0", "--out", str(blocker / "sweep")])


# --------------------------------------------------------------------------- maps and tracks

def _alias_bomb(top: str) -> str:
    """A document of 81 alias references that expands to 9^10 (3.5 billion) values under ``walls``."""
    levels = ["l0: &l0 [1, 1, 1, 1, 1, 1, 1, 1, 1]"] + [f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]" for i in range(1, 9)]
    return top + "\n".join(levels) + f"\nwalls: [{', '.join(['*l8'] * 9)}]\n"


ALIAS_BOMB = _alias_bomb("size: [5, 5]\n")


BAD_MAPS = [
    (ALIAS_BOMB, "expands to more than 2,000,000 values through its aliases"),
    ("size: [5, 5]\nl0: &l0 [1]\nwalls: [" + ", ".join(["*l0"] * 101) + "]", "more than 100 alias references"),
    ("size: " + "[" * 40 + "1" + "]" * 40, "nested deeper than 32 levels"),
    ("size: [5, 5]\nrandom_boxes: {count: 1000000, size_x: [0.1, 0.2], size_y: [0.1, 0.2]}", "random_boxes.count: expected an integer in [0, 64]"),
    ("size: [20, 20]\nrandom_circles: {count: 10000, radius: [0.05, 0.1]}", "random_circles.count: expected an integer in [0, 64]"),
    ("size: [20, 20]\nmoving_circles: {count: 65, radius: [0.05, 0.1], speed: [0, 1]}", "moving_circles.count: expected an integer in [0, 64]"),
    ("size: [20, 20]\nrandom_boxes: {count: 40, size_x: [0.1, 0.2], size_y: [0.1, 0.2]}\nrandom_circles: {count: 40, radius: [0.05, 0.1]}",
     "random_boxes.count + random_circles.count = 80; a map re-places at most 64"),
    # a random object whose circumscribed circle and margins span the world could be placed in no episode
    ("size: [10, 10]\nrandom_circles: {count: 64, radius: [5, 5]}", "random_circles.radius: the largest circle, 10 m across"),
    ("size: [10, 10]\nrandom_boxes: {count: 4, size_x: [0.5, 9.9], size_y: [0.1, 0.1]}", "random_boxes.size_x: the largest box, 9.9 m across"),
    ("size: [10, 10]\nmoving_circles: {count: 2, radius: [0.1, 4.95], speed: [0, 1]}", "moving_circles.radius: the largest moving disc, 9.9 m"),
    ("size: [1.0e39, 1.0e39]", "size: at most 10000 m per side"),
    ("size: [50000, 5]", "size: at most 10000 m per side"),
    ("size: [5, 5]\nsize: [6, 6]", "size: duplicate key at line 2"),
    ("size: [5, 5]\nboxs: []", "boxs: unknown key (did you mean 'boxes'?)"),
    ("size: [5, 5]\nboxes:\n  - {center: [0, 0], size: [nan, 1]}", "boxes[0].size"),
    ("size: [5, 5\n", "YAML syntax error"),
]


@pytest.mark.parametrize("text,message", BAD_MAPS, ids=[m for _, m in BAD_MAPS])
def test_bad_map_file_is_named_quickly(tmp_path, text, message):
    from torchnav.maps import load_map

    _refused_quickly(load_map, MapError, tmp_path / "bad.yaml", text, message)


def _refused_quickly(load, error: type, path: Path, text: str, message: str) -> None:
    """``load(path)`` of a file holding ``text`` raises ``error`` naming ``message`` and the file, within 5 s."""
    import time

    path.write_text(text)
    t0 = time.perf_counter()
    with pytest.raises(error) as e:
        load(path)
    assert message in str(e.value) and str(path) in str(e.value)
    assert time.perf_counter() - t0 < 5, "the loader must not hang"


@pytest.mark.parametrize("text", ["size: [5, 5]\nboxes:\n  - {center: [0, 0], size: [5, 5]}",  # a box as large as the world
                                  "size: [0.3, 0.3]",  # smaller than the robot
                                  "size: [10000, 0.5]\nwalls: boundary"])  # thinner than the room grid's spacing: a grid of no cell
def test_map_without_room_for_the_robot_is_refused(tmp_path, text):
    from torchnav.envs import make_nav_env

    path = tmp_path / "full.yaml"
    path.write_text(text)
    with pytest.raises(MapError, match="no room for a start"):
        make_nav_env(str(path), num_envs=2)


def test_huge_image_is_refused_before_decoding(tmp_path, monkeypatch):
    from PIL import Image

    from torchnav.maps import load_map, occupancy

    Image.new("L", (300, 300), 255).save(tmp_path / "big.png")
    monkeypatch.setattr(occupancy, "MAX_PIXELS", 200 * 200)
    (tmp_path / "m.yaml").write_text("size: [10, 10]\noccupancy: {image: big.png, resolution: 0.01}\n")
    with pytest.raises(MapError, match="300 x 300 pixels is more than the 40,000 allowed"):
        load_map(tmp_path / "m.yaml")


def test_track_alias_bomb_is_refused(tmp_path):
    from torchnav.tracks import load_track

    path = tmp_path / "t.yaml"
    path.write_text(_alias_bomb("width: 0.02\n"))
    with pytest.raises(TrackError, match="expands to more than"):
        load_track(path)


BAD_TRACKS = [  # (track file, what the message must contain): each refused before the curve is allocated
    ("width: 0.02\nspacing: 1.0e-9\nlines:\n  - {points: [[0, 0], [1, 0], [1, 1]], closed: true}",
     "spacing: a line 3.41421 m long at spacing 1e-09 m would need 3,414,213,562 points, more than the 1,000,000 allowed"),
    ("width: 0.02\nspacing: 1.0e-300\nlines:\n  - {points: [[0, 0], [1, 0], [1, 1]], closed: true}", "spacing: a line"),
    ("width: 0.02\nlines:\n  - {points: [[0, 0], [1.0e6, 0], [1.0e6, 1.0e6]], closed: true}", "spacing: a line"),
    ("width: 0.02\nlines:\n  - {points: [[0, 0], [1.0e5, 0], [1.0e5, 1.0e5]], closed: true, corner_radius: 2.0e4}",
     "lines[0].corner_radius: the fillets"),
    ("width: 0.02\nlines:\n  - {points: [[0, 0], [1.0e4, 0], [1.0e4, 1.0e4]], closed: true, smooth: true}", "lines[0].points: the spline"),
    ("width: 0.02\nlines:\n  - {points: [[0, 0], [1.0e-7, 0], [1.0e-7, 1.0e-7]], closed: true}",  # a lap smaller than one spacing
     "spacing: a closed line 3.41421e-07 m long at spacing 0.02 m would have 1 segment; a lap needs at least 3"),
    ("width: 0.02\nspacing: 0.7\nlines:\n  - {points: [[0, 0], [0.4, 0], [0.4, 0.4]], closed: true}", "would have 2 segments; a lap needs at least 3"),
]


@pytest.mark.parametrize("text,message", BAD_TRACKS, ids=[str(i) for i in range(len(BAD_TRACKS))])
def test_track_resampling_is_bounded_up_front(tmp_path, text, message):
    from torchnav.tracks import load_track

    _refused_quickly(load_track, TrackError, tmp_path / "t.yaml", text, message)


def test_track_at_the_point_limit_builds(tmp_path):
    from torchnav.tracks import load_track
    from torchnav.tracks.geometry import MAX_CURVE_POINTS

    side = MAX_CURVE_POINTS * 0.02 / 4 * 0.99  # a square lap just under the limit at the default spacing
    path = tmp_path / "t.yaml"
    path.write_text(f"width: 0.02\nlines:\n  - {{points: [[0, 0], [{side}, 0], [{side}, {side}], [0, {side}]], closed: true}}")
    assert len(load_track(path).lap) <= MAX_CURVE_POINTS + 1


def test_image_track_of_a_tiny_scale_is_refused(tmp_path):
    from PIL import Image, ImageDraw

    from torchnav.tracks import load_track

    im = Image.new("L", (100, 100), 0)
    ImageDraw.Draw(im).ellipse((10, 10, 90, 90), outline=255, width=3)
    im.save(tmp_path / "ring.png")
    # 1e-9 m per pixel: a lap of a quarter of a micrometre, which resampling once made into a single point
    _refused_quickly(load_track, TrackError, tmp_path / "t.yaml", "image: ring.png\nresolution: 1.0e-9\n", "spacing: the traced lap: a closed line")


@pytest.mark.parametrize("kind", ["map", "track"])
def test_image_over_pillows_own_limit_is_named(tmp_path, monkeypatch, kind):
    from PIL import Image

    from torchnav.maps import load_map
    from torchnav.tracks import load_track

    Image.new("L", (300, 300), 255).save(tmp_path / "big.png")
    # Pillow refuses images over twice its MAX_IMAGE_PIXELS inside open(); lower it so a small file trips it.
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100 * 100)
    if kind == "map":
        (tmp_path / "m.yaml").write_text("size: [10, 10]\noccupancy: {image: big.png, resolution: 0.01}\n")
        with pytest.raises(MapError, match=r"big\.png: more than the 16,777,216 pixels allowed"):
            load_map(tmp_path / "m.yaml")
    else:
        (tmp_path / "t.yaml").write_text("image: big.png\nresolution: 0.01\n")
        with pytest.raises(TrackError, match=r"big\.png: more than the 16,777,216 pixels allowed"):
            load_track(tmp_path / "t.yaml")


@pytest.mark.parametrize("objects", [
    "random_circles: {count: 64, radius: [0.05, 0.1], clearance: 0.5, margin: 0.01}",
    "random_boxes: {count: 32, size_x: [0.1, 0.2], size_y: [0.1, 0.2], clearance: 0.5}\nrandom_circles: {count: 32, radius: [0.05, 0.1], clearance: 0.5}\n"
    "moving_circles: {count: 64, radius: [0.05, 0.1], speed: [0, 0.5], clearance: 0.5, margin: 0.01}",
    "moving_boxes: {count: 64, size_x: [0.1, 0.2], size_y: [0.1, 0.2], speed: [0, 0.5], motion: pedestrian}",
], ids=["circles", "boxes+circles+movers", "moving_boxes"])
def test_every_count_at_its_maximum_builds_within_seconds(tmp_path, objects):
    import time

    from torchnav.envs import make_nav_env

    path = tmp_path / "m.yaml"
    path.write_text(f"size: [20, 20]\n{objects}\n")
    t0 = time.perf_counter()
    env = make_nav_env(str(path), num_envs=64)
    env.rollout(3)
    assert time.perf_counter() - t0 < 30, "the documented maximum must build and step within seconds"


@pytest.mark.parametrize("obstacles", ["circles:\n  - [0, 0, 5.0]",  # leaves only the four corners free
                                       "boxes:\n  - {center: [0, 0], size: [7.8, 7.8]}"])  # leaves a thin ring
def test_a_map_with_little_room_never_starts_in_collision(tmp_path, obstacles):
    from torchnav.envs import make_nav_env
    from torchnav.sim import points_clearance

    path = tmp_path / "little_room.yaml"
    path.write_text(f"size: [10, 10]\n{obstacles}\n")
    env = make_nav_env(str(path), num_envs=512)
    for seed in range(3):
        env.set_seed(seed)
        td = env.reset()
        clear = points_clearance(td["pose"][:, None, :2], env.state.world)[:, 0]
        assert (clear >= env.cfg.robot.radius + env.cfg.reset.start_clearance - 1e-4).all(), \
            f"seed {seed}: {(clear < env.cfg.robot.radius).sum().item()} of 512 starts overlap an obstacle"


def test_map_distance_field_is_chunked_over_many_obstacles():
    # check_room's grid against a map's fixed obstacles once held a (points, obstacles) table:
    # 40,000 cells x 100,000 circles asked for 32 GB. Chunks give the same distances.
    from torchnav.maps.free_space import obstacle_distance_arrays
    from torchnav.sim import make_world, points_clearance

    g = torch.Generator().manual_seed(0)
    circles = torch.cat((torch.rand(5000, 2, generator=g, dtype=torch.float64) * 20 - 10, torch.full((5000, 1), 0.05, dtype=torch.float64)), 1)
    xy = torch.rand(2000, 2, generator=g, dtype=torch.float64) * 20 - 10
    got = obstacle_distance_arrays(xy.numpy(), circles=circles.numpy())
    want = points_clearance(xy[None], make_world(1, circles=circles.numpy(), dtype=torch.float64))[0].numpy()
    assert np.array_equal(got, want)


@pytest.mark.parametrize("fault", ["disk full", "killed during the rename"])
def test_a_write_that_fails_half_way_leaves_the_previous_file_loadable(tmp_path, monkeypatch, fault):
    import os

    from torchnav import checkpoint
    from torchnav.checkpoint import load_checked, save_checked, write_atomic

    ckpt, summary = tmp_path / "checkpoint.pt", tmp_path / "summary.json"
    save_checked(ckpt, {"format": "test", "step": torch.tensor(1)})
    write_atomic(summary, '{"frames": 1}')

    def fail(*args, **kwargs):
        raise OSError(28 if fault == "disk full" else 4, fault)

    actor, policy = _saved_policy(tmp_path)
    from torchnav.policy import load_policy, save_policy

    monkeypatch.setattr(checkpoint.os, "fsync" if fault == "disk full" else "replace", fail)
    with pytest.raises(OSError, match=fault):
        save_checked(ckpt, {"format": "test", "step": torch.tensor(2)})
    with torch.no_grad():
        other = type(actor)(6, 2, [16, 16], "relu", "tanh")
        for p in other.parameters():
            p.fill_(0.5)
    with pytest.raises(OSError, match=fault):
        save_policy(policy, other, task="nav", task_config={}, algorithm="td3")
    with pytest.raises(OSError, match=fault):
        write_atomic(summary, '{"frames": 2}')
    monkeypatch.undo()
    assert int(load_checked(ckpt)["step"]) == 1 and summary.read_text() == '{"frames": 1}'
    got = load_policy(policy).actor.state_dict()
    assert all(torch.equal(got[k], v) for k, v in actor.state_dict().items()), "actor.pt is not the previous policy"
    assert sorted(os.listdir(tmp_path)) == ["actor.pt", "checkpoint.pt", "summary.json"]  # no half-written temporary file is left


@pytest.mark.parametrize("fault", ["killed during the rename", "disk full"])
def test_a_recording_that_fails_half_way_leaves_the_previous_one_loadable(tmp_path, monkeypatch, fault):
    import warnings

    from torchnav.envs import make_nav_env
    from torchnav.record import EpisodeRecorder, RecordingWarning, mcap_writer, read_recording, record_rollout

    env = make_nav_env("arena", num_envs=2, max_steps=20, seed=0)
    path = tmp_path / "episodes.mcap"
    with EpisodeRecorder(path, env, envs=(0,), episodes=1) as rec:
        record_rollout(env, None, 40, rec)
    before = read_recording(path)
    assert before.complete and len(before.episodes()) == 1

    def fail(*args, **kwargs):
        raise OSError(28 if fault == "disk full" else 4, fault)

    monkeypatch.setattr(mcap_writer.os, "replace" if fault.startswith("killed") else "fsync", fail)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        rec = EpisodeRecorder(path, env, envs=(1,), episodes=2)
        record_rollout(env, None, 60, rec)
        rec.close()
    monkeypatch.undo()
    assert sum(issubclass(x.category, RecordingWarning) for x in w) == 1 and fault in rec.error
    assert f"{path} is as it was before this recording" in str(w[0].message)
    after = read_recording(path)  # the previous recording, whole
    assert after.complete and after.info["envs"] == before.info["envs"] and len(after.episodes()) == 1
    assert read_recording(rec.partial_path).episodes(), "the failed recording's flushed episodes are kept beside it"


# --------------------------------------------------------------------------- the soak (bench/soak.py)

def _soak():
    spec = importlib.util.spec_from_file_location("soak", ROOT / "bench" / "soak.py")
    soak = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(soak)
    return soak


def test_soak_counters_see_what_they_count():
    """The soak's checks are not vacuous: a pose outside its walls, a NaN and an undocumented inf are counted."""
    from torchnav.sim import make_world

    soak = _soak()
    world = make_world(2, segments=[[-5, -5, 5, -5], [5, -5, 5, 5], [5, 5, -5, 5], [-5, 5, -5, -5]])
    box = soak.world_box(world, 0.2)
    assert box[0].tolist() == pytest.approx([-5.2, -5.2, 5.2, 5.2])
    pose = torch.tensor([[0.0, 0.0, 0.0], [5.3, 0.0, 0.0]])
    assert soak.outside(pose, box).tolist() == [False, True]
    assert soak.outside(torch.full((2, 3), float("nan")), box).all()
    c = soak.Counts()
    c.state({"pose": torch.tensor([float("nan"), 1.0]), "goal_path": torch.tensor([float("inf")]), "sim": {"vel": torch.tensor([float("inf")])}})
    assert (c.nan, c.inf_unexpected) == (1, 1)


@pytest.mark.slow  # a minute or two: every cell of the soak, briefly
def test_soak_quick_finds_nothing(tmp_path):
    import json
    import subprocess

    out = subprocess.run([sys.executable, str(ROOT / "bench" / "soak.py"), "--quick", "--json", "--threads", "1"], cwd=ROOT,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    soak = _soak()
    assert [c["cell"] for c in summary["cells"]] == [name for name, _, _ in soak.cells()]
    assert all(c["env_steps"] > 0 for c in summary["cells"])
    for key in ("nan", "inf_unexpected", "out_of_bounds", "tunnelled", "silent", "errors"):
        assert summary[key] == 0, (key, [(c["cell"], c[key]) for c in summary["cells"] if c[key]])
    assert summary["bad_actions_refused"] >= 2 * len(summary["cells"]), "the NaN and inf probes must run in every cell"
    assert len(summary["rss_mb_per_round"]) == 2 and summary["env_steps"] == sum(c["env_steps"] for c in summary["cells"])
    assert summary["env_steps"] >= summary["steps_requested"]  # the multi-robot cell's share is not lost


@pytest.mark.parametrize("overrides, key", [
    ({"lidar": {"n_rays": 10**8}}, "lidar.n_rays"),
    ({"lidar": {"n_rays": 10**8, "n_sectors": 10**8}}, "lidar.n_sectors"),
    ({"observation": {"history": 10**8}}, "observation.history"),
    ({"observation": {"visit_sectors": 8, "visit_memory": 10**9}}, "observation.visit_memory"),
    ({"lidar": {"max_range": 1e300}}, "lidar.max_range"),
    ({"camera": {"n_cols": 10**7}}, "camera.n_cols"),
    ({"camera": {"max_range": 1e300}}, "camera.max_range"),
])
def test_sizes_past_memory_are_refused_up_front(overrides, key):
    """Sizes whose tensors would not fit in memory are named before anything is allocated."""
    from torchnav.envs import make_nav_env

    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        make_nav_env("arena", 4, **overrides)


@pytest.mark.parametrize("n", [0, -3, 10**9, 2.5, True, "8"])
def test_num_envs_out_of_range_is_named(n):
    from torchnav.envs import NavEnv

    with pytest.raises(ValueError, match="num_envs must be an integer"):
        NavEnv(num_envs=n)


def test_a_map_of_ten_thousand_rows_parses_quickly(tmp_path):
    """The strict loader's rules on libyaml's parser (about 24 s of CPU for this file on the pure-Python
    parser, 2-4 s now): the rows load, and a duplicate key in such a file is still refused with its line."""
    from torchnav.maps import load_map

    rows = "\n".join(f"  - [{-4.8 + 0.096 * (i % 100):.3f}, {-4.8 + 0.096 * (i // 100):.3f}, 0.01]" for i in range(10_000))
    (tmp_path / "many.yaml").write_text(f"size: [10, 10]\ncircles:\n{rows}\n")
    assert len(load_map(str(tmp_path / "many.yaml")).circles) == 10_000
    (tmp_path / "dup.yaml").write_text(f"size: [10, 10]\nsize: [5, 5]\ncircles:\n{rows}\n")
    with pytest.raises(MapError, match="size: duplicate key at line 2"):
        load_map(str(tmp_path / "dup.yaml"))


@pytest.mark.parametrize("width", [1e-12, 1e6])
def test_track_width_out_of_range_is_named(tmp_path, width):
    from torchnav.tracks import load_track

    (tmp_path / "t.yaml").write_text(f"width: {width}\nlines:\n  - {{points: [[0, 0], [1, 0], [1, 1]], closed: true, lap: true}}\n")
    with pytest.raises(TrackError, match=r"width: expected a line width in \[0.001, 10\] m"):
        load_track(str(tmp_path / "t.yaml"))


def test_exports_keep_the_previous_file_on_a_failed_write(tmp_path, monkeypatch):
    """The C and ONNX exports write through write_atomic: a write that fails keeps the previous files."""
    import os

    from torchnav.export.c import write_files

    write_files(tmp_path, {"policy.h": "old"})

    def full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError, match="No space"):
        write_files(tmp_path, {"policy.h": "new"})
    assert (tmp_path / "policy.h").read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["policy.h"]
