"""The recipes' config classes (torchnav/train_config.py): every shipped YAML lists only what it changes
from its class's defaults, and a bad key or value is named, with what is allowed, before any run
directory exists."""

from __future__ import annotations

import dataclasses
import importlib
import sys
import typing
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "recipes"))

import torchnav.train_config as K  # noqa: E402
from torchnav.config import ConfigError, to_dict  # noqa: E402
from torchnav.tasks import LineConfig, MultiNavConfig, NavConfig  # noqa: E402

L = K  # the loading functions live in the same module

# every shipped config file -> the recipe that reads it
SHIPPED = {p.stem: p.stem for p in (ROOT / "recipes" / "configs").glob("*.yaml") if p.stem in K.RECIPES}
SHIPPED.update({"ppo_generalist": "ppo_lidar", "ppo_generalist_jackal": "ppo_lidar", "ppo_movers": "ppo_lidar"})


def test_every_config_file_has_its_recipe():
    assert sorted(SHIPPED) == sorted(p.stem for p in (ROOT / "recipes" / "configs").glob("*.yaml"))
    assert sorted(K.RECIPES) == sorted(p.stem for p in (ROOT / "recipes").glob("*.py") if (ROOT / "recipes" / "configs" / f"{p.stem}.yaml").is_file())


@pytest.mark.parametrize("config,recipe", sorted(SHIPPED.items()))
def test_shipped_yaml_lists_what_differs_from_its_class_and_round_trips(config, recipe, tmp_path):
    path = ROOT / "recipes" / "configs" / f"{config}.yaml"
    cfg = L.load_config(recipe, ["--config", str(path)])
    assert type(cfg) is K.RECIPES[recipe]
    assert isinstance(cfg.task, LineConfig if recipe.endswith("_line") else NavConfig)
    # each key of the file is a field, each value is the field's value, and differs from the default
    data = yaml.safe_load(path.read_text()) or {}
    base = data.pop(K.BASE_KEY, None)  # a file with a base lists what differs from its base's config
    default = L.load_config(recipe, ["--config", str(path.parent / base)]) if base else K.RECIPES[recipe]()

    def same(node, obj, base, key):
        if isinstance(node, dict) and dataclasses.is_dataclass(obj):
            for k, v in node.items():
                assert k in {f.name for f in dataclasses.fields(obj)}, key
                same(v, getattr(obj, k), getattr(base, k), f"{key}.{k}")
        else:
            assert to_dict(obj) == node or to_dict(obj) == to_dict(node), key
            assert to_dict(obj) != to_dict(base), f"{key}: the file repeats the default {to_dict(base)!r}"

    same(data, cfg, default, config)
    # the saved config has every key, and reads back to the same config
    L.save_config(cfg, tmp_path)
    saved = yaml.safe_load((tmp_path / "config.yaml").read_text())
    assert saved == to_dict(cfg) and set(saved) == {f.name for f in dataclasses.fields(cfg)}
    assert L.load_config(recipe, ["--config", str(tmp_path / "config.yaml")]) == cfg


def test_config_dir_and_default_folder(tmp_path):
    """load_config reads <config_dir>/<name>.yaml, by default the repository's recipes/configs."""
    assert K.CONFIG_DIR == ROOT / "recipes" / "configs"
    (tmp_path / "td3_lidar.yaml").write_text("seed: 7\n")
    assert L.load_config("td3_lidar", [], config_dir=tmp_path).seed == 7
    assert L.load_config("td3_lidar", []).seed == 0
    with pytest.raises(ConfigError, match="config file not found"):
        L.load_config("td3_lidar", [], config_dir=tmp_path / "nowhere")


def test_base_file_lays_its_changes_over_another(tmp_path):
    """``base: FILE`` (relative to the file): mappings merge key by key, other values replace, chains
    follow; a missing base, a cycle, a base that is not a path and unreadable YAML are named."""
    (tmp_path / "a.yaml").write_text("seed: 3\ntask:\n  max_steps: 300\n  robot: {v_max: 0.5, omega_max: 2.0}\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.yaml").write_text("base: ../a.yaml\ntask:\n  robot: {omega_max: 3.0}\n")
    (tmp_path / "c.yaml").write_text("base: sub/b.yaml\nseed: 5\n")
    cfg = L.load_config("td3_lidar", ["--config", str(tmp_path / "c.yaml"), "task.robot.v_max=0.7"])
    assert (cfg.seed, cfg.task.max_steps, cfg.task.robot.v_max, cfg.task.robot.omega_max) == (5, 300, 0.7, 3.0)
    # a preset in the file replaces its base's body; robot keys beside it win
    (tmp_path / "d.yaml").write_text("base: a.yaml\ntask:\n  robot: {preset: turtlebot3_burger, omega_max: 1.5}\n")
    robot = L.load_config("td3_lidar", ["--config", str(tmp_path / "d.yaml")]).task.robot
    assert (robot.v_max, robot.omega_max, robot.radius) == (0.22, 1.5, 0.105)
    cases = {"base: nowhere.yaml\n": r"config file not found: .*nowhere.yaml \(the base of .*bad.yaml\)",
             "base: bad.yaml\n": r"base: bad.yaml is a cycle",
             "base: [a.yaml]\n": r"base: expected the path of the config file this one changes",
             "seed: [1\n": r"bad.yaml: not readable YAML",
             "- 1\n": r"bad.yaml: expected a mapping of config sections, got list"}
    for text, message in cases.items():
        (tmp_path / "bad.yaml").write_text(text)
        with pytest.raises(ConfigError, match=message):
            L.load_config("td3_lidar", ["--config", str(tmp_path / "bad.yaml")])


