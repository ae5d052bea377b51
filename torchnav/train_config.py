"""The training recipes' configs: one frozen dataclass per recipe, with every default and its
documentation, and the reading of a recipe's YAML file and command line into it.

A recipe's config (:data:`RECIPES`\\ ``[name]``) has the sections ``env`` (how many copies of the
task run), ``task`` (the task's own config, :class:`~torchnav.tasks.NavConfig` or
:class:`~torchnav.tasks.LineConfig`), ``train`` (the algorithm's class: :class:`TD3Train`,
:class:`SACTrain`, :class:`PPOTrain`, :class:`DQNTrain`, :class:`APGTrain`), ``eval``, ``logger``,
``checkpoint`` and, for APG, ``smooth``. Every field has its default and its documentation here,
once: an algorithm's ``train`` defaults are the values of its main recipe (``TD3Train`` those of
``td3_lidar``, ``PPOTrain`` of ``ppo_lidar``, ``SACTrain`` of ``sac_lidar``, ``DQNTrain`` of
``dqn_line``, ``APGTrain`` of ``apg_lidar``), the shared sections' defaults are ``td3_lidar``'s, and a
recipe's YAML file (``recipes/configs/<name>.yaml``) lists only what it changes. The resolved config
a run saves (``<run>/config.yaml``, :func:`save_config`) has every key.

Each field declares what it allows (``torchnav.config``); :func:`load_config` puts the command
line's ``key=value`` overrides into the file's content (an unknown key is named with the closest
valid one) and builds the class, which reports every problem at once in one ConfigError, before
anything is created or started. torchnav does not import the recipes: the YAML files are found in
the ``recipes/configs`` folder of the source checkout this package lives in (:data:`CONFIG_DIR`),
or in the folder given as ``config_dir``.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import importlib.util
import re
import sys
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import torch
import yaml

from .checkpoint import write_atomic
from .config import (Config, ConfigError, checked, count, discount, flag, from_dict, is_int, merge, non_negative, one_of, positive,
                     probability, real, sizes, to_dict)
from .policy import RECURRENT
from .tasks import LineConfig, MultiNavConfig, NavConfig
from .tasks.robots import override_config, without_body

CONFIG_DIR = Path(__file__).resolve().parents[1] / "recipes" / "configs"  # the recipes' YAML files in a source checkout

# logger.backend -> the package it needs beyond the core install (and the extra that brings it)
LOGGER_BACKENDS = {"csv": None, "tensorboard": "tensorboard", "wandb": "wandb"}
THREADS = "'auto' or an int >= 1"


def _threads_ok(v: Any) -> bool:
    return v == "auto" or (is_int(v) and v >= 1)


def check_threads(setting: Any) -> None:
    """Refuse a ``threads`` setting other than ``'auto'`` (or None) or an int >= 1."""
    if setting is not None and not _threads_ok(setting):
        raise ConfigError(f"threads={setting!r}: must be {THREADS}")


def check_backend(backend: Any) -> None:
    """Refuse an unknown ``logger.backend``, or one whose package is not installed."""
    from_dict(LoggerConfig, {"backend": backend}, where="logger")


# --------------------------------------------------------------------------- sections


@dataclass(frozen=True)
class EnvConfig(Config):
    """``env``: the batch of tasks (the task itself is ``task``)."""

    num_envs: int = count(1, 128)  # envs stepped side by side


@dataclass(frozen=True)
class NavEnvConfig(EnvConfig):
    compile_step: bool = flag(False)  # run the simulator step through torch.compile (20-60 s to compile; pays on dense worlds)


@dataclass(frozen=True)
class EvalConfig(Config):
    interval_frames: int = count(0, 50_000)  # periodic evaluation every this many frames (0: never)
    episodes: int = count(1, 200)  # episodes per periodic evaluation (goals anywhere or random starts, deterministic policy)
    final_episodes: int = count(1, 1000)  # episodes of the final evaluation
    target_success: float = probability(0.95)  # the summary reports when periodic evaluation first reached this
    record_episodes: int = count(0, 4)  # final-evaluation episodes written to <run>/episodes.mcap (0: none)
    # true: the run ends with the actor that scored best in periodic evaluation (ties: the later; the last actor is
    # evaluated too), kept as <run>/best_actor.pt as it goes; the final evaluation (other seeds) then scores that one
    keep_best: bool = flag(True)


@dataclass(frozen=True)
class LineEvalConfig(EvalConfig):
    laps: int = count(1, 1)  # an episode succeeds when it completes this many laps


@dataclass(frozen=True)
class LoggerConfig(Config):
    backend: str = one_of(*LOGGER_BACKENDS, default="csv")  # TorchRL loggers (extras [tensorboard], [wandb]), written to <run>/logs
    root: str = "runs"  # parent of run directories
    run_dir: str | None = None  # explicit run directory (None: <root>/<recipe>_<time>_seed<seed>)
    progress: bool = flag(True)  # tqdm progress bar

    def checks(self) -> list[tuple[bool, str]]:
        package = LOGGER_BACKENDS[self.backend]
        return [(not package or importlib.util.find_spec(package) is not None,
                 f"backend={self.backend} needs the {package} package: pip install -e '.[{self.backend}]'")]


@dataclass(frozen=True)
class CheckpointConfig(Config):
    interval_frames: int = count(1, 50_000)  # write <run>/checkpoint.pt every this many frames (and at the end or on Ctrl-C/SIGTERM)
    # true: the newest run under logger.root (or logger.run_dir); or a run directory; or a kept
    # <run>/checkpoints/<frames>.pt (a new run continues from it)
    resume: bool | str = False
    # also keep each interval's checkpoint as <run>/checkpoints/<frames>.pt (hard links: no copy when the filesystem allows it)
    keep: bool = flag(False)


@dataclass(frozen=True)
class NavSmoothConfig(Config):
    """``smooth`` (APG, navigation): differentiable terms added to the reward in place of the task's
    terminal events, which have no gradient (``torchnav.apg``)."""

    contact: float = real(-8.0)  # weight of relu(1 - clearance / contact_margin): 0 far from obstacles, this at contact
    contact_margin: float = positive(0.6)  # m of clearance (robot disc to the nearest obstacle) below which `contact` applies
    ramp_frames: int = count(0, 50_000)  # their weight grows linearly from 0 over this many frames (0: full from the start)


@dataclass(frozen=True)
class LineSmoothConfig(Config):
    """``smooth`` (APG, line following): as :class:`NavSmoothConfig`."""

    path: float = real(-0.5)  # weight of (distance from the lap path / termination.max_path_distance)^2, per step
    ramp_frames: int = count(0, 0)  # their weight grows linearly from 0 over this many frames (0: full from the start)


# --------------------------------------------------------------------------- train, per algorithm


@dataclass(frozen=True)
class Train(Config):
    """The base of the algorithms' ``train`` sections."""


