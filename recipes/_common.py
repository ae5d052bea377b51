"""Builders shared by the recipes: config loading, run directories, logging, checkpoints, evaluation.

Kept out of ``torchnav/`` on purpose: the package never imports recipes.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import importlib.util
import json
import math
import os
import random
import re
import signal
import sys
import time
from pathlib import Path
from typing import Any, Callable

import torch
import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigAttributeError, ConfigKeyError

from torchnav.checkpoint import load_checked, save_checked
from torchnav.config import ConfigError, merge, to_dict
from torchnav.protocol import LineProtocol, NavProtocol, TaskProtocol
from torchnav.tasks import LineConfig, NavConfig

CONFIG_DIR = Path(__file__).resolve().parent / "configs"
# Sections whose keys are validated by NavConfig rather than by the YAML file.
_FREE_SECTIONS = ("task", "reward.weights")


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


def load_config(name: str, argv: list[str]) -> DictConfig:
    """``configs/<name>.yaml`` (or ``--config FILE``) with the command line's overrides, validated.

    Unknown keys are errors that name the key; ``task.*`` keys are checked against
    NavConfig/LineConfig when the task is built.
    """
    path, overrides = parse_cli(name, argv)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    return _merged(yaml.safe_load(path.read_text()) or {}, overrides, str(path))


def _merged(base: dict[str, Any], overrides: list[str], source: str) -> DictConfig:
    """``base`` (a config as a dict) with dotted ``overrides``: unknown keys refused, every value validated."""
    cfg = OmegaConf.create(base)
    defaults = cfg.copy()
    for sec in _FREE_SECTIONS:
        if OmegaConf.select(cfg, sec) is None:
            OmegaConf.update(cfg, sec, {}, force_add=True)
    OmegaConf.set_struct(cfg, True)
    for sec in _FREE_SECTIONS:
        OmegaConf.set_struct(OmegaConf.select(cfg, sec), False)
    try:
        cfg = OmegaConf.merge(cfg, OmegaConf.from_dotlist(overrides))
    except (ConfigAttributeError, ConfigKeyError) as e:
        key = getattr(e, "full_key", None) or str(e).splitlines()[0]
        raise ConfigError(f"unknown config key '{key}'{_did_you_mean(cfg, str(key))} (see {source} for every valid key)") from None
    validate(cfg, defaults)
    return cfg


# What a resumed run may change from the config it was started with: its length, evaluation,
# logging, checkpoint cadence, threads and device. Anything else would make it another experiment.
RESUME_CHANGES = ("train.total_frames", "eval.", "logger.", "checkpoint.", "threads", "device")


def resumed_config(saved: dict[str, Any], argv: list[str], name: str, run: Path) -> tuple[DictConfig, list[str]]:
    """The config a resumed run continues with: the one it was started with (``saved``, from its
    checkpoint) plus the command line's overrides, of which only :data:`RESUME_CHANGES` may change a
    value. Returns the config and one line per changed value; a refused change is a ConfigError."""
    _, overrides = parse_cli(name, argv)
    cfg = _merged(saved, overrides, f"{run}/config.yaml")
    old, new = _leaves(saved), _leaves(OmegaConf.to_container(cfg, resolve=True))
    changed = [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k) and k not in ("checkpoint.resume", "logger.run_dir")]
    refused = [k for k in changed if not any(k == p or (p.endswith(".") and k.startswith(p)) for p in RESUME_CHANGES)]
    if refused:
        raise ConfigError(f"--resume={run}: cannot change {', '.join(f'{k} ({old.get(k)!r} -> {new.get(k)!r})' for k in refused)}; "
                          f"a resumed run keeps the config it was started with except {', '.join(RESUME_CHANGES)}. Start a new run instead.")
    return cfg, [f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in changed]


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v: Any) -> bool:
    return (_is_int(v) or isinstance(v, float)) and math.isfinite(v)


# key -> (test, what is allowed). A key may appear in some recipes only; "train.lr*" matches every learning rate.
_RULES: dict[str, tuple[Callable[[Any], bool], str]] = {}
for _keys, _rule in {
    ("seed",): (lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
    ("env.num_envs", "env.max_steps", "train.total_frames", "train.frames_per_batch", "train.updates_per_batch", "train.batch_size",
     "train.buffer_size", "train.policy_delay", "train.epochs", "train.minibatch_size", "eval.episodes", "eval.final_episodes",
     "eval.laps", "checkpoint.interval_frames", "train.horizon", "train.critic_epochs"): (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    ("train.init_random_frames", "train.expl_anneal_frames", "smooth.ramp_frames", "train.eps_anneal_frames", "train.obs_stats_steps",
     "eval.interval_frames", "eval.record_episodes"): (lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
    ("train.lr*", "train.max_grad_norm", "train.skip_grad_norm", "train.clip_epsilon", "train.alpha_init", "env.goal_tolerance",
     "smooth.contact_margin"):
        (lambda v: _is_num(v) and v > 0, "a finite number > 0"),
    ("train.policy_noise", "train.noise_clip", "train.expl_sigma_init", "train.expl_sigma_end", "train.entropy_coeff",
     "train.critic_coeff", "train.action_reg"): (lambda v: _is_num(v) and v >= 0, "a finite number >= 0"),
    ("train.gamma", "train.tau"): (lambda v: _is_num(v) and 0 < v <= 1, "a number in (0, 1]"),
    ("train.lmbda", "train.eps_init", "train.eps_end", "eval.target_success"): (lambda v: _is_num(v) and 0 <= v <= 1, "a number in [0, 1]"),
    ("train.init_log_std",): (_is_num, "a finite number"),
    ("train.hidden",): (lambda v: isinstance(v, list) and len(v) > 0 and all(_is_int(h) and h >= 1 for h in v), "a non-empty list of integers >= 1"),
    ("train.activation",): (lambda v: v in ("relu", "tanh"), "relu or tanh"),
    ("env.compile_step", "logger.progress", "train.lr_decay"): (lambda v: isinstance(v, bool), "true or false"),
    ("device",): (lambda v: isinstance(v, str) and re.fullmatch(r"cpu|cuda(:\d+)?", v) is not None, "cpu, cuda or cuda:N"),
}.items():
    for _k in _keys:
        _RULES[_k] = _rule


def _rule(key: str) -> tuple[Callable[[Any], bool], str] | None:
    return _RULES.get(key) or next((r for k, r in _RULES.items() if k.endswith("*") and key.startswith(k[:-1])), None)


def _leaves(node: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(node, dict):
        out: dict[str, Any] = {}
        for k, v in node.items():
            out.update(_leaves(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: node}


def validate(cfg: DictConfig, defaults: DictConfig | None = None) -> None:
    """Check every value of a recipe config before any work: its type (that of the recipe's
    default file, when ``defaults`` is given), finiteness, range, the relations between keys
    and that the device exists. Raises a ConfigError naming the key, the value and what is
    allowed. ``task.*`` keys are NavConfig/LineConfig fields, checked by those classes."""
    values = _leaves(OmegaConf.to_container(cfg, resolve=True))
    base = _leaves(OmegaConf.to_container(defaults, resolve=True)) if defaults is not None else {}
    problems = []
    for key, v in values.items():
        if key.startswith("task.") or key in ("threads", "checkpoint.resume", "logger.run_dir"):
            continue  # the task's own config class, ThreadGovernor and find_resume_dir check these
        if isinstance(v, float) and not math.isfinite(v):
            problems.append(f"{key}={v!r}: must be finite")
            continue
        rule = _rule(key)
        if rule is not None:
            if not rule[0](v):
                problems.append(f"{key}={v!r}: must be {rule[1]}")
            continue
        d = base.get(key)
        if d is not None and not (type(v) is type(d) or (isinstance(d, float) and _is_int(v))):
            problems.append(f"{key}={v!r}: must be a {type(d).__name__} like its default {d!r}")
    fpb, n = values.get("train.frames_per_batch"), values.get("env.num_envs")
    if _is_int(fpb) and _is_int(n) and n >= 1 and fpb % n:
        problems.append(f"train.frames_per_batch={fpb} must be a multiple of env.num_envs={n}")
    for small, big in (("train.minibatch_size", "train.frames_per_batch"), ("train.batch_size", "train.buffer_size"),
                       ("eval.record_episodes", "eval.final_episodes")):
        if _is_int(values.get(small)) and _is_int(values.get(big)) and values[small] > values[big]:
            problems.append(f"{small}={values[small]} must be at most {big}={values[big]}")
    dev = values.get("device")
    if isinstance(dev, str) and dev.startswith("cuda") and (rule := _rule("device")) and rule[0](dev):
        n = torch.cuda.device_count() if torch.cuda.is_available() else 0
        index = int(dev.split(":")[1]) if ":" in dev else 0
        if index >= n:
            problems.append(f"device={dev!r}: this machine has {n} CUDA device(s){'' if n else ' (torch ' + torch.__version__ + ')'}; use device=cpu")
    if problems:
        raise ConfigError("invalid config:\n  " + "\n  ".join(problems))


def _did_you_mean(cfg: DictConfig, key: str) -> str:
    """A close valid key for an unknown dotted ``key``, as a message suffix."""
    import difflib

    parent, _, leaf = key.rpartition(".")
    node = OmegaConf.select(cfg, parent) if parent else cfg
    if not isinstance(node, DictConfig):
        return ""
    close = difflib.get_close_matches(leaf, [str(k) for k in node.keys()], n=1)
    return f" (did you mean '{parent + '.' if parent else ''}{close[0]}'?)" if close else ""


def _section(cfg: DictConfig, name: str) -> dict[str, Any]:
    return OmegaConf.to_container(cfg[name], resolve=True)  # type: ignore[return-value]


def nav_config(cfg: DictConfig, **extra: Any) -> NavConfig:
    """The NavConfig described by a recipe config's ``env``, ``curriculum``, ``reward`` and ``task`` sections."""
    env = {k: v for k, v in _section(cfg, "env").items() if k not in ("num_envs", "compile_step")}
    d = merge(merge(_section(cfg, "task"), env), {"curriculum": _section(cfg, "curriculum"), "reward": _section(cfg, "reward")})
    return NavConfig.from_dict(merge(d, extra), where="config")