def test_every_train_default_is_its_main_recipe():
    """Each algorithm's train defaults are its main recipe's resolved values (whose file sets no train key)."""
    for recipe, cls in (("td3_lidar", K.TD3Train), ("ppo_lidar", K.PPOTrain), ("sac_lidar", K.SACTrain),
                        ("dqn_line", K.DQNTrain), ("apg_lidar", K.APGTrain)):
        assert L.load_config(recipe, []).train == cls(), recipe
        assert "train" not in (yaml.safe_load((ROOT / "recipes" / "configs" / f"{recipe}.yaml").read_text()) or {}), recipe


def test_every_field_declares_what_it_allows():
    """A new recipe key without a declared range fails here: only these take any value of their type."""
    free = set()

    def walk(cls, prefix):
        for f in dataclasses.fields(cls):
            tp = typing.get_type_hints(cls)[f.name]
            if dataclasses.is_dataclass(tp):
                if tp not in (NavConfig, LineConfig, MultiNavConfig):  # the task's own classes check themselves
                    walk(tp, f"{prefix}{f.name}.")
            elif "check" not in f.metadata:
                free.add(prefix + f.name)

    for cls in K.RECIPES.values():
        walk(cls, "")
    # any path (root, run_dir) and resume's true, false or a path
    assert free == {"logger.root", "logger.run_dir", "checkpoint.resume"}


@pytest.mark.parametrize("recipe", sorted(K.RECIPES))
@pytest.mark.parametrize("override,message", [
    ("train.total_framez=10", "unknown config key 'train.total_framez' (did you mean 'train.total_frames'?)"),
    ("train.total_frames=abc", "train.total_frames='abc': must be an integer >= 1"),
    ("train.total_frames=0", "train.total_frames=0: must be an integer >= 1"),
    ("train.gamma=inf", "train.gamma=inf: must be finite"),
    ("eval.target_success=1.5", "eval.target_success=1.5: must be a number in [0, 1]"),
    ("task.max_steps=x", "task.max_steps='x': must be an integer >= 1"),
])
def test_bad_key_type_or_range_is_named_before_the_run_directory(tmp_path, recipe, override, message):
    run = tmp_path / "run"
    with pytest.raises(ConfigError) as e:
        importlib.import_module(recipe).main([override, f"logger.run_dir={run}"])
    assert message in str(e.value)
    assert not run.exists()


def test_a_file_leaving_out_a_key_takes_its_default_and_an_old_layout_key_is_unknown(tmp_path):
    data = {"train": {"total_frames": 1000}, "env": {"num_envs": 16}}
    path = tmp_path / "partial.yaml"
    path.write_text(yaml.safe_dump(data))
    cfg = L.load_config("td3_lidar", ["--config", str(path)])
    assert cfg.train == K.TD3Train(total_frames=1000) and cfg.eval == K.EvalConfig() and cfg.env.num_envs == 16
    # a key of the layout before the task section (env.map, curriculum, reward) is just an unknown key
    with pytest.raises(ConfigError, match="unknown config key 'env.map'; valid keys of env: num_envs, compile_step"):
        L.load_config("td3_lidar", ["env.map=warehouse"])
    with pytest.raises(ConfigError, match="unknown config key 'curriculum.growth'; valid keys: seed, device, threads, env, task"):
        L.load_config("td3_lidar", ["curriculum.growth=0.01"])
    path.write_text(yaml.safe_dump({"env": {"num_envs": 16, "track": "oval"}, "reward": {"weights": {"lap": 1.0}}}))
    with pytest.raises(ConfigError) as e:
        L.load_config("ppo_line", ["--config", str(path)])
    assert "env: unknown key 'track'; valid keys: num_envs" in str(e.value) and "unknown key 'reward'" in str(e.value)


def test_a_resumed_run_keeps_its_saved_config_and_names_each_change(tmp_path):
    saved = to_dict(L.load_config("ppo_line", ["task.track=oval", "task.max_steps=900", "task.reward.weights.lap=1.0"]))
    cfg, changes = L.resumed_config(saved, ["train.total_frames=2000000"], "ppo_line", tmp_path)
    assert (cfg.task.track, cfg.task.max_steps, cfg.task.reward.weights) == ("oval", 900, {"lap": 1.0})
    assert changes == ["train.total_frames: 1000000 -> 2000000"] and cfg.logger.run_dir == str(tmp_path)
    with pytest.raises(ConfigError, match=r"cannot change task.max_steps \(900 -> 800\)"):
        L.resumed_config(saved, ["task.max_steps=800"], "ppo_line", tmp_path)


def test_command_line_values_read_as_yaml():
    assert L.parse_override("train.lr=1e-3") == ("train.lr", 0.001)
    assert L.parse_override("train.hidden=[16,16]") == ("train.hidden", [16, 16])
    assert L.parse_override("task.curriculum.mode=off") == ("task.curriculum.mode", "off")  # not YAML 1.1's false
    assert L.parse_override("logger.run_dir=null") == ("logger.run_dir", None)
    assert L.parse_override("eval.target_success=nan")[1] != L.parse_override("eval.target_success=nan")[1]  # a float nan
    with pytest.raises(ConfigError, match="train.hidden=\\[16: not a readable value"):
        L.parse_override("train.hidden=[16")