@dataclass(frozen=True)
class TD3Train(Train):
    total_frames: int = count(1, 250_880)  # env steps over all envs (245 batches)
    frames_per_batch: int = count(1, 1024)  # env steps collected between update rounds (a multiple of env.num_envs)
    init_random_frames: int = count(0, 5120)  # uniformly random actions first; updates start once the buffer holds this many
    updates_per_batch: int = count(1, 96)  # gradient steps per collected batch (1 per 10.7 frames; fewer, larger steps learn less)
    batch_size: int = count(1, 256)  # transitions per gradient step (at most buffer_size)
    buffer_size: int = count(1, 1_000_000)  # replay buffer capacity (transitions)
    gamma: float = discount(0.99)  # discount
    n_steps: int = count(1, 3)  # n-step returns: each stored transition sums up to this many rewards (within a collected batch; 1: one-step TD3)
    tau: float = discount(0.005)  # target-network soft-update rate
    lr_actor: float = positive(6e-4)  # Adam learning rate, actor
    lr_critic: float = positive(6e-4)  # Adam learning rate, twin critics
    policy_delay: int = count(1, 2)  # actor and target updates every this many critic updates
    policy_noise: float = non_negative(0.2)  # target-policy smoothing noise std (action units)
    noise_clip: float = non_negative(0.5)  # clip of the smoothing noise
    expl_sigma_init: float = non_negative(0.5)  # Gaussian exploration noise std at the start ...
    expl_sigma_end: float = non_negative(0.1)  # ... annealed linearly to this ...
    expl_anneal_frames: int = count(0, 150_000)  # ... over this many frames
    hidden: tuple[int, ...] = sizes((128, 128))  # MLP hidden sizes of actor and critics


