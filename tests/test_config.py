"""The config schema: from_dict/to_dict/merge, validation (every problem at once), each default
declared once, the simulator's parameters derived from the task config, and the config reference
in docs/tasks.md matching the dataclass defaults."""

from __future__ import annotations

import dataclasses
import math
import re
import typing
from pathlib import Path

import pytest
import yaml

from torchnav.config import Checked, Config, ConfigError, from_dict, merge, to_dict
from torchnav.tasks import LineConfig, NavConfig
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
        ({"robot": {"v_maximum": 1.0}}, "env.robot: unknown key 'v_maximum'", "valid keys: preset, dt, radius"),
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
        ({"max_steps": "500"}, "env.max_steps='500': must be an integer >= 1"),
        ({"max_steps": 500.0}, "env.max_steps=500.0: must be an integer >= 1"),
        ({"max_steps": True}, "env.max_steps=True: must be an integer >= 1"),
        ({"goal_tolerance": "near"}, "env.goal_tolerance='near': must be a finite number > 0"),
        ({"check_actions": 1}, "env.check_actions: expected true or false"),
        ({"map": 3}, "env.map: expected a string"),
        ({"robot": 1.0}, "env.robot: expected a mapping"),
        ({"lidar": {"offset": [0.0, 0.0]}}, "env.lidar.offset=[0.0, 0.0]: must be (x m, y m, yaw rad)"),
        ({"lidar": {"offset": 0.0}}, "env.lidar.offset=0.0: must be (x m, y m, yaw rad)"),
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
        ({"max_steps": 0}, "env.max_steps=0: must be an integer >= 1"),
        ({"goal_tolerance": 0.0}, "env.goal_tolerance=0.0: must be a finite number > 0"),
        ({"curriculum": {"mode": "linear"}}, "env.curriculum.mode='linear': must be growth or success or off"),
        ({"curriculum": {"min_radius": 2.0, "init_radius": 1.0}}, "min_radius <= init_radius <= max_radius"),
        ({"curriculum": {"init_radius": 20.0}}, "min_radius <= init_radius <= max_radius"),
        ({"curriculum": {"growth": -0.1}}, "env.curriculum.growth=-0.1: must be a finite number >= 0"),
        ({"curriculum": {"success_step": -1.0}}, "env.curriculum.success_step=-1.0: must be a finite number >= 0"),
        ({"curriculum": {"success_smoothing": 0.0}}, "env.curriculum.success_smoothing=0.0: must be a number in (0, 1]"),
        ({"action": {"mode": "joystick"}}, "env.action.mode='joystick': must be continuous or discrete"),
        ({"action": {"discrete_set": [[1.0, 0.0]]}}, "env.action.discrete_set needs at least 2 actions"),
        ({"observation": {"history": 0}}, "env.observation.history=0: must be an integer in [1, 64]"),
        ({"worlds": {"anywhere_goals": 1.2}}, "env.worlds.anywhere_goals=1.2: must be a number in [0, 1]"),
        ({"worlds": {"below_level": 2.0}}, "env.worlds.below_level=2.0: must be a number in [0, 1]"),
        ({"reset": {"candidates": 0}}, "env.reset.candidates=0: must be an integer >= 1"),
        ({"reset": {"goal_clearance": -0.1}}, "env.reset.goal_clearance=-0.1: must be a finite number >= 0"),
        ({"reset": {"start_clearance": -0.1}}, "env.reset.start_clearance=-0.1: must be a finite number >= 0"),
        ({"lidar": {"n_rays": 30, "n_sectors": 20}}, "env.lidar.n_sectors=20 must divide n_rays=30"),
        ({"lidar": {"max_range": 0.0}}, "env.lidar.max_range=0.0: must be a number of m in (0, 10000]"),
        ({"lidar": {"min_range": 5.0, "max_range": 4.0}}, "env.lidar.max_range=4.0 must be greater than min_range=5.0"),
        ({"lidar": {"fov_deg": 400.0}}, "env.lidar.fov_deg=400.0: must be a number of degrees in (0, 360]"),
        ({"robot": {"dt": 0.0}}, "env.robot.dt=0.0: must be a finite number > 0"),
        ({"robot": {"integrator": "rk4"}}, "env.robot.integrator='rk4': must be euler or exact"),
        ({"imu": {"rate": 0.0}}, "env.imu.rate=0.0: must be a number > 0 (inf: no limit)"),
        ({"camera": {"fov_deg": 180.0}}, "env.camera.fov_deg=180.0: must be a number of degrees in (0, 180)"),
        ({"map": "warehouse", "worlds": {"families": {"rooms": 1.0}}}, "env.map: 'warehouse' is not used when worlds.families is set"),
    ],
)
def test_invalid_values_raise_config_error(data, msg):
    with pytest.raises(ConfigError) as e:
        NavConfig.from_dict(data)
    assert msg in str(e.value)