def line_config(cfg: DictConfig) -> LineConfig:
    """The LineConfig described by a recipe config's ``env``, ``reward`` and ``task`` sections."""
    env = {k: v for k, v in _section(cfg, "env").items() if k != "num_envs"}
    return LineConfig.from_dict(merge(merge(_section(cfg, "task"), env), {"reward": _section(cfg, "reward")}), where="config")


def task_protocol(cfg: DictConfig, task: str) -> TaskProtocol:
    """The task protocol (``torchnav.protocol``) of a recipe config: ``"nav"`` or ``"line"``; an unknown
    or malformed map or track is named now, before the run directory exists."""
    if task == "nav":
        return NavProtocol(nav_config(cfg), compile_step=cfg.env.get("compile_step", False))  # compile_step checked by validate
    return LineProtocol(line_config(cfg), laps=cfg.eval.laps)


def make_run_dir(cfg: DictConfig, name: str, resuming: bool = False) -> Path:
    """The run directory: ``logger.run_dir``, or a new ``<logger.root>/<name>_<time>_seed<seed>``.

    A new run's directory is created exclusively: an automatic name that exists already
    (two runs started in the same second) gets a ``_2``, ``_3``, ... suffix, and an explicit
    ``logger.run_dir`` that already holds a run is refused (resume it, or pick another).
    """
    if cfg.logger.run_dir:
        run = Path(cfg.logger.run_dir)
        if resuming:
            return run
        if run.is_dir() and any((run / f).exists() for f in ("checkpoint.pt", "config.yaml", "actor.pt")):
            raise ConfigError(f"logger.run_dir={run} already holds a run; continue it with --resume={run} or choose another directory")
        run.mkdir(parents=True, exist_ok=True)
        return run
    stamp = _dt.datetime.now().strftime("%Y%m%d_%H%M%S")
    base = Path(cfg.logger.root) / f"{name}_{stamp}_seed{cfg.seed}"
    base.parent.mkdir(parents=True, exist_ok=True)
    for i in range(1, 1000):
        run = base if i == 1 else base.with_name(f"{base.name}_{i}")
        try:
            run.mkdir()
            return run
        except FileExistsError:
            continue
    raise ConfigError(f"could not create a new run directory next to {base}")