@dataclass(frozen=True)
class SACTrain(Train):
    total_frames: int = count(1, 250_368)  # env steps over all envs (489 batches)
    frames_per_batch: int = count(1, 512)  # env steps collected between update rounds (a multiple of env.num_envs)
    init_random_frames: int = count(0, 5120)  # uniformly random actions first; updates start once the buffer holds this many
    updates_per_batch: int = count(1, 64)  # gradient steps per collected batch
    batch_size: int = count(1, 256)  # transitions per gradient step (at most buffer_size)
    buffer_size: int = count(1, 1_000_000)  # replay buffer capacity (transitions)
    gamma: float = discount(0.99)  # discount
    tau: float = discount(0.005)  # target-network soft-update rate
    lr_actor: float = positive(3e-4)  # Adam learning rate, actor
    lr_critic: float = positive(3e-4)  # Adam learning rate, twin critics
    lr_alpha: float = positive(3e-4)  # Adam learning rate, log temperature
    alpha_init: float = positive(0.2)  # initial entropy temperature (learned towards the target entropy -2)
    hidden: tuple[int, ...] = sizes((256, 256))  # MLP hidden sizes of actor and critics


@dataclass(frozen=True)
class PPOTrain(Train):
    total_frames: int = count(1, 3_997_696)  # env steps over all envs (122 batches of ppo_lidar's 4096 envs x 8 steps)
    frames_per_batch: int = count(1, 32_768)  # env steps per PPO iteration (a multiple of env.num_envs)
    epochs: int = count(1, 2)  # passes over each batch
    minibatch_size: int = count(1, 8192)  # transitions per gradient step (at most frames_per_batch)
    lr: float = positive(1e-3)  # Adam learning rate (policy, log-std and value network together)
    lr_decay: bool = flag(False)  # true: the learning rate falls linearly to 0 at total_frames
    max_grad_norm: float = positive(0.5)  # gradient-norm clip
    gamma: float = discount(0.99)  # discount
    lmbda: float = probability(0.95)  # GAE lambda
    clip_epsilon: float = positive(0.2)  # PPO ratio clip
    entropy_coeff: float = non_negative(0.0)  # entropy bonus weight
    critic_coeff: float = non_negative(0.5)  # value-loss weight
    init_log_std: float = real(-0.5)  # initial log standard deviation of the pre-tanh Gaussian
    obs_stats_steps: int = count(0, 32)  # random-action steps (x num_envs) that estimate the observation normalisation
    hidden: tuple[int, ...] = sizes((64, 64))  # MLP hidden sizes of the policy and value networks
    activation: str = one_of("relu", "tanh", default="relu")  # tanh is slower on CPU and learned slower on the lidar task
    # off | gru: a recurrent policy (MLP -> GRU cell -> head) whose hidden state each env carries, reset at an
    # episode's start; minibatches are then whole per-env sequences of frames_per_batch / num_envs steps
    # (minibatch_size a multiple of it); the value network stays feed-forward; the saved actor.pt is format
    # torchnav-actor-v3 (docs/training.md#recurrent-policies)
    recurrent: str = one_of(*RECURRENT, default="off", hint=' (in a YAML file quote "off": unquoted it reads as false)')
    recurrent_hidden: int = count(1, 128)  # size of the GRU's hidden state (train.recurrent: gru)


@dataclass(frozen=True)
class MAPPOTrain(PPOTrain):
    """``train`` of ``mappo_nav``: PPO with one policy and one value network shared by every robot.
    Frames are env steps (each steps ``robots.n`` robots); a minibatch is ``minibatch_size`` env
    steps with all their robots. ``recurrent`` must stay off. Its other defaults are PPOTrain's
    (recipes/configs/mappo_nav.yaml sets what the recipe changes)."""

    # central: MAPPO, the value network sees every robot slot's observation (TorchRL MultiAgentMLP,
    # centralised); local: IPPO, each robot's value from its own observation; parameters shared either way
    critic: str = one_of("central", "local", default="central")