def test_every_problem_is_reported_at_once():
    """Unknown keys, wrong types, refused values and broken relations of every section, in one error."""
    with pytest.raises(ConfigError) as e:
        NavConfig.from_dict({"max_steps": 0, "robot": {"dt": 0.0, "v_maximum": 1.0}, "lidar": {"n_rays": 30, "n_sectors": 20},
                             "curriculum": {"grwth": 0.1}, "reward": {"geodesic_margin": "wide"}})
    msg = str(e.value)
    for want in ("env.max_steps=0: must be an integer >= 1", "env.robot: unknown key 'v_maximum'", "env.robot.dt=0.0: must be",
                 "env.lidar.n_sectors=20 must divide n_rays=30", "env.curriculum: unknown key 'grwth' (did you mean 'growth'?)",
                 "env.reward.geodesic_margin='wide': must be a finite number >= 0"):
        assert want in msg, (want, msg)
    assert msg.startswith("invalid config:") and len(e.value.problems) == 6
    with pytest.raises(ConfigError) as e:
        LineConfig.from_dict({"max_steps": 0, "sensors": {"mode": "digital"}, "termination": {"max_path_distance": 0.0}})
    assert sorted(p.split(":")[0] for p in e.value.problems) == ["env.max_steps=0", "env.sensors.mode='digital'", "env.termination.max_path_distance=0.0"]


def test_a_config_checks_itself_on_construction():
    """Direct construction validates like from_dict: each refused field, named, in one ConfigError (a ValueError)."""
    from torchnav.sim import LidarParams

    with pytest.raises(ConfigError) as e:
        RobotConfig(dt=-1.0, radius=0.0)
    assert e.value.problems == ["dt=-1.0: must be a finite number > 0", "radius=0.0: must be a finite number > 0"]
    with pytest.raises(ValueError, match="n_rays=0: must be an integer >= 1"):
        LidarParams(n_rays=0, fov=math.pi, min_range=0.0, max_range=10.0, offset=(0.0, 0.0, 0.0), noise_std=0.0, scan="rays",
                    window=2, dense_slots=64)
    with pytest.raises(TypeError, match="missing"):  # the simulator's robot and lidar have no defaults: a task config has them
        LidarParams(n_rays=20)


def test_config_is_frozen():
    cfg = NavConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.max_steps = 3  # type: ignore[misc]


def test_task_config_sections_default_to_their_own_defaults():
    @dataclasses.dataclass(frozen=True)
    class Toy(Config):
        steps: int = 3
        robot: RobotConfig  # a section: no default written, RobotConfig() is its default
        lidar: LidarConfig = LidarConfig(n_rays=40)  # an explicit default wins

    a, b = Toy(), Toy()
    assert a.robot == RobotConfig() and a.lidar.n_rays == 40
    assert a.robot is not b.robot  # a fresh section per config
    assert Toy.from_dict({"robot": {"dt": 0.05}}).robot.dt == 0.05
    assert NavConfig().robot == RobotConfig() and NavConfig().curriculum == CurriculumConfig()


def test_sim_params_are_built_from_the_task_config():
    from torchnav.sim import CameraParams, ImuParams
    from torchnav.sim.floor import FloorSensorParams

    cfg = NavConfig.from_dict({"robot": {"radius": 0.25, "v_max": 0.7}, "action": {"forward_only": False},
                               "lidar": {"fov_deg": 270.0, "n_rays": 40, "scan": "sectors"},
                               "imu": {"enabled": True, "gyro_noise": 0.1, "rate": 50.0}, "camera": {"enabled": True, "fov_deg": 60.0}})
    p = cfg.sim_params()
    assert (p.robot_radius, p.v_min, p.v_max) == (0.25, -0.7, 0.7)
    assert (p.lidar.n_rays, p.lidar.fov, p.lidar.scan) == (40, pytest.approx(1.5 * math.pi), "sectors")
    assert p.imu == ImuParams(gyro_noise=0.1, rate=50.0) and type(p.imu) is ImuParams  # `enabled` is not an ImuParams field
    assert isinstance(p.camera, CameraParams) and p.camera.fov == pytest.approx(math.pi / 3)
    plain = NavConfig().sim_params()
    assert plain.v_min == 0.0 and plain.imu is None and plain.camera is None
    line = LineConfig.from_dict({"sensors": {"count": 3}, "robot": {"wheel_speed_max": 0.4}})
    assert line.sensor_params() == FloorSensorParams(count=3) and line.sim_params().omega_max == pytest.approx(2 * 0.4 / 0.12)


