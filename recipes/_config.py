"""The recipes' configs: one frozen dataclass per recipe, one YAML file per recipe, the same keys.

``configs/<recipe>.yaml`` maps one to one onto :data:`RECIPES`\\ ``[recipe]``: each top-level key
is a field, each section a class. ``task`` is the task's own config (``NavConfig`` or
``LineConfig``, their defaults filling what the file leaves out); ``env`` is how many copies of it
run; ``train`` is the algorithm's class (:class:`TD3Train`, :class:`SACTrain`, :class:`PPOTrain`,
:class:`DQNTrain`, :class:`APGTrain`). Every other field has no default: the YAML file sets it,
and the range the field allows is declared with it (``checked``). ``from_dict`` checks every
value (type, range, finiteness, unknown or missing keys), then each class's ``__post_init__`` the
relations between keys and the machine (``device``); all problems come back in one ConfigError
that names each key, its value and what is allowed, before any run directory exists.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import importlib.util
import re
import sys
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import yaml

from torchnav.config import ConfigError, checked, from_dict, is_int, is_number, raise_problems, to_dict
from torchnav.tasks import LineConfig, NavConfig

CONFIG_DIR = Path(__file__).resolve().parent / "configs"


# --------------------------------------------------------------------------- what a field allows


def count(lo: int) -> Any:
    return checked(lambda v: is_int(v) and v >= lo, f"an integer >= {lo}")


def positive() -> Any:
    return checked(lambda v: is_number(v) and v > 0, "a finite number > 0")


def non_negative() -> Any:
    return checked(lambda v: is_number(v) and v >= 0, "a finite number >= 0")


def discount() -> Any:
    return checked(lambda v: is_number(v) and 0 < v <= 1, "a number in (0, 1]")


def probability() -> Any:
    return checked(lambda v: is_number(v) and 0 <= v <= 1, "a number in [0, 1]")


def real() -> Any:
    return checked(is_number, "a float")


def flag() -> Any:
    return checked(lambda v: isinstance(v, bool), "true or false")


def one_of(*options: str) -> Any:
    return checked(lambda v: v in options, " or ".join(options))


def sizes() -> Any:
    return checked(lambda v: isinstance(v, (list, tuple)) and len(v) > 0 and all(is_int(h) and h >= 1 for h in v),
                   "a non-empty list of integers >= 1")


# logger.backend -> the package it needs beyond the core install (and the extra that brings it)
LOGGER_BACKENDS = {"csv": None, "tensorboard": "tensorboard", "wandb": "wandb"}


def check_backend(backend: str) -> None:
    """Refuse an unknown ``logger.backend``, or one whose package is not installed."""
    if backend not in LOGGER_BACKENDS:
        raise ConfigError(f"logger.backend must be one of {sorted(LOGGER_BACKENDS)}, got {backend!r}")
    package = LOGGER_BACKENDS[backend]
    if package and importlib.util.find_spec(package) is None:
        raise ConfigError(f"logger.backend={backend} needs the {package} package: pip install -e '.[{backend}]'")


def check_threads(setting: Any) -> None:
    if setting not in ("auto", None) and not (is_int(setting) and setting >= 1):
        raise ConfigError(f"threads must be 'auto' or an int >= 1, got {setting!r}")


# --------------------------------------------------------------------------- sections


@dataclass(frozen=True)
class EnvConfig:
    """``env``: the batch of tasks (the task itself is ``task``)."""

    num_envs: int = count(1)  # envs stepped side by side


@dataclass(frozen=True)
class NavEnvConfig(EnvConfig):
    compile_step: bool = flag()  # run the simulator step through torch.compile


@dataclass(frozen=True)
class EvalConfig:
    interval_frames: int = count(0)  # periodic evaluation every this many frames (0: never)
    episodes: int = count(1)  # episodes per periodic evaluation
    final_episodes: int = count(1)  # episodes of the final evaluation
    target_success: float = probability()  # the summary reports when periodic evaluation first reached this
    record_episodes: int = count(0)  # final-evaluation episodes written to <run>/episodes.mcap


@dataclass(frozen=True)
class LineEvalConfig(EvalConfig):
    laps: int = count(1)  # an episode succeeds when it completes this many laps


@dataclass(frozen=True)
class LoggerConfig:
    backend: str  # csv | tensorboard | wandb (LOGGER_BACKENDS)
    root: str  # parent of run directories
    run_dir: str | None  # explicit run directory (None: <root>/<recipe>_<time>_seed<seed>)
    progress: bool = flag()  # tqdm progress bar

    def __post_init__(self) -> None:
        check_backend(self.backend)


@dataclass(frozen=True)
class CheckpointConfig:
    interval_frames: int = count(1)  # write <run>/checkpoint.pt every this many frames
    resume: bool | str  # true: the newest run; or a run directory


@dataclass(frozen=True)
class SmoothConfig:
    """``smooth`` (APG): differentiable terms in place of the task's terminal events (``torchnav.apg``)."""

    ramp_frames: int = count(0)  # their weight grows linearly from 0 over this many frames


