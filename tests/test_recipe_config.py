"""The recipes' config classes (recipes/_config.py): every shipped YAML is exactly its class, and a bad
key or value is named, with what is allowed, before any run directory exists."""

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

import _config as K  # noqa: E402
import _config_load as L  # noqa: E402

from torchnav.config import ConfigError, to_dict  # noqa: E402
from torchnav.tasks import LineConfig, NavConfig  # noqa: E402

# every shipped config file -> the recipe that reads it
SHIPPED = {p.stem: p.stem for p in (ROOT / "recipes" / "configs").glob("*.yaml") if p.stem in K.RECIPES}
SHIPPED.update({"ppo_generalist": "ppo_lidar", "ppo_movers": "ppo_lidar"})


def test_every_config_file_has_its_recipe():
    assert sorted(SHIPPED) == sorted(p.stem for p in (ROOT / "recipes" / "configs").glob("*.yaml"))
    assert sorted(K.RECIPES) == sorted(p.stem for p in (ROOT / "recipes").glob("*.py") if (ROOT / "recipes" / "configs" / f"{p.stem}.yaml").is_file())


@pytest.mark.parametrize("config,recipe", sorted(SHIPPED.items()))
def test_shipped_yaml_is_its_class_and_round_trips(config, recipe, tmp_path):
    path = ROOT / "recipes" / "configs" / f"{config}.yaml"
    cfg = L.load_config(recipe, ["--config", str(path)])
    assert type(cfg) is K.RECIPES[recipe]
    assert isinstance(cfg.task, LineConfig if recipe.endswith("_line") else NavConfig)
    # one to one: each key of the file is a field, and each value is the field's value
    data = yaml.safe_load(path.read_text())
    assert set(data) == {f.name for f in dataclasses.fields(cfg)}

    def same(node, obj, key):
        if isinstance(node, dict) and dataclasses.is_dataclass(obj):
            for k, v in node.items():
                same(v, getattr(obj, k), f"{key}.{k}")
        else:
            assert to_dict(obj) == node or to_dict(obj) == to_dict(node), key

    same(data, cfg, config)
    L.save_config(cfg, tmp_path)
    assert L.load_config(recipe, ["--config", str(tmp_path / "config.yaml")]) == cfg


def test_every_field_declares_what_it_allows():
    """A new recipe key without a declared range fails here: only these take any value of their type."""
    free = set()

    def walk(cls, prefix):
        for f in dataclasses.fields(cls):
            tp = typing.get_type_hints(cls)[f.name]
            if dataclasses.is_dataclass(tp):
                if tp not in (NavConfig, LineConfig):  # the task's own classes check themselves
                    walk(tp, f"{prefix}{f.name}.")
            elif "check" not in f.metadata:
                free.add(prefix + f.name)

    for cls in K.RECIPES.values():
        walk(cls, "")
    # threads: 'auto' or an int >= 1 and logger.backend: a known, installed backend, both in __post_init__
    assert free == {"threads", "logger.backend", "logger.root", "logger.run_dir", "checkpoint.resume"}


@pytest.mark.parametrize("recipe", sorted(K.RECIPES))
@pytest.mark.parametrize("override,message", [
    ("train.total_framez=10", "unknown config key 'train.total_framez' (did you mean 'train.total_frames'?)"),
    ("train.total_frames=abc", "train.total_frames='abc': must be an integer >= 1"),
    ("train.total_frames=0", "train.total_frames=0: must be an integer >= 1"),
    ("train.gamma=inf", "train.gamma=inf: must be finite"),
    ("eval.target_success=1.5", "eval.target_success=1.5: must be a number in [0, 1]"),
    ("task.max_steps=x", "task.max_steps: expected an integer, got str 'x'"),
])
def test_bad_key_type_or_range_is_named_before_the_run_directory(tmp_path, recipe, override, message):
    run = tmp_path / "run"
    with pytest.raises(ConfigError) as e:
        importlib.import_module(recipe).main([override, f"logger.run_dir={run}"])
    assert message in str(e.value)
    assert not run.exists()


@pytest.mark.parametrize("old,new", [("env.map=warehouse", "task.map"), ("curriculum.growth=0.01", "task.curriculum.growth"),
                                     ("reward.weights.step=-0.01", "task.reward.weights.step"), ("env.max_steps=100", "task.max_steps")])
def test_a_key_of_the_old_layout_names_its_new_key(old, new):
    with pytest.raises(ConfigError, match=f"{old.split('=')[0]} is now {new}"):
        L.load_config("td3_lidar", [old])


def test_an_old_layout_file_is_refused_and_an_old_saved_run_migrates(tmp_path):
    new = yaml.safe_load((ROOT / "recipes" / "configs" / "ppo_line.yaml").read_text())
    old = {**new, "env": {"num_envs": 256, "track": "oval", "max_steps": 900}, "reward": {"weights": {"lap": 1.0}}, "task": {}}
    path = tmp_path / "old.yaml"
    path.write_text(yaml.safe_dump(old))
    with pytest.raises(ConfigError, match="env.max_steps is now task.max_steps; env.track is now task.track; reward is now task.reward"):
        L.load_config("ppo_line", ["--config", str(path)])
    cfg, changes = L.resumed_config(old, ["train.total_frames=2000000"], "ppo_line", tmp_path)
    assert (cfg.task.track, cfg.task.max_steps, cfg.task.reward.weights) == ("oval", 900, {"lap": 1.0})
    assert changes == ["train.total_frames: 1000000 -> 2000000"] and cfg.logger.run_dir == str(tmp_path)


def test_a_file_missing_a_key_names_it(tmp_path):
    data = yaml.safe_load((ROOT / "recipes" / "configs" / "td3_lidar.yaml").read_text())
    del data["train"]["policy_delay"], data["eval"]
    path = tmp_path / "partial.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as e:
        L.load_config("td3_lidar", ["--config", str(path)])
    assert "train.policy_delay: missing" in str(e.value) and "eval: missing" in str(e.value)


def test_command_line_values_read_as_yaml():
    assert L.parse_override("train.lr=1e-3") == ("train.lr", 0.001)
    assert L.parse_override("train.hidden=[16,16]") == ("train.hidden", [16, 16])
    assert L.parse_override("task.curriculum.mode=off") == ("task.curriculum.mode", "off")  # not YAML 1.1's false
    assert L.parse_override("logger.run_dir=null") == ("logger.run_dir", None)
    assert L.parse_override("eval.target_success=nan")[1] != L.parse_override("eval.target_success=nan")[1]  # a float nan
    with pytest.raises(ConfigError, match="train.hidden=\\[16: not a readable value"):
        L.parse_override("train.hidden=[16")