# --------------------------------------------------------------------------- each default declared once

# Which task sections become which simulator parameters (NavConfig.sim_params, LineConfig.sim_params),
# and the fields they rename: (task section, simulator class, {task field: simulator field}).
BUILT_INTO = [
    ("torchnav.tasks.config.RobotConfig", "torchnav.sim.params.SimParams", {"radius": "robot_radius"}),
    ("torchnav.tasks.config.LidarConfig", "torchnav.sim.params.LidarParams", {"fov_deg": "fov"}),
    ("torchnav.tasks.config.CameraConfig", "torchnav.sim.params.CameraParams", {"fov_deg": "fov"}),
    ("torchnav.tasks.line_config.LineRobotConfig", "torchnav.sim.params.SimParams", {"radius": "robot_radius", "wheel_speed_max": "v_max"}),
    ("torchnav.tasks.line_config.DistanceSensorConfig", "torchnav.sim.params.LidarParams", {"forward": "offset"}),
]


def _config_classes() -> list[type]:
    """Every config dataclass of torchnav: the subclasses of ``Checked`` (the base of every config)
    defined in torchnav: the simulator's parameters, the task configs and their sections, the recipes' configs."""
    import torchnav.sim  # noqa: F401
    import torchnav.tasks  # noqa: F401
    import torchnav.train_config  # noqa: F401

    out, todo = [], list(Checked.__subclasses__())
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        if cls.__module__.startswith("torchnav.") and dataclasses.is_dataclass(cls) and cls not in out:
            out.append(cls)
    return out


def _name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def _has_default(f: dataclasses.Field) -> bool:
    return f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING


def test_no_two_config_classes_declare_the_same_default():
    """Each parameter's default is declared in exactly one class.

    Two fields are the same parameter when they have the same name, or names the table
    ``BUILT_INTO`` pairs, in two classes that map onto each other:

    * a task section and the simulator class ``sim_params()`` builds from it (``BUILT_INTO``): the
      simulator class must have no default for any field the task section declares;
    * a class and its bases: a subclass must not declare a base's field again, except to narrow a
      section to a subclass of its class (``task: NavConfig`` in ``NavRecipe``), which declares no
      parameter.

    Fields of the same name in classes that do not map onto each other are different parameters:
    the alternatives for one section (``TD3Train.gamma`` and ``PPOTrain.gamma``: a recipe has one
    train class; ``NavConfig.max_steps`` and ``LineConfig.max_steps``: a recipe has one task) and
    unrelated sections (``eval.interval_frames`` and ``checkpoint.interval_frames``).
    """
    classes = {_name(c): c for c in _config_classes()}
    assert len(classes) > 40 and "torchnav.train_config.TD3Train" in classes and "torchnav.sim.params.SimParams" in classes
    for task_name, sim_name, renamed in BUILT_INTO:
        task, sim = classes[task_name], classes[sim_name]
        sim_fields = {f.name: f for f in dataclasses.fields(sim)}
        assert set(renamed) <= {f.name for f in dataclasses.fields(task)} and set(renamed.values()) <= set(sim_fields), renamed
        for f in dataclasses.fields(task):
            s = sim_fields.get(renamed.get(f.name, f.name))
            assert s is None or not _has_default(s), f"{task_name}.{f.name} and {sim_name}.{s.name} both declare a default"
    for cls in classes.values():
        hints = typing.get_type_hints(cls)
        for base in cls.__mro__[1:]:
            if not dataclasses.is_dataclass(base):
                continue
            base_hints = typing.get_type_hints(base)
            for name in set(cls.__dict__.get("__annotations__", {})) & {f.name for f in dataclasses.fields(base)}:
                allowed = [t for t in typing.get_args(base_hints[name]) or (base_hints[name],) if isinstance(t, type)]
                assert dataclasses.is_dataclass(hints[name]) and any(issubclass(hints[name], t) for t in allowed), \
                    f"{_name(cls)}.{name} declares the field of {_name(base)} again"