@dataclass(frozen=True)
class NavSmoothConfig(SmoothConfig):
    contact: float = real()  # weight of relu(1 - clearance / contact_margin)
    contact_margin: float = positive()  # m


@dataclass(frozen=True)
class LineSmoothConfig(SmoothConfig):
    path: float = real()  # weight of (distance from the lap path / termination.max_path_distance)^2


# --------------------------------------------------------------------------- train, per algorithm


@dataclass(frozen=True)
class Train:
    total_frames: int = count(1)  # env steps over all envs
    gamma: float = discount()
    hidden: tuple[int, ...] = sizes()  # MLP hidden sizes


@dataclass(frozen=True)
class TwoRates:
    lr_actor: float = positive()
    lr_critic: float = positive()


@dataclass(frozen=True)
class Annealed:
    expl_sigma_init: float = non_negative()  # exploration noise std at the start ...
    expl_sigma_end: float = non_negative()  # ... annealed linearly to this
    expl_anneal_frames: int = count(0)  # ... over this many frames


@dataclass(frozen=True)
class Collected(Train):
    frames_per_batch: int = count(1)  # env steps per batch (a multiple of env.num_envs)


@dataclass(frozen=True)
class Replay(Collected):
    init_random_frames: int = count(0)  # random actions first; updates start once the buffer holds this many
    updates_per_batch: int = count(1)
    batch_size: int = count(1)  # transitions per gradient step (at most buffer_size)
    buffer_size: int = count(1)
    tau: float = discount()  # target-network soft-update rate


@dataclass(frozen=True)
class TD3Train(Annealed, TwoRates, Replay):
    policy_delay: int = count(1)
    policy_noise: float = non_negative()
    noise_clip: float = non_negative()


@dataclass(frozen=True)
class SACTrain(TwoRates, Replay):
    lr_alpha: float = positive()
    alpha_init: float = positive()


@dataclass(frozen=True)
class Discrete:
    """What DQN and PPO share: one learning rate, a gradient clip, observation statistics, an activation."""

    lr: float = positive()
    max_grad_norm: float = positive()
    obs_stats_steps: int = count(0)  # random-action steps (x num_envs) that estimate the observation normalisation
    activation: str = one_of("relu", "tanh")


@dataclass(frozen=True)
class DQNTrain(Discrete, Replay):
    eps_init: float = probability()
    eps_end: float = probability()
    eps_anneal_frames: int = count(0)


@dataclass(frozen=True)
class PPOTrain(Discrete, Collected):
    epochs: int = count(1)
    minibatch_size: int = count(1)  # at most frames_per_batch
    lmbda: float = probability()
    clip_epsilon: float = positive()
    entropy_coeff: float = non_negative()
    critic_coeff: float = non_negative()
    init_log_std: float = real()