def save_config(cfg: DictConfig, run: Path) -> None:
    (run / "config.yaml").write_text(OmegaConf.to_yaml(cfg))


# logger.backend -> the package it needs beyond the core install (and the extra that brings it)
LOGGER_BACKENDS = {"csv": None, "tensorboard": "tensorboard", "wandb": "wandb"}


def check_logger(cfg: DictConfig) -> None:
    """Refuse an unknown ``logger.backend``, or one whose package is not installed, before any run starts."""
    backend = cfg.logger.backend
    if backend not in LOGGER_BACKENDS:
        raise ConfigError(f"logger.backend must be one of {sorted(LOGGER_BACKENDS)}, got {backend!r}")
    package = LOGGER_BACKENDS[backend]
    if package and importlib.util.find_spec(package) is None:
        raise ConfigError(f"logger.backend={backend} needs the {package} package: pip install -e '.[{backend}]'")


def make_logger(cfg: DictConfig, run: Path):
    """TorchRL logger writing into ``<run>/logs`` (CSV by default; TensorBoard; Weights & Biases
    offline unless the environment sets ``WANDB_MODE=online``, with the run's directory name as its name)."""
    check_logger(cfg)
    if cfg.logger.backend == "wandb":
        from torchrl.record.loggers.wandb import WandbLogger

        (run / "logs").mkdir(parents=True, exist_ok=True)
        online = os.environ.get("WANDB_MODE", "offline") == "online"
        return WandbLogger(exp_name=run.name, save_dir=str(run / "logs"), project=os.environ.get("WANDB_PROJECT", "torchnav"),
                           offline=not online, log_env_packages=False)
    from torchrl.record.loggers import get_logger

    return get_logger(cfg.logger.backend, logger_name=str(run), experiment_name="logs")