def test_every_simulator_parameter_class_takes_its_defaults_from_a_task():
    """A simulator parameter class is either built from a task section (``BUILT_INTO``: it has no
    default of its own for what the section declares) or is itself a task's section (``ImuParams``
    under ``ImuConfig``, ``FloorSensorParams`` as ``LineConfig.sensors``), so its defaults are the task's."""
    sections = set()

    def walk(cls):
        for f in dataclasses.fields(cls):
            tp = typing.get_type_hints(cls)[f.name]
            if dataclasses.is_dataclass(tp):
                sections.update(tp.__mro__)
                walk(tp)

    walk(NavConfig)
    walk(LineConfig)
    built = {sim for _, sim, _ in BUILT_INTO}
    sim_classes = [c for c in _config_classes() if c.__module__.startswith("torchnav.sim.")]
    assert len(sim_classes) == 5
    for cls in sim_classes:
        assert _name(cls) in built or cls in sections, f"{_name(cls)}: neither built from a task section nor one"


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


def test_robot_presets_fill_the_robot_under_the_keys_given_and_round_trip():
    from torchnav.envs import make_nav_env
    from torchnav.tasks.robots import ROBOT_PRESETS

    for name, (values, delay) in ROBOT_PRESETS.items():
        cfg = NavConfig.from_dict({"robot": {"preset": name}})
        assert all(getattr(cfg.robot, k) == v for k, v in values.items()), name
        assert cfg.randomize.delay == ((delay, delay) if delay else None), name
        assert NavConfig.from_dict(to_dict(cfg)) == cfg  # a saved config builds the same robot again
        env = make_nav_env("arena", num_envs=2, robot={"preset": name})
        assert env.task.params.robot_radius == cfg.robot.radius and env.task.delay_steps == delay
        env.rollout(3)
    given = NavConfig.from_dict({"robot": {"preset": "jackal", "v_max": 1.5}, "randomize": {"delay": [0, 2]}})
    assert given.robot.v_max == 1.5 and given.robot.omega_max == 4.0 and given.randomize.delay == (0, 2)
    assert NavConfig.from_dict({"robot": {"preset": "default"}}) == NavConfig()
    with pytest.raises(ConfigError, match=r"env.robot.preset='tb3'.*turtlebot3_burger"):
        NavConfig.from_dict({"robot": {"preset": "tb3"}})


def test_a_recipe_override_chooses_a_robot_preset():
    from torchnav.train_config import load_config

    recipe = load_config("td3_lidar", ["task.robot.preset=turtlebot3_burger"], Path(__file__).resolve().parent.parent / "recipes" / "configs")
    assert recipe.task.robot.v_max == 0.22 and recipe.task.robot.radius == 0.105 and recipe.task.randomize.delay == (1, 1)
    # a preset on the command line replaces the file's body (the generalist's file sets omega_max: 2.0) ...
    generalist = ["--config", str(Path(__file__).resolve().parent.parent / "recipes" / "configs" / "ppo_generalist.yaml")]
    assert load_config("ppo_lidar", generalist).task.robot.omega_max == 2.0
    assert load_config("ppo_lidar", generalist + ["task.robot.preset=jackal"]).task.robot.omega_max == 4.0
    # ... and robot keys given beside it on the command line, in either order, win over the preset
    for argv in (["task.robot.omega_max=3.0", "task.robot.preset=jackal"], ["task.robot.preset=jackal", "task.robot.omega_max=3.0"]):
        robot = load_config("ppo_lidar", generalist + argv).task.robot
        assert (robot.omega_max, robot.v_max, robot.radius) == (3.0, 2.0, 0.267)


def test_a_preset_over_a_saved_config_replaces_its_body():
    """A saved config (a checkpoint's) holds every robot key; override_config lets a preset laid over
    it change the body, keeps the keys given beside it and what is not the body (dt, randomize)."""
    from torchnav.tasks.robots import BODY_KEYS, ROBOT_PRESETS, override_config

    saved = to_dict(NavConfig.from_dict({"robot": {"omega_max": 2.0, "dt": 0.05}, "randomize": {"dropout": [0.0, 0.1]}}))
    jackal = NavConfig.from_dict(override_config(saved, {"robot": {"preset": "jackal"}}))
    assert all(getattr(jackal.robot, k) == ROBOT_PRESETS["jackal"][0][k] for k in BODY_KEYS)
    assert jackal.robot.dt == 0.05 and jackal.randomize.dropout == (0.0, 0.1) and jackal.randomize.delay == (1, 1)
    given = NavConfig.from_dict(override_config(saved, {"robot": {"preset": "jackal", "v_max": 1.0}, "max_steps": 99}))
    assert (given.robot.v_max, given.robot.omega_max, given.max_steps) == (1.0, 4.0, 99)
    assert NavConfig.from_dict(override_config(saved, {"robot": {"preset": "default"}})).robot.omega_max == 1.0
    assert NavConfig.from_dict(override_config(saved, {"robot": {"v_max": 0.5}})).robot.omega_max == 2.0  # no preset: a merge