@dataclass(frozen=True)
class APGTrain(Annealed, TwoRates, Train):
    horizon: int = count(1)
    lr_decay: bool = flag()
    lmbda: float = probability()
    tau: float = discount()
    critic_epochs: int = count(1)
    minibatch_size: int = count(1)
    max_grad_norm: float = positive()
    skip_grad_norm: float = positive()
    action_reg: float = non_negative()
    activation: str = one_of("relu", "tanh")


# --------------------------------------------------------------------------- recipes


@dataclass(frozen=True)
class Recipe:
    """A recipe's whole config; each subclass names its task and algorithm."""

    seed: int = count(0)
    device: str = checked(lambda v: isinstance(v, str) and re.fullmatch(r"cpu|cuda(:\d+)?", v) is not None, "cpu, cuda or cuda:N")
    threads: int | str  # 'auto' or a fixed number (ThreadGovernor)
    env: EnvConfig
    task: NavConfig | LineConfig
    train: Train
    eval: EvalConfig
    logger: LoggerConfig
    checkpoint: CheckpointConfig

    def value(self, key: str) -> Any:
        """The value of a dotted key (None where the recipe has no such key)."""
        obj: Any = self
        for part in key.split("."):
            obj = getattr(obj, part, None)
        return obj

    def __post_init__(self) -> None:
        problems = []
        try:
            check_threads(self.threads)
        except ConfigError as e:
            problems.append(str(e))
        fpb, n = self.value("train.frames_per_batch"), self.env.num_envs
        if fpb is not None and fpb % n:
            problems.append(f"train.frames_per_batch={fpb} must be a multiple of env.num_envs={n}")
        for small, big in (("train.minibatch_size", "train.frames_per_batch"), ("train.batch_size", "train.buffer_size"),
                           ("eval.record_episodes", "eval.final_episodes")):
            a, b = self.value(small), self.value(big)
            if a is not None and b is not None and a > b:
                problems.append(f"{small}={a} must be at most {big}={b}")
        if self.device.startswith("cuda"):
            have = torch.cuda.device_count() if torch.cuda.is_available() else 0
            if (int(self.device.split(":")[1]) if ":" in self.device else 0) >= have:
                problems.append(f"device={self.device!r}: this machine has {have} CUDA device(s)"
                                f"{'' if have else ' (torch ' + torch.__version__ + ')'}; use device=cpu")
        raise_problems(problems)


@dataclass(frozen=True)
class NavRecipe(Recipe):
    env: NavEnvConfig
    task: NavConfig


@dataclass(frozen=True)
class LineRecipe(Recipe):
    task: LineConfig
    eval: LineEvalConfig


def _recipe(name: str, base: type[Recipe], train: type[Train], smooth: type[SmoothConfig] | None = None) -> type[Recipe]:
    """``base`` with its algorithm's ``train`` class (and APG's ``smooth`` section)."""
    fields = [("train", train)] + ([("smooth", smooth)] if smooth else [])
    return dataclasses.make_dataclass(name, fields, bases=(base,), frozen=True, namespace={"__module__": __name__})


# recipe (recipes/<name>.py, configs/<name>.yaml) -> its config class
RECIPES: dict[str, type[Recipe]] = {
    "td3_lidar": _recipe("TD3Lidar", NavRecipe, TD3Train),
    "sac_lidar": _recipe("SACLidar", NavRecipe, SACTrain),
    "ppo_lidar": _recipe("PPOLidar", NavRecipe, PPOTrain),
    "apg_lidar": _recipe("APGLidar", NavRecipe, APGTrain, NavSmoothConfig),
    "ppo_line": _recipe("PPOLine", LineRecipe, PPOTrain),
    "dqn_line": _recipe("DQNLine", LineRecipe, DQNTrain),
    "apg_line": _recipe("APGLine", LineRecipe, APGTrain, LineSmoothConfig),
}


# --------------------------------------------------------------------------- files and command lines

# Keys of the layout before the task section became the task's own config: old key -> new key.
MOVED = {"env.map": "task.map", "env.max_steps": "task.max_steps", "env.goal_tolerance": "task.goal_tolerance",
         "env.track": "task.track", "curriculum": "task.curriculum", "reward": "task.reward"}


