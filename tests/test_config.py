"""Strict configuration: from_dict/to_dict/merge, NavConfig validation, and the config
reference in docs/tasks.md matching the dataclass defaults."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import pytest
import yaml

from torchnav.config import ConfigError, TaskConfig, fields_as, from_dict, merge, to_dict
from torchnav.tasks import NavConfig
from torchnav.tasks.config import CurriculumConfig, LidarConfig, RobotConfig

DOCS = Path(__file__).resolve().parents[1] / "docs" / "tasks.md"


# --------------------------------------------------------------------------- from_dict


def test_defaults_and_partial_sections():
    cfg = NavConfig.from_dict({"map": "warehouse", "curriculum": {"growth": 0.01}})
    assert cfg.map == "warehouse" and cfg.curriculum.growth == 0.01
    assert cfg.curriculum.init_radius == CurriculumConfig().init_radius  # untouched fields keep defaults
    assert cfg.robot == RobotConfig() and NavConfig.from_dict(None) == NavConfig() == NavConfig.from_dict({})


@pytest.mark.parametrize(
    "data, key, hint",
    [
        ({"max_step": 10}, "'max_step'", "did you mean 'max_steps'"),
        ({"curriculum": {"grwth": 0.1}}, "env.curriculum: unknown key 'grwth'", "did you mean 'growth'"),
        ({"robot": {"v_maximum": 1.0}}, "env.robot: unknown key 'v_maximum'", "valid keys: dt, radius"),
        ({"lidar": {"zzz": 1}}, "env.lidar: unknown key 'zzz'", "valid keys"),
    ],
)
def test_unknown_keys_are_named(data, key, hint):
    with pytest.raises(ConfigError) as e:
        NavConfig.from_dict(data)
    assert key in str(e.value) and hint in str(e.value)
    assert isinstance(e.value, ValueError)


@pytest.mark.parametrize(
    "data, where",
    [
        ({"max_steps": "500"}, "env.max_steps: expected an integer"),
        ({"max_steps": 500.0}, "env.max_steps: expected an integer"),
        ({"max_steps": True}, "env.max_steps: expected an integer"),
        ({"goal_tolerance": "near"}, "env.goal_tolerance: expected a number"),
        ({"check_actions": 1}, "env.check_actions: expected true or false"),
        ({"map": 3}, "env.map: expected a string"),
        ({"robot": 1.0}, "env.robot: expected a mapping"),
        ({"lidar": {"offset": [0.0, 0.0]}}, "env.lidar.offset: expected 3 values"),
        ({"lidar": {"offset": 0.0}}, "env.lidar.offset: expected a list"),
        ({"action": {"discrete_set": [[1.0, 0.0], [1.0]]}}, "env.action.discrete_set[1]: expected 2 values"),
        ({"reward": {"weights": {"goal": "lots"}}}, "env.reward.weights.goal: expected a number"),
        ({"reward": {"weights": [1.0]}}, "env.reward.weights: expected a mapping"),
    ],
)
def test_wrong_types_name_the_key(data, where):
    with pytest.raises(ConfigError) as e:
        NavConfig.from_dict(data)
    assert where in str(e.value)


def test_numbers_are_coerced_sensibly():
    cfg = NavConfig.from_dict({"goal_tolerance": 1, "robot": {"lin_acc_max": "inf", "v_max": 2}})
    assert cfg.goal_tolerance == 1.0 and isinstance(cfg.goal_tolerance, float)
    assert cfg.robot.lin_acc_max == math.inf and cfg.robot.v_max == 2.0
    cfg = NavConfig.from_dict({"action": {"discrete_set": [[1, 0], [0, 1]]}, "lidar": {"offset": [0.1, 0, 0]}})
    assert cfg.action.discrete_set == ((1.0, 0.0), (0.0, 1.0)) and cfg.lidar.offset == (0.1, 0.0, 0.0)


@pytest.mark.parametrize(
    "data, msg",
    [
        ({"max_steps": 0}, "max_steps must be >= 1"),
        ({"goal_tolerance": 0.0}, "goal_tolerance must be > 0"),
        ({"curriculum": {"mode": "linear"}}, "curriculum.mode must be one of"),
        ({"curriculum": {"min_radius": 2.0, "init_radius": 1.0}}, "min_radius <= init_radius <= max_radius"),
        ({"curriculum": {"init_radius": 20.0}}, "min_radius <= init_radius <= max_radius"),
        ({"curriculum": {"growth": -0.1}}, "growth and success_step must be >= 0"),
        ({"curriculum": {"success_smoothing": 0.0}}, "success_smoothing must be in (0, 1]"),
        ({"action": {"mode": "joystick"}}, "action.mode must be one of"),
        ({"action": {"discrete_set": [[1.0, 0.0]]}}, "at least 2 actions"),
        ({"observation": {"history": 0}}, "observation.history must be >= 1"),
        ({"worlds": {"anywhere_goals": 1.2}}, "worlds.anywhere_goals must be in [0, 1], got 1.2"),
        ({"worlds": {"below_level": 2.0}}, "worlds.below_level must be in [0, 1], got 2.0"),
        ({"reset": {"candidates": 0}}, "reset.candidates must be >= 1"),
        ({"reset": {"goal_clearance": -0.1}}, "reset clearances must be >= 0"),
        ({"lidar": {"n_rays": 30, "n_sectors": 20}}, "robot/lidar: lidar.n_sectors must divide n_rays=30"),
        ({"lidar": {"max_range": 0.0}}, "robot/lidar: lidar needs 0 <= min_range < max_range"),
        ({"robot": {"dt": 0.0}}, "robot/lidar: dt must be > 0"),
        ({"robot": {"integrator": "rk4"}}, "robot/lidar"),
        ({"map": "warehouse", "worlds": {"families": {"rooms": 1.0}}}, "map: 'warehouse' is not used when worlds.families is set"),
    ],
)
def test_invalid_values_raise_config_error(data, msg):
    with pytest.raises(ConfigError) as e:
        NavConfig.from_dict(data)
    assert msg in str(e.value)


def test_config_is_frozen():
    cfg = NavConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.max_steps = 3  # type: ignore[misc]


def test_task_config_sections_default_to_their_own_defaults():
    @dataclasses.dataclass(frozen=True)
    class Toy(TaskConfig):
        steps: int = 3
        robot: RobotConfig  # a section: no default written, RobotConfig() is its default
        lidar: LidarConfig = LidarConfig(n_rays=40)  # an explicit default wins

    a, b = Toy(), Toy()
    assert a.robot == RobotConfig() and a.lidar.n_rays == 40
    assert a.robot is not b.robot  # a fresh section per config
    assert Toy.from_dict({"robot": {"dt": 0.05}}).robot.dt == 0.05
    assert NavConfig().robot == RobotConfig() and NavConfig().curriculum == CurriculumConfig()


def test_fields_as_copies_the_fields_both_dataclasses_have():
    from torchnav.sim import ImuParams, LidarParams
    from torchnav.tasks.config import ImuConfig

    imu = fields_as(ImuParams, ImuConfig(enabled=True, gyro_noise=0.1, rate=50.0))  # `enabled` is not an ImuParams field
    assert imu == ImuParams(gyro_noise=0.1, rate=50.0)
    lidar = fields_as(LidarParams, LidarConfig(n_rays=40, fov_deg=90.0, scan="sectors"), fov=math.pi / 2)  # values win
    assert (lidar.n_rays, lidar.fov, lidar.scan, lidar.n_sectors) == (40, math.pi / 2, "sectors", 20)
    assert NavConfig.from_dict({"lidar": {"fov_deg": 270.0}}).sim_params().lidar.fov == pytest.approx(1.5 * math.pi)


# --------------------------------------------------------------------------- to_dict, merge, YAML


def test_to_dict_round_trips_through_yaml():
    cfg = NavConfig.from_dict({"map": "street", "reward": {"preset": "shaped", "weights": {"step": -0.02}}, "lidar": {"offset": [0.1, 0.0, 0.0]}})
    text = yaml.safe_dump(to_dict(cfg))
    assert NavConfig.from_dict(yaml.safe_load(text)) == cfg
    assert to_dict(NavConfig())["robot"]["lin_acc_max"] == math.inf


def test_merge_is_recursive_and_leaves_inputs_alone():
    base = {"a": 1, "s": {"x": 1, "y": 2}, "w": {"k": 1}}
    over = {"s": {"y": 3}, "w": 5, "n": {"z": 0}}
    out = merge(base, over)
    assert out == {"a": 1, "s": {"x": 1, "y": 3}, "w": 5, "n": {"z": 0}}
    assert base == {"a": 1, "s": {"x": 1, "y": 2}, "w": {"k": 1}}


def test_from_dict_on_any_dataclass():
    cfg = from_dict(LidarConfig, {"n_rays": 40}, where="lidar")
    assert cfg.n_rays == 40 and cfg.n_sectors == 20
    with pytest.raises(ConfigError, match="lidar: unknown key 'rays'"):
        from_dict(LidarConfig, {"rays": 40}, where="lidar")


# --------------------------------------------------------------------------- docs/tasks.md matches the code


def _doc_defaults() -> dict[str, str]:
    """``{dotted.key: default}`` from the config tables of docs/tasks.md (first column in backticks,
    default in the 4th column)."""
    rows = {}
    for line in DOCS.read_text().splitlines():
        m = re.match(r"^\|\s*`([a-z_]+(?:\.[a-z_]+)?)`\s*\|([^|]*)\|([^|]*)\|([^|]*)\|", line)
        if m:
            rows[m.group(1)] = m.group(4).strip().strip("`")
    return rows


def _fields(cls, prefix=""):
    for f in dataclasses.fields(cls):
        value = getattr(cls(), f.name)
        if dataclasses.is_dataclass(value):
            yield from _fields(type(value), f"{f.name}.")
        else:
            yield prefix + f.name, value


def test_docs_list_every_config_field_with_its_default():
    docs = _doc_defaults()
    fields = dict(_fields(NavConfig))
    missing = [k for k in fields if k not in docs]
    assert not missing, f"docs/tasks.md does not document {missing}"
    for key, value in fields.items():
        doc = docs[key]
        if isinstance(value, bool) or isinstance(value, str):
            assert doc == (str(value).lower() if isinstance(value, bool) else value) or doc == f'"{value}"', (key, doc)
        elif isinstance(value, (int, float)):
            expected = "inf" if value == math.inf else repr(value)
            assert doc in (expected, str(value)), (key, doc, value)
        elif value is None:  # optional ranges (randomize), off by default
            assert doc == "null", (key, doc)
        elif key in ("reward.weights", "worlds.families", "worlds.movers"):  # dicts, empty by default
            assert doc == "{}", (key, doc)
        elif key == "action.discrete_set":
            assert f"{len(value)} actions" in doc, (key, doc)
            listed = ", ".join(f"({v:g}, {w:g})" for v, w in value)
            assert f"`{listed}`" in DOCS.read_text(), listed
        else:
            assert doc == str(list(value)).replace(" ", "") or doc == str(list(value)), (key, doc, value)