def seed_everything(seed: int) -> None:
    random.seed(seed)
    torch.manual_seed(seed)


def rng_states() -> dict[str, Any]:
    return {"torch": torch.get_rng_state(), "python": list(random.getstate()[1])}


def set_rng_states(sd: dict[str, Any]) -> None:
    torch.set_rng_state(sd["torch"])
    st = random.getstate()
    random.setstate((st[0], tuple(sd["python"]), st[2]))


def save_checkpoint(path: Path, payload: dict[str, Any]) -> None:
    """Durable save with a content hash (``torchnav.checkpoint``): a crash never leaves a torn checkpoint."""
    save_checked(path, payload)


def load_checkpoint(path: Path) -> dict[str, Any]:
    """A recipe checkpoint, refused with a CheckpointError naming the file when damaged or non-finite."""
    return load_checked(path)


def find_resume_dir(cfg: DictConfig, name: str) -> Path | None:
    """The run directory to resume: an explicit path, or the newest run of recipe ``name``."""
    r = cfg.checkpoint.resume
    if r in (False, None, "", "false"):
        return None
    if r is True or r == "true":
        if cfg.logger.run_dir:
            return Path(cfg.logger.run_dir)
        runs = sorted((p for p in Path(cfg.logger.root).glob(f"{name}_*") if (p / "checkpoint.pt").is_file()), key=lambda p: p.stat().st_mtime)
        if not runs:
            raise FileNotFoundError(f"--resume: no {name} run with a checkpoint.pt under {cfg.logger.root}")
        return runs[-1]
    return Path(str(r))