def moved(key: str) -> str | None:
    """The new name of a key of the old layout (None for any other key)."""
    for old, new in MOVED.items():
        if key == old or key.startswith(old + "."):
            return new + key[len(old):]
    return None


def _moved_in(data: dict[str, Any]) -> list[str]:
    """The old-layout keys (``MOVED``) present in a config as nested dicts."""
    return [old for old in MOVED if _lookup(data, old) is not _ABSENT]


_ABSENT = object()


def _lookup(data: Any, key: str) -> Any:
    for part in key.split("."):
        if not isinstance(data, dict) or part not in data:
            return _ABSENT
        data = data[part]
    return data


def _put(cls: type, data: dict[str, Any], key: str, value: Any) -> None:
    """Set dotted ``key`` of ``data`` (a config of class ``cls`` as nested dicts), after checking that
    each part of it names a field: an unknown key is a ConfigError naming it and the closest valid one."""
    tp: Any = cls
    parts = key.split(".")
    for i, part in enumerate(parts):
        if dataclasses.is_dataclass(tp):
            names = [f.name for f in dataclasses.fields(tp)]
            if part not in names:
                where = ".".join(parts[:i])
                close = difflib.get_close_matches(part, names, n=1)
                hint = f" (did you mean '{where + '.' if where else ''}{close[0]}'?)" if close else ""
                raise ConfigError(f"unknown config key '{key}'{hint}; valid keys{' of ' + where if where else ''}: {', '.join(names)}")
            tp = typing.get_type_hints(tp)[part]
        else:
            tp = None  # inside a mapping-valued field (task.reward.weights, task.worlds.families): any key
        if i == len(parts) - 1:
            data[part] = value
        else:
            if not isinstance(data.get(part), dict):
                data[part] = {}
            data = data[part]


class _Values(yaml.SafeLoader):
    """Command-line values read as YAML, with 1e-3, nan and inf as floats and only true/false as booleans."""


_Values.yaml_implicit_resolvers = {c: [r for r in rs if r[0] != "tag:yaml.org,2002:bool"] for c, rs in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Values.add_implicit_resolver("tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF"))
_Values.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(r"^[-+]?(?:(?:\d+\.?\d*|\.\d+)[eE][-+]?\d+|nan|inf)$", re.I),
                              list("-+0123456789.nNiI"))


def parse_override(text: str) -> tuple[str, Any]:
    """``key.sub=value`` as ``(key, value)``, the value read as YAML (``[16,16]`` a list, ``null`` None)."""
    key, _, raw = text.partition("=")
    try:
        return key, yaml.load(raw, Loader=_Values)  # noqa: S506 - a SafeLoader
    except yaml.YAMLError as e:
        raise ConfigError(f"{key}={raw}: not a readable value ({str(e).splitlines()[0]})") from None


def parse_cli(name: str, argv: list[str]) -> tuple[Path, list[str]]:
    """The config file and the ``key.sub=value`` overrides of a recipe's command line.

    ``--config PATH`` replaces ``configs/<name>.yaml``; ``--resume [RUN_DIR]`` sets
    ``checkpoint.resume``; ``-h`` prints the usage and exits.
    """
    path = CONFIG_DIR / f"{name}.yaml"
    overrides: list[str] = []
    it = iter(argv)
    for a in it:
        if a in ("-h", "--help"):
            print(f"usage: python recipes/{name}.py [--config FILE] [--resume[=RUN_DIR]] [key.sub=value ...]\n"
                  f"defaults and documentation of every key: {path}")
            sys.exit(0)
        if a == "--config":
            path = Path(next(it, ""))
        elif a.startswith("--config="):
            path = Path(a.split("=", 1)[1])
        elif a == "--resume":
            overrides.append("checkpoint.resume=true")
        elif a.startswith("--resume="):
            overrides.append(f"checkpoint.resume={a.split('=', 1)[1]}")
        elif "=" in a and not a.startswith("-"):
            overrides.append(a)
        else:
            raise ConfigError(f"unrecognised argument {a!r}: expected key=value, --config FILE or --resume")
    return path, overrides