@dataclass(frozen=True)
class DQNTrain(Train):
    total_frames: int = count(1, 1_000_448)  # env steps over all envs (977 batches)
    frames_per_batch: int = count(1, 1024)  # env steps collected between update rounds (a multiple of env.num_envs)
    init_random_frames: int = count(0, 10_240)  # uniformly random actions first; updates start once the buffer holds this many
    updates_per_batch: int = count(1, 16)  # gradient steps per collected batch
    batch_size: int = count(1, 512)  # transitions per gradient step (at most buffer_size)
    buffer_size: int = count(1, 500_000)  # replay buffer capacity (transitions)
    gamma: float = discount(0.99)  # discount
    tau: float = discount(0.005)  # target-network soft-update rate
    lr: float = positive(5e-4)  # Adam learning rate
    max_grad_norm: float = positive(10.0)  # gradient-norm clip
    eps_init: float = probability(1.0)  # epsilon-greedy: random-action probability at the start ...
    eps_end: float = probability(0.05)  # ... annealed linearly to this ...
    eps_anneal_frames: int = count(0, 300_000)  # ... over this many frames
    obs_stats_steps: int = count(0, 32)  # random-action steps (x num_envs) that estimate the observation normalisation
    hidden: tuple[int, ...] = sizes((64, 64))  # MLP hidden sizes of the Q-network
    activation: str = one_of("relu", "tanh", default="relu")


@dataclass(frozen=True)
class APGTrain(Train):
    total_frames: int = count(1, 301_056)  # env steps over all envs (294 horizons of apg_lidar's 32 envs x 32 steps)
    horizon: int = count(1, 32)  # steps backpropagated through before the critic bootstraps (SHAC: 32)
    lr_actor: float = positive(2e-3)  # Adam learning rate of the policy
    lr_critic: float = positive(1e-3)  # Adam learning rate of the critic
    lr_decay: bool = flag(True)  # both learning rates fall linearly to 0 at total_frames (SHAC's schedule)
    gamma: float = discount(0.99)  # discount
    lmbda: float = probability(0.95)  # TD(lambda) of the critic's targets
    tau: float = discount(0.2)  # Polyak rate of the target critic (the one that bootstraps the actor's horizon)
    critic_epochs: int = count(1, 16)  # passes of the critic over each horizon's transitions (with 4 the lidar policy collided more)
    minibatch_size: int = count(1, 512)  # transitions per critic gradient step
    max_grad_norm: float = positive(1.0)  # gradient-norm clip (actor and critic)
    skip_grad_norm: float = positive(1000.0)  # an actor gradient with a larger (or non-finite) norm is dropped, not applied
    # weight of the mean squared pre-tanh action in the actor loss: keeps actions off tanh's flat tails, where
    # the gradient no longer reaches them (the lidar policy's collisions happened at full speed, tanh saturated)
    action_reg: float = non_negative(0.1)
    expl_sigma_init: float = non_negative(0.3)  # std of the Gaussian noise added before the tanh at the start ...
    expl_sigma_end: float = non_negative(0.05)  # ... annealed linearly to this ...
    expl_anneal_frames: int = count(0, 200_000)  # ... over this many frames
    hidden: tuple[int, ...] = sizes((64, 64))  # MLP hidden sizes of the policy and the critic
    activation: str = one_of("relu", "tanh", default="tanh")  # tanh is smooth: the policy is differentiated through


# --------------------------------------------------------------------------- recipes


@dataclass(frozen=True)
class Recipe(Config):
    """A recipe's whole config; each subclass names its task and algorithm (a subclass narrows a section's class)."""

    seed: int = count(0, 0)  # seeds torch, the env generator and evaluation scenarios
    device: str = checked(lambda v: isinstance(v, str) and re.fullmatch(r"cpu|cuda(:\d+)?", v) is not None, "cpu, cuda or cuda:N", "cpu")
    # torch CPU threads: auto (the cores other processes leave free, re-checked every 5 s;
    # docs/performance.md#contention) or a fixed number
    threads: int | str = checked(_threads_ok, THREADS, "auto")
    env: EnvConfig
    task: NavConfig | LineConfig = field(default_factory=NavConfig)
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

    def checks(self) -> list[tuple[bool, str]]:
        fpb, n, mb = self.value("train.frames_per_batch"), self.env.num_envs, self.value("train.minibatch_size")
        out = [(fpb is None or fpb % n == 0, f"train.frames_per_batch={fpb} must be a multiple of env.num_envs={n}")]
        for small, big in (("train.minibatch_size", "train.frames_per_batch"), ("train.batch_size", "train.buffer_size"),
                           ("eval.record_episodes", "eval.final_episodes")):
            a, b = self.value(small), self.value(big)
            out.append((a is None or b is None or a <= b, f"{small}={a} must be at most {big}={b}"))
        steps = fpb // n if fpb is not None and fpb % n == 0 else None
        recurrent = self.value("train.recurrent")
        out.append((recurrent in (None, "off") or not steps or mb % steps == 0,
                    f"train.minibatch_size={mb} must be a multiple of the {steps} steps per env of a batch "
                    f"(train.frames_per_batch / env.num_envs) with train.recurrent={recurrent}: minibatches are whole per-env sequences"))
        if self.device.startswith("cuda"):
            have = torch.cuda.device_count() if torch.cuda.is_available() else 0
            out.append(((int(self.device.split(":")[1]) if ":" in self.device else 0) < have,
                        f"device={self.device!r}: this machine has {have} CUDA device(s)"
                        f"{'' if have else ' (torch ' + torch.__version__ + ')'}; use device=cpu"))
        return out


