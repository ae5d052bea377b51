"""Builders shared by the recipes: run directories, logging, checkpoints, threads, signals; the config
functions of ``_config_load`` (reading the config classes of ``_config``) are reached through here too.

Kept out of ``torchnav/`` on purpose: the package never imports recipes.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import random
import signal
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterable

import torch

from torchnav.checkpoint import load_checked, save_checked
from torchnav.config import ConfigError, to_dict
from torchnav.protocol import LineProtocol, NavProtocol, TaskProtocol
from torchnav.tasks import NavConfig
from torchnav.train_config import (LOGGER_BACKENDS, RECIPES, RESUME_CHANGES, Recipe, check_backend, check_threads,  # noqa: F401
                                   load_config, parse_cli, resumed_config, save_config)  # (the recipes use them from here)


def task_protocol(cfg: Recipe) -> TaskProtocol:
    """The task protocol (``torchnav.protocol``) of a recipe config, from its ``task`` section: an
    unknown or malformed map or track is named now, before the run directory exists."""
    if isinstance(cfg.task, NavConfig):
        return NavProtocol(cfg.task, compile_step=cfg.env.compile_step)
    return LineProtocol(cfg.task, laps=cfg.eval.laps)


def make_run_dir(cfg: Recipe, name: str, resuming: bool = False) -> Path:
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


def check_logger(cfg: Any) -> None:
    """Refuse an unknown ``logger.backend``, or one whose package is not installed, before any run starts."""
    check_backend(cfg.logger.backend)


def make_logger(cfg: Recipe, run: Path):
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


def find_resume(cfg: Recipe, name: str) -> tuple[Path, Path | None] | None:
    """What ``checkpoint.resume`` names, as ``(checkpoint file, run directory to continue in)``, or None:
    a run directory (explicit, or the newest run of recipe ``name``) continues in place; a kept
    checkpoint file (``<run>/checkpoints/<frames>.pt``, ``checkpoint.keep``) has no run directory to
    continue in: a new run starts from it, so the run it came from stays as it was."""
    r = cfg.checkpoint.resume
    if r in (False, None, "", "false"):
        return None
    if r is True or r == "true":
        if cfg.logger.run_dir:
            run = Path(cfg.logger.run_dir)
        else:
            runs = sorted((p for p in Path(cfg.logger.root).glob(f"{name}_*") if (p / "checkpoint.pt").is_file()), key=lambda p: p.stat().st_mtime)
            if not runs:
                raise FileNotFoundError(f"--resume: no {name} run with a checkpoint.pt under {cfg.logger.root}")
            run = runs[-1]
        return run / "checkpoint.pt", run
    path = Path(str(r))
    if path.is_file() or path.suffix == ".pt":
        return path, None
    return path / "checkpoint.pt", path


class ThreadGovernor:
    """torch's CPU thread count, chosen from the cores other processes leave free and re-checked as a run goes.

    Two torch threads on two cores collapse when another process is busy: OpenMP's
    threads spin waiting for each other while one of them is descheduled (PPO's default
    run took 164 s next to one busy process instead of 49 s; with one thread, 60 s;
    docs/performance.md#contention). ``threads: auto`` therefore measures, over each
    ``interval`` s, the CPU time of the whole machine (``/proc/stat``) less this
    process's own and its finished children's (``os.times``), and sets as many threads as cores are left free:
    at least 1, at most the cores this process may use. A fixed ``threads: N`` sets N
    once and never changes it; so does ``auto`` where ``/proc/stat`` is missing or
    counts other cores than this process may use (not Linux, some containers).
    """

    STAT = Path("/proc/stat")

    def __init__(self, setting: Any, interval: float = 5.0, probe: float = 0.2) -> None:
        check_threads(setting)
        self.cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        self.auto = setting in ("auto", None) and self._machine_cores() == self.cores
        self.threads = self.cores if setting in ("auto", None) else int(setting)
        self.interval = float(interval)
        self.changes: list[tuple[float, int, float]] = []  # (time in the run s, threads, other processes' cores)
        self.steal = 0.0  # cores' worth of hypervisor steal over the last interval (inside the others' cores)
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

    def _sample(self) -> tuple[float, float, float, float]:
        """(wall s, busy CPU s of the machine, CPU s of this process and of its finished children: the
        C++ compilers that ``torch.compile`` runs are this run's work, not another process's; and the
        machine's steal s, time a hypervisor gave this VM's cores to others, counted inside busy)."""
        f = [int(x) for x in self.STAT.read_text().split("\n", 1)[0].split()[1:]]
        busy = sum(f) - f[3] - (f[4] if len(f) > 4 else 0)  # all but idle and iowait; guest time is inside user
        if len(f) > 8:
            busy -= sum(f[8:10])
        t = os.times()
        tick = os.sysconf("SC_CLK_TCK")
        steal = f[7] / tick if len(f) > 7 else 0.0
        return time.monotonic(), busy / tick, t.user + t.system + t.children_user + t.children_system, steal

    @staticmethod
    def _cores(a: tuple[float, ...], b: tuple[float, ...], cpu_s: float) -> float:
        """``cpu_s`` CPU seconds spent between samples ``a`` and ``b`` as cores' worth (at least 0)."""
        return max(0.0, cpu_s / max(b[0] - a[0], 1e-6))

    def others(self, a: tuple[float, ...], b: tuple[float, ...]) -> float:
        """Cores used by other processes between samples ``a`` and ``b`` (hypervisor steal included)."""
        return self._cores(a, b, (b[1] - a[1]) - (b[2] - a[2]))

    def stolen(self, a: tuple[float, ...], b: tuple[float, ...]) -> float:
        """Cores' worth of hypervisor steal between samples ``a`` and ``b`` (part of :meth:`others`)."""
        return self._cores(a, b, b[3] - a[3])

    def update(self, force: bool = False) -> int | None:
        """Re-check (at most every ``interval`` s, any time with ``force``); returns the new thread count when it changed."""
        if not self.auto or (not force and time.monotonic() - self._mark[0] < self.interval):
            return None
        now = self._sample()
        others, self.steal = self.others(self._mark, now), self.stolen(self._mark, now)
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


def config_dict(cfg: Recipe) -> dict[str, Any]:
    return to_dict(cfg)


def adam(params: Iterable[torch.Tensor], **kwargs: Any) -> torch.optim.Adam:
    """``torch.optim.Adam`` with its fused kernel (one kernel per step for all parameters instead of
    several per parameter), where the parameters' device has one, else the plain one. Same
    algorithm, other rounding: TD3's update at the quick start's sizes took 5.9 instead of 8.0 ms
    (docs/performance.md, "Fused Adam")."""
    params = list(params)
    try:
        return torch.optim.Adam(params, fused=True, **kwargs)
    except RuntimeError:  # a device without a fused Adam
        return torch.optim.Adam(params, **kwargs)


def decay_lr(optim: torch.optim.Optimizer, lr: float, frames: int, total_frames: int) -> None:
    """Set ``optim``'s learning rate to ``lr`` falling linearly to 0 at ``total_frames`` (``train.lr_decay``).
    Computed from the frame count, so a resumed run continues the same schedule."""
    keep = max(0.0, 1.0 - frames / total_frames)
    for group in optim.param_groups:
        group["lr"] = float(lr) * keep


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
    "main_guard", "parse_cli", "load_config", "resumed_config", "task_protocol", "make_run_dir", "save_config", "check_logger", "make_logger", "seed_everything", "rng_states",
    "set_rng_states", "save_checkpoint", "load_checkpoint", "find_resume", "StopFlag", "ThreadGovernor", "write_json",
    "config_dict", "to_dict", "adam",
]