def build(name: str, data: dict[str, Any], overrides: list[str], source: str, run_dir: Path | None = None) -> Recipe:
    """Recipe ``name``'s config from ``data`` (a config file's content) and dotted ``overrides``,
    every value validated; ``run_dir`` sets ``logger.run_dir`` (a resumed run's directory)."""
    cls = RECIPES.get(name)
    if cls is None:
        raise ConfigError(f"unknown recipe {name!r}; recipes: {', '.join(RECIPES)}")
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of config sections, got {type(data).__name__}")
    old = _moved_in(data)
    if old:
        raise ConfigError(f"{source}: " + "; ".join(f"{k} is now {MOVED[k]}" for k in old)
                          + " (the task section is the task's NavConfig or LineConfig: docs/training.md#configuration)")
    data = copy.deepcopy(data)
    for text in overrides:
        key, value = parse_override(text)
        if (new := moved(key)) is not None:
            raise ConfigError(f"{key} is now {new} (the task section is the task's NavConfig or LineConfig: docs/training.md#configuration)")
        _put(cls, data, key, value)
    if run_dir is not None:
        _put(cls, data, "logger.run_dir", str(run_dir))
    return from_dict(cls, data, where="")


def load_config(name: str, argv: list[str]) -> Recipe:
    """``configs/<name>.yaml`` (or ``--config FILE``) with the command line's overrides, validated."""
    path, overrides = parse_cli(name, argv)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    return build(name, yaml.safe_load(path.read_text()) or {}, overrides, str(path))


def migrated(saved: dict[str, Any]) -> dict[str, Any]:
    """A config saved by an older torchnav (``env.map``, ``curriculum``, ...) in the current layout."""
    saved = copy.deepcopy(saved)
    for old in _moved_in(saved):
        *parents, leaf = old.split(".")
        node = saved
        for p in parents:
            node = node[p]
        *new_parents, new_leaf = MOVED[old].split(".")
        dest = saved
        for p in new_parents:
            dest = dest.setdefault(p, {})
        dest[new_leaf] = node.pop(leaf)
    return saved


# What a resumed run may change from the config it was started with: its length, evaluation,
# logging, checkpoint cadence, threads and device. Anything else would make it another experiment.
RESUME_CHANGES = ("train.total_frames", "eval.", "logger.", "checkpoint.", "threads", "device")


def _leaves(node: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(node, dict):
        out: dict[str, Any] = {}
        for k, v in node.items():
            out.update(_leaves(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: node}


def resumed_config(saved: dict[str, Any], argv: list[str], name: str, run: Path) -> tuple[Recipe, list[str]]:
    """The config a resumed run continues with: the one it was started with (``saved``, from its
    checkpoint) plus the command line's overrides, of which only :data:`RESUME_CHANGES` may change a
    value, and ``logger.run_dir`` set to ``run``. Returns the config and one line per changed value;
    a refused change is a ConfigError."""
    _, overrides = parse_cli(name, argv)
    saved = migrated(saved)
    source = f"{run}/config.yaml"
    old = _leaves(to_dict(build(name, saved, [], source)))
    cfg = build(name, saved, overrides, source, run_dir=run)
    new = _leaves(to_dict(cfg))
    changed = [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k) and k not in ("checkpoint.resume", "logger.run_dir")]
    refused = [k for k in changed if not any(k == p or (p.endswith(".") and k.startswith(p)) for p in RESUME_CHANGES)]
    if refused:
        raise ConfigError(f"--resume={run}: cannot change {', '.join(f'{k} ({old.get(k)!r} -> {new.get(k)!r})' for k in refused)}; "
                          f"a resumed run keeps the config it was started with except {', '.join(RESUME_CHANGES)}. Start a new run instead.")
    return cfg, [f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in changed]


def save_config(cfg: Recipe, run: Path) -> None:
    """``<run>/config.yaml``: every key, the task's defaults included; ``--config`` reads it back to the same config."""
    (run / "config.yaml").write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))