@dataclass(frozen=True)
class NavRecipe(Recipe):
    env: NavEnvConfig
    task: NavConfig


@dataclass(frozen=True)
class LineRecipe(Recipe):
    task: LineConfig
    eval: LineEvalConfig


@dataclass(frozen=True)
class TD3Lidar(NavRecipe):
    train: TD3Train


@dataclass(frozen=True)
class SACLidar(NavRecipe):
    train: SACTrain


@dataclass(frozen=True)
class PPOLidar(NavRecipe):
    train: PPOTrain


@dataclass(frozen=True)
class APGLidar(NavRecipe):
    train: APGTrain
    smooth: NavSmoothConfig


@dataclass(frozen=True)
class MultiNavRecipe(Recipe):
    task: MultiNavConfig


@dataclass(frozen=True)
class MAPPONav(MultiNavRecipe):
    train: MAPPOTrain

    def checks(self) -> list[tuple[bool, str]]:
        return super().checks() + [
            (self.train.recurrent == "off", f"train.recurrent={self.train.recurrent!r}: mappo_nav has no recurrent policy (use off)")]


@dataclass(frozen=True)
class PPOLine(LineRecipe):
    train: PPOTrain


@dataclass(frozen=True)
class DQNLine(LineRecipe):
    train: DQNTrain


@dataclass(frozen=True)
class APGLine(LineRecipe):
    train: APGTrain
    smooth: LineSmoothConfig


# recipe (recipes/<name>.py, recipes/configs/<name>.yaml) -> its config class
RECIPES: dict[str, type[Recipe]] = {
    "td3_lidar": TD3Lidar, "sac_lidar": SACLidar, "ppo_lidar": PPOLidar, "apg_lidar": APGLidar,
    "ppo_line": PPOLine, "dqn_line": DQNLine, "apg_line": APGLine, "mappo_nav": MAPPONav,
}


# --------------------------------------------------------------------------- files and command lines


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


def parse_cli(name: str, argv: list[str], config_dir: Path | str | None = None) -> tuple[Path, list[str]]:
    """The config file and the ``key.sub=value`` overrides of a recipe's command line.

    The file is ``<config_dir>/<name>.yaml`` (default :data:`CONFIG_DIR`), or ``--config PATH``;
    ``--resume [RUN_DIR]`` sets ``checkpoint.resume``; ``-h`` prints the usage and exits.
    """
    path = Path(config_dir or CONFIG_DIR) / f"{name}.yaml"
    overrides: list[str] = []
    it = iter(argv)
    for a in it:
        if a in ("-h", "--help"):
            print(f"usage: python recipes/{name}.py [--config FILE] [--resume[=RUN_DIR]] [key.sub=value ...]\n"
                  f"every key, its default and its documentation: torchnav/train_config.py (docs/training.md#configuration); "
                  f"what this recipe changes: {path}")
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


def build(name: str, data: dict[str, Any], overrides: Iterable[str] = (), source: str = "config", run_dir: Path | str | None = None) -> Recipe:
    """Recipe ``name``'s config from ``data`` (a config file's content, keys left out taking their
    defaults) and dotted ``overrides``, every value validated; ``run_dir`` sets ``logger.run_dir``."""
    cls = RECIPES.get(name)
    if cls is None:
        raise ConfigError(f"unknown recipe {name!r}; recipes: {', '.join(RECIPES)}")
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of config sections, got {type(data).__name__}")
    data = copy.deepcopy(data)
    parsed = [parse_override(text) for text in overrides]
    given = {key.removeprefix("task.robot.") for key, _ in parsed if key.startswith("task.robot.")}
    task = data.get("task")
    if "preset" in given and isinstance(task, dict) and isinstance(task.get("robot"), dict):
        task["robot"] = without_body(task["robot"], keep=given)  # the preset replaces the file's body (override_config)
    for key, value in parsed:
        _put(cls, data, key, value)
    if run_dir is not None:
        _put(cls, data, "logger.run_dir", str(run_dir))
    return from_dict(cls, data, where="")