class ThreadGovernor:
    """torch's CPU thread count, chosen from the cores other processes leave free and re-checked as a run goes.

    Two torch threads on two cores collapse when another process is busy: OpenMP's
    threads spin waiting for each other while one of them is descheduled (PPO's default
    run took 164 s next to one busy process instead of 49 s; with one thread, 60 s;
    docs/performance.md#contention). ``threads: auto`` therefore measures, over each
    ``interval`` s, the CPU time of the whole machine (``/proc/stat``) less this
    process's own (``os.times``), and sets as many threads as cores are left free:
    at least 1, at most the cores this process may use. A fixed ``threads: N`` sets N
    once and never changes it; so does ``auto`` where ``/proc/stat`` is missing or
    counts other cores than this process may use (not Linux, some containers).
    """

    STAT = Path("/proc/stat")

    def __init__(self, setting: Any, interval: float = 5.0, probe: float = 0.2) -> None:
        if setting not in ("auto", None) and not (isinstance(setting, int) and not isinstance(setting, bool) and setting >= 1):
            raise ConfigError(f"threads must be 'auto' or an int >= 1, got {setting!r}")
        self.cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        self.auto = setting in ("auto", None) and self._machine_cores() == self.cores
        self.threads = self.cores if setting in ("auto", None) else int(setting)
        self.interval = float(interval)
        self.changes: list[tuple[float, int, float]] = []  # (time in the run s, threads, other processes' cores)
        self._t0 = time.monotonic()
        if self.auto:
            self._mark = self._sample()
            time.sleep(probe)  # a first look before any work
            self.update(force=True)
        torch.set_num_threads(self.threads)

    def _machine_cores(self) -> int:
        try:
            return sum(1 for line in self.STAT.read_text().splitlines() if line.startswith("cpu") and line[3:4].isdigit())
        except OSError:
            return -1

    def _sample(self) -> tuple[float, float, float]:
        """(wall s, busy CPU s of the machine, CPU s of this process)."""
        f = [int(x) for x in self.STAT.read_text().split("\n", 1)[0].split()[1:]]
        busy = sum(f) - f[3] - (f[4] if len(f) > 4 else 0)  # all but idle and iowait; guest time is inside user
        if len(f) > 8:
            busy -= sum(f[8:10])
        t = os.times()
        return time.monotonic(), busy / os.sysconf("SC_CLK_TCK"), t.user + t.system

    def others(self, a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
        """Cores used by other processes between samples ``a`` and ``b``."""
        wall = max(b[0] - a[0], 1e-6)
        return max(0.0, ((b[1] - a[1]) - (b[2] - a[2])) / wall)

    def update(self, force: bool = False) -> int | None:
        """Re-check (at most every ``interval`` s, any time with ``force``); returns the new thread count when it changed."""
        if not self.auto or (not force and time.monotonic() - self._mark[0] < self.interval):
            return None
        now = self._sample()
        others = self.others(self._mark, now)
        self._mark = now
        want = max(1, min(self.cores, round(self.cores - others)))
        if want == self.threads and self.changes:  # the first look is always recorded
            return None
        self.threads = want
        torch.set_num_threads(want)
        self.changes.append((round(now[0] - self._t0, 1), want, round(others, 2)))
        return want


def threads_arg(text: str) -> str | int:
    """argparse type of ``--threads``: ``auto`` or a positive int."""
    if text == "auto":
        return text
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"expected 'auto' or an int >= 1, got {text!r}")
    return int(text)


class StopFlag:
    """Turns SIGTERM and SIGINT into a flag the training loop polls, so it can checkpoint and exit."""

    def __init__(self) -> None:
        self.stop = False
        self._old = {}
        for sig in (signal.SIGTERM, signal.SIGINT):
            self._old[sig] = signal.signal(sig, self._handle)

    def _handle(self, signum, frame) -> None:  # noqa: ARG002
        if self.stop:  # second signal: give up immediately
            signal.signal(signum, self._old[signum])
            raise KeyboardInterrupt
        self.stop = True
        print(f"\nreceived signal {signum}: finishing this batch, writing a checkpoint, then exiting", file=sys.stderr, flush=True)

    def restore(self) -> None:
        for sig, h in self._old.items():
            signal.signal(sig, h)


def write_json(path: Path, obj: Any) -> None:
    path.write_text(json.dumps(obj, indent=2))


def config_dict(cfg: DictConfig) -> dict[str, Any]:
    return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]


def main_guard(main: Callable[[list[str]], Any]) -> None:
    """Run ``main(sys.argv[1:])`` for a command-line tool: bad input (a config, map, track or
    checkpoint error, a missing file, any ValueError naming what is wrong) becomes one line on
    stderr and exit code 2 instead of a traceback."""
    try:
        main(sys.argv[1:])
    except (ConfigError, FileNotFoundError, ValueError) as e:  # MapError, TrackError, CheckpointError are ValueErrors
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)


__all__ = [
    "main_guard", "parse_cli", "load_config", "resumed_config", "nav_config", "line_config", "task_protocol", "make_run_dir", "save_config", "check_logger", "make_logger", "seed_everything", "rng_states",
    "set_rng_states", "save_checkpoint", "load_checkpoint", "find_resume_dir", "StopFlag", "ThreadGovernor", "write_json",
    "config_dict", "to_dict",
]
