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
``_config_load`` reads a file and a command line into these classes.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import re
from dataclasses import dataclass
from typing import Any

import torch

from torchnav.config import ConfigError, checked, is_int, is_number, raise_problems
from torchnav.policy import RECURRENT
from torchnav.tasks import LineConfig, NavConfig


# --------------------------------------------------------------------------- what a field allows


def count(lo: int, default: Any = dataclasses.MISSING) -> Any:
    return checked(lambda v: is_int(v) and v >= lo, f"an integer >= {lo}", default)


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


def flag(default: Any = dataclasses.MISSING) -> Any:
    return checked(lambda v: isinstance(v, bool), "true or false", default)


def one_of(*options: str, default: Any = dataclasses.MISSING, hint: str = "") -> Any:
    return checked(lambda v: v in options, " or ".join(options) + hint, default)


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
    resume: bool | str  # true: the newest run; or a run directory; or a kept checkpoint file (a new run continues from it)
    # also keep each interval's checkpoint as <run>/checkpoints/<frames>.pt (hard links: no copy when the
    # filesystem allows it); default off, so that configs saved before the key existed resume unchanged
    keep: bool = flag(default=False)


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
    # defaults so that configs saved before these keys existed resume as feed-forward runs
    recurrent: str = one_of(*RECURRENT, default="off", hint=' (in a YAML file quote "off": unquoted it reads as false)')  # docs/training.md
    recurrent_hidden: int = count(1, default=128)  # size of the GRU state (train.recurrent: gru)
    lr_decay: bool = flag(default=False)  # the learning rate falls linearly to 0 at total_frames


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
        steps = fpb // n if fpb is not None and fpb % n == 0 else None
        mb = self.value("train.minibatch_size")
        if self.value("train.recurrent") not in (None, "off") and steps and mb % steps:
            problems.append(f"train.minibatch_size={mb} must be a multiple of the {steps} steps per env of a batch "
                            f"(train.frames_per_batch / env.num_envs) with train.recurrent={self.value('train.recurrent')}: "
                            "minibatches are whole per-env sequences")
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