BASE_KEY = "base"  # a config file's top-level key naming the config file it starts from


def read_config_file(path: Path | str, _chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    """A config file's content, with the files of its ``base:`` chain laid under it.

    ``base: FILE`` (a path relative to the file) makes the file a list of changes to FILE's config:
    mappings merge key by key, so a section given in the file changes only the keys it names, except
    that a ``task.robot.preset`` given in the file replaces the base's robot body
    (``torchnav.tasks.robots.override_config``; ``recipes/configs/ppo_generalist_jackal.yaml`` starts
    from ``ppo_generalist.yaml``)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}" + (f" (the base of {_chain[-1]})" if _chain else ""))
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not readable YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of config sections, got {type(data).__name__}")
    if BASE_KEY not in data:
        return data
    base = data.pop(BASE_KEY)
    if not isinstance(base, str) or not base.strip():
        raise ConfigError(f"{path}: {BASE_KEY}: expected the path of the config file this one changes (relative to {path.parent}), got {base!r}")
    chain = _chain + (path.resolve(),)
    base_path = path.parent / base
    if base_path.resolve() in chain:
        raise ConfigError(f"{path}: {BASE_KEY}: {base} is a cycle: {' -> '.join(str(p) for p in chain)} -> {base_path.resolve()}")
    under = read_config_file(base_path, chain)
    merged = merge(under, data)
    if isinstance(under.get("task"), dict) and isinstance(data.get("task"), dict):  # a robot.preset given here replaces the base's body
        merged["task"] = override_config(under["task"], data["task"])
    return merged


def load_config(name: str, argv: list[str], config_dir: Path | str | None = None) -> Recipe:
    """``<config_dir>/<name>.yaml`` (default :data:`CONFIG_DIR`; or ``--config FILE``; with its
    ``base:`` chain, :func:`read_config_file`) with the command line's overrides, validated."""
    path, overrides = parse_cli(name, argv, config_dir)
    return build(name, read_config_file(path), overrides, str(path))


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


def resumed_config(saved: dict[str, Any], argv: list[str], name: str, run: Path | str | None,
                   source: Path | str | None = None) -> tuple[Recipe, list[str]]:
    """The config a resumed run continues with: the one it was started with (``saved``, from its
    checkpoint ``source``) plus the command line's overrides, of which only :data:`RESUME_CHANGES` may
    change a value, and ``logger.run_dir`` set to ``run`` (None: a new automatic run directory). Returns
    the config and one line per changed value; a refused change is a ConfigError."""
    _, overrides = parse_cli(name, argv)
    label = source or run  # what --resume named
    source = str(source or f"{run}/config.yaml")
    old = _leaves(to_dict(build(name, saved, [], source)))
    if run is None:
        saved = {**saved, "logger": {**saved.get("logger", {}), "run_dir": None}}
    cfg = build(name, saved, overrides, source, run_dir=run)
    new = _leaves(to_dict(cfg))
    changed = [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k) and k not in ("checkpoint.resume", "logger.run_dir")]
    refused = [k for k in changed if not any(k == p or (p.endswith(".") and k.startswith(p)) for p in RESUME_CHANGES)]
    if refused:
        raise ConfigError(f"--resume={label}: cannot change {', '.join(f'{k} ({old.get(k)!r} -> {new.get(k)!r})' for k in refused)}; "
                          f"a resumed run keeps the config it was started with except {', '.join(RESUME_CHANGES)}. Start a new run instead.")
    return cfg, [f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in changed]


def save_config(cfg: Recipe, run: Path) -> None:
    """``<run>/config.yaml``: every key, the defaults included; ``--config`` reads it back to the same config."""
    write_atomic(run / "config.yaml", yaml.safe_dump(to_dict(cfg), sort_keys=False))
