"""Builders the recipes share, as plain functions; each recipe owns its training loop.

A recipe reads top to bottom (``td3_lidar.py`` is the model):

    run = B.setup("td3_lidar", argv, ckpt_format=..., action_mode="continuous")  # config, run dir, logger, env
    ... networks, loss, optimisers ...
    state = {"actor": actor, ...}                  # what a checkpoint holds beyond env, RNG and counters
    collector = B.make_collector(run, policy)
    B.restore(run, state, collector)               # a resumed run continues exactly where it stopped
    with B.Progress(run, state, actor) as progress:  # progress bar, logs; a checkpoint on any exit
        for data in collector:
            progress.collected(data)
            ... the update ...
            progress.updated(losses)               # progress bar, logs, periodic evaluation, checkpoints
            if progress.stop:
                break
    return B.finish(run, actor) if not progress.stop else B.stopped(run)

Kept out of ``torchnav/`` on purpose: the package never imports recipes. The config classes and
their YAML/CLI loading are the library's (``torchnav.train_config``).
"""

from __future__ import annotations

import argparse
import collections
import datetime as _dt
import json
import os
import random
import shutil
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from tqdm import tqdm

from torchnav.checkpoint import load_checked, save_checked, write_atomic
from torchnav.config import ConfigError, to_dict
from torchnav.evaluation import FINAL_EVAL_SEED, PERIODIC_EVAL_SEED
from torchnav.policy import STATE_KEY, Actor, RecurrentActor, load_policy, save_policy, policy_payload, to_policy
from torchnav.protocol import LineProtocol, MultiNavProtocol, NavProtocol, TaskProtocol
from torchnav.tasks import MultiNavConfig, NavConfig
from torchnav.train_config import LOGGER_BACKENDS, Recipe, check_backend, check_threads, load_config, resumed_config, save_config  # noqa: F401

RECENT_EPISODES = 500  # training episodes behind the train/<outcome>_rate figures of the progress bar and logs
REPLAY_KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"), ("next", "terminated"))


# --------------------------------------------------------------------------- setup


@dataclass
class Run:
    """One training run as :func:`setup` builds it."""

    name: str  # the recipe (configs/<name>.yaml)
    ckpt_format: str  # what its checkpoints say they are; a resume refuses any other
    cfg: Recipe
    task: TaskProtocol
    env: Any  # the training env (torchnav.envs.NavEnv or LineEnv)
    device: torch.device
    dir: Path  # the run directory
    logger: Any
    threads: "ThreadGovernor"
    resumed: dict[str, Any] | None  # the checkpoint a resumed run continues (None: a fresh run)
    # collect_s / update_s / eval_s: where the training wall time went (progress output, summary.json);
    # target_unix: the clock time periodic evaluation first reached eval.target_success
    counters: dict[str, Any] = field(default_factory=lambda: {
        "frames": 0, "updates": 0, "batches": 0, "wall_time": 0.0, "collect_s": 0.0, "update_s": 0.0, "eval_s": 0.0,
        "time_to_target": None, "frames_to_target": None, "target_unix": None,
        "eval_frames": None, "eval_score": None, "best_frames": None, "best_score": None})  # the last and the best periodic evaluation
    meta: dict[str, Any] = field(default_factory=dict)  # extra fields of the saved policy (DQN's action table)

    @property
    def fresh(self) -> bool:
        return self.resumed is None

    def remaining_frames(self) -> int:
        return int(self.cfg.train.total_frames) - int(self.counters["frames"])


def setup(name: str, argv: list[str], ckpt_format: str, action_mode: str | None = None) -> Run:
    """Config (``configs/<name>.yaml`` and the command line, or the resumed run's config), seeds, thread
    count, task, run directory, logger and training env; every config problem is named before the run
    directory exists."""
    cfg = load_config(name, argv)
    resume = find_resume(cfg, name)
    ckpt_path, resume_dir = resume if resume is not None else (None, None)
    ckpt = None
    if ckpt_path is not None:
        ckpt = load_checked(ckpt_path)
        if ckpt.get("format") != ckpt_format:
            raise ConfigError(f"{ckpt_path} is not a {name} checkpoint (format {ckpt.get('format')!r}, expected {ckpt_format!r})")
        # from a kept checkpoint file: a new run directory (logger.run_dir, or a new automatic one)
        cfg, changes = resumed_config(ckpt["config"], argv, name, resume_dir or cfg.logger.run_dir,
                                      source=None if resume_dir is not None else ckpt_path)
        for line in changes:
            print(f"resume: {line}")
        if int(ckpt["counters"]["frames"]) >= int(cfg.train.total_frames):
            print(f"resume: the run already has {int(ckpt['counters']['frames']):,} of train.total_frames={int(cfg.train.total_frames):,} "
                  "frames; raise train.total_frames to train on")
    threads = ThreadGovernor(cfg.threads)
    seed_everything(cfg.seed)
    task = task_protocol(cfg)
    if action_mode is not None and task.config.action.mode != action_mode:
        raise ConfigError(f"{name} needs task.action.mode={action_mode}, got {task.config.action.mode!r}")
    run_dir = make_run_dir(cfg, name, resuming=resume_dir is not None)
    if ckpt is not None and resume_dir is None:
        print(f"resume: a new run in {run_dir} continues {ckpt_path} at {int(ckpt['counters']['frames']):,} frames")
    save_config(cfg, run_dir)
    device = torch.device(cfg.device)
    env = task.make_env(int(cfg.env.num_envs), device, int(cfg.seed))
    run = Run(name, ckpt_format, cfg, task, env, device, run_dir, make_logger(cfg, run_dir), threads, ckpt)
    if ckpt is not None:
        run.counters.update(ckpt["counters"])
        if not (run_dir / "best_actor.pt").exists():  # a new run directory continuing a kept checkpoint: no best yet
            run.counters["best_frames"] = run.counters["best_score"] = None
    return run


def task_protocol(cfg: Recipe) -> TaskProtocol:
    """The task protocol (``torchnav.protocol``) of a recipe config, from its ``task`` section: an
    unknown or malformed map or track is named now, before the run directory exists."""
    if isinstance(cfg.task, MultiNavConfig):  # a NavConfig too: checked first
        return MultiNavProtocol(cfg.task)
    if isinstance(cfg.task, NavConfig):
        return NavProtocol(cfg.task, compile_step=cfg.env.compile_step)
    return LineProtocol(cfg.task, laps=cfg.eval.laps)


class RunDirError(ConfigError):
    """A run directory that cannot be used: not writable, or another run's (named before training starts)."""


CLAIM = ".torchnav_run"  # in every run directory: created exclusively by its run, locked while a process writes there
_CLAIMS: dict[Path, int] = {}  # run directory -> the open, locked claim file of this process


def _open_claim(path: Path, exclusive: bool) -> int:
    """``os.open`` of a claim file for writing (``O_EXCL`` when ``exclusive``): the probe that the directory is writable."""
    return os.open(path, os.O_WRONLY | os.O_CREAT | (os.O_EXCL if exclusive else 0), 0o644)


def claim_run_dir(run: Path, fresh: bool) -> None:
    """Make ``run`` this process's run directory, or raise :class:`RunDirError` naming why not.

    A fresh run creates ``run/.torchnav_run`` exclusively (``O_EXCL``: of two runs given the same
    directory at once, exactly one gets it); a resume reopens it. Either way the file is then
    locked (``flock``) for as long as this process lives, or until it claims that directory again,
    so a resume cannot write beside a run still in progress, and a run killed by any signal leaves
    no stale lock. Opening the file for writing is also the probe for a read-only directory, a full
    disk, or a path under a regular file, all named here rather than at the first checkpoint."""
    try:
        run.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunDirError(f"run directory {run}: cannot create it ({type(e).__name__}: {e})") from None
    key = run.resolve()
    if key in _CLAIMS:  # this process's earlier run in that directory has ended: one recipe runs at a time
        os.close(_CLAIMS.pop(key))
    try:
        fd = _open_claim(run / CLAIM, exclusive=fresh)
    except FileExistsError:
        raise RunDirError(f"logger.run_dir={run} already holds a run (or another run is starting in it); "
                          f"continue it with --resume={run} or choose another directory") from None
    except OSError as e:
        raise RunDirError(f"run directory {run} is not writable ({type(e).__name__}: {e}); choose another logger.run_dir or logger.root") from None
    try:
        import fcntl  # POSIX; elsewhere the exclusive creation alone keeps fresh runs apart

        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except ImportError:
        pass
    except OSError:
        os.close(fd)
        raise RunDirError(f"run directory {run} is in use by another process (its {CLAIM} is locked); "
                          "wait for that run to end, or choose another directory") from None
    os.ftruncate(fd, 0)
    os.write(fd, f"pid {os.getpid()} on {os.uname().nodename}\n".encode())
    _CLAIMS[key] = fd


def make_run_dir(cfg: Recipe, name: str, resuming: bool = False) -> Path:
    """The run directory: ``logger.run_dir``, or a new ``<logger.root>/<name>_<time>_seed<seed>``,
    claimed for this process (:func:`claim_run_dir`).

    A new run's directory is created exclusively: an automatic name that exists already
    (two runs started in the same second) gets a ``_2``, ``_3``, ... suffix, and an explicit
    ``logger.run_dir`` that already holds a run, or that another run claimed first, is refused
    (resume it, or pick another). A directory that cannot be written raises :class:`RunDirError`.
    """
    if cfg.logger.run_dir:
        run = Path(cfg.logger.run_dir)
        if not resuming and run.is_dir() and any((run / f).exists() for f in ("checkpoint.pt", "config.yaml", "actor.pt")):
            raise RunDirError(f"logger.run_dir={run} already holds a run; continue it with --resume={run} or choose another directory")
        claim_run_dir(run, fresh=not resuming)
        return run
    stamp = _dt.datetime.now().strftime("%Y%m%d_%H%M%S")
    base = Path(cfg.logger.root) / f"{name}_{stamp}_seed{cfg.seed}"
    try:
        base.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunDirError(f"logger.root={cfg.logger.root}: cannot create it ({type(e).__name__}: {e})") from None
    for i in range(1, 1000):
        run = base if i == 1 else base.with_name(f"{base.name}_{i}")
        try:
            run.mkdir()
        except FileExistsError:
            continue
        except OSError as e:
            raise RunDirError(f"logger.root={cfg.logger.root} is not writable ({type(e).__name__}: {e})") from None
        claim_run_dir(run, fresh=True)
        return run
    raise RunDirError(f"could not create a new run directory next to {base}")


def make_logger(cfg: Recipe, run: Path):
    """TorchRL logger writing into ``<run>/logs`` (CSV by default; TensorBoard; Weights & Biases
    offline unless the environment sets ``WANDB_MODE=online``, with the run's directory name as its name)."""
    check_backend(cfg.logger.backend)
    if cfg.logger.backend == "wandb":
        from torchrl.record.loggers.wandb import WandbLogger

        (run / "logs").mkdir(parents=True, exist_ok=True)
        online = os.environ.get("WANDB_MODE", "offline") == "online"
        return WandbLogger(exp_name=run.name, save_dir=str(run / "logs"), project=os.environ.get("WANDB_PROJECT", "torchnav"),
                           offline=not online, log_env_packages=False)
    from torchrl.record.loggers import get_logger

    return get_logger(cfg.logger.backend, logger_name=str(run), experiment_name="logs")


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


def seed_everything(seed: int) -> None:
    random.seed(seed)
    torch.manual_seed(seed)


def rng_states() -> dict[str, Any]:
    return {"torch": torch.get_rng_state(), "python": list(random.getstate()[1])}


def set_rng_states(sd: dict[str, Any]) -> None:
    torch.set_rng_state(sd["torch"])
    st = random.getstate()
    random.setstate((st[0], tuple(sd["python"]), st[2]))


# --------------------------------------------------------------------------- collection, replay, optimisers


def make_collector(run: Run, policy, random_start: bool = False, env: Any = None) -> Collector | None:
    """TorchRL's collector of the training env (or ``env``, a transformed view of it) over the remaining
    frames (None when none remain); with ``random_start`` a run's first ``train.init_random_frames``
    frames take random actions."""
    remaining, fpb = run.remaining_frames(), int(run.cfg.train.frames_per_batch)
    if remaining <= 0:
        return None
    extra = {"init_random_frames": max(0, int(run.cfg.train.init_random_frames) - int(run.counters["frames"]))} if random_start else {}
    return Collector(run.env if env is None else env, policy, frames_per_batch=fpb, total_frames=max(remaining, fpb), device=run.device,
                     auto_register_policy_transforms=False, **extra)


def restore(run: Run, state: dict[str, Any], collector: Collector | None = None) -> None:
    """A resumed run's ``state`` (``{key: module, optimiser or other state_dict holder}``), env, RNGs and
    collector put back from its checkpoint: the collector's next step continues the episodes in flight
    (a ``set_state`` reset: the env holds them again, nothing new is drawn), so the run goes on exactly
    as if it had never stopped. Nothing to do for a fresh run."""
    ck = run.resumed
    if ck is None:
        return
    for k, m in state.items():
        m.load_state_dict(ck[k])
    run.env.load_state_dict(ck["env"])
    set_rng_states(ck["rng"])
    if collector is not None:
        collector.reset(set_state=True)
    print(f"resuming {run.dir} at {run.counters['frames']:,} frames, {run.task.status(run.env)}")


def make_replay_buffer(run: Run) -> TensorDictReplayBuffer:
    tc = run.cfg.train
    return TensorDictReplayBuffer(storage=LazyTensorStorage(int(tc.buffer_size), device=run.device))  # sampled by replay_updates


class ReplayState:
    """A replay buffer's content and write position as checkpoint state (``state_dict`` /
    ``load_state_dict``), through the buffer's public API: only the filled rows are saved (the
    buffer's own ``state_dict`` holds its whole capacity), and they are written back to the same
    slots with the writer at the same place, so a resumed run samples the same transitions."""

    def __init__(self, buffer: TensorDictReplayBuffer) -> None:
        self.buffer = buffer

    def state_dict(self) -> dict[str, Any]:
        n = len(self.buffer)
        return {"rows": self.buffer[:n].exclude("index").clone().to_dict() if n else None, "write_count": int(self.buffer.write_count)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["rows"] is None:
            return
        rows = TensorDict.from_dict(state["rows"], auto_batch_size=True, batch_dims=1)
        n, cursor = rows.shape[0], int(state["write_count"]) % self.buffer.storage.max_size
        if int(state["write_count"]) <= n:  # not wrapped yet: the rows are the writes in order
            self.buffer.extend(rows)
            return
        # wrapped round: the slots from the cursor on, then those before it, so the writer stands at the cursor
        if cursor:
            self.buffer.extend(rows[:cursor])
        self.buffer.extend(rows[cursor:])
        if cursor:
            self.buffer.extend(rows[:cursor])


def n_step_returns(batch: TensorDictBase, n: int, gamma: float) -> TensorDictBase:
    """The ``(envs, T)`` collector ``batch`` as ``n``-step transitions: each step's ``("next", "reward")`` becomes
    the discounted sum of the rewards of up to ``n`` steps (fewer where the episode ends or the batch does),
    ``("next", "observation")`` and ``("next", "terminated")`` those of the last of them, and ``("next",
    "discount")`` is ``gamma`` to the power of their number: the target is ``reward + discount * (1 - terminated) *
    Q(next)``. A new TensorDict of the replay keys; ``batch`` is left as it was."""
    reward, done, term = batch["next", "reward"], batch["next", "done"], batch["next", "terminated"]
    envs, t_len = batch.shape[:2]
    t = torch.arange(t_len, device=reward.device).expand(envs, t_len)
    total, discount = torch.zeros_like(reward), torch.ones_like(reward)
    last, alive = t.clone(), torch.ones_like(t, dtype=torch.bool)
    for k in range(int(n)):
        j = (t + k).clamp(max=t_len - 1)
        valid = alive & (t + k < t_len)
        take = lambda x: x.gather(1, j.view(envs, t_len, *[1] * (x.dim() - 2)).expand_as(x))  # noqa: E731  x at step t + k
        total = total + torch.where(valid.unsqueeze(-1), discount * take(reward), 0.0)
        discount = torch.where(valid.unsqueeze(-1), discount * gamma, discount)
        last = torch.where(valid, j, last)
        alive = valid & ~take(done).squeeze(-1)
    at_last = lambda x: x.gather(1, last.view(envs, t_len, *[1] * (x.dim() - 2)).expand_as(x))  # noqa: E731
    return TensorDict({"observation": batch["observation"], "action": batch["action"],
                       "next": {"observation": at_last(batch["next", "observation"]), "reward": total, "discount": discount,
                                "done": at_last(done), "terminated": at_last(term)}}, batch_size=batch.shape[:2], device=batch.device)


def replay_updates(run: Run, buffer: TensorDictReplayBuffer, batch: TensorDictBase, step: Callable[[TensorDictBase], dict]) -> dict:
    """Store ``batch`` (as ``train.n_steps``-step transitions where the recipe has that setting above 1), then
    ``train.updates_per_batch`` calls of ``step(sample) -> {name: loss}`` once the buffer holds
    ``train.init_random_frames`` transitions (TD3, SAC, DQN); the last step's losses."""
    tc, out = run.cfg.train, {}
    keys = REPLAY_KEYS
    if int(getattr(tc, "n_steps", 1)) > 1:
        batch, keys = n_step_returns(batch, int(tc.n_steps), float(tc.gamma)), REPLAY_KEYS + (("next", "discount"),)
    buffer.extend(batch.reshape(-1).select(*keys))
    if len(buffer) >= int(tc.init_random_frames):
        # The buffer does not change during the round, so every step's minibatch is drawn in one call (one gather,
        # not one per step): the same distribution, uniform with replacement, at a fraction of the bookkeeping.
        steps, size = int(tc.updates_per_batch), int(tc.batch_size)
        for sample in buffer.sample(steps * size).reshape(steps, size).unbind(0):
            out = step(sample)
            run.counters["updates"] += 1
    return out


class RecurrentCarry:
    """The recurrent state each env carries between steps (``torchnav.policy.with_state``), as
    checkpoint state: :meth:`keep` notes it after every batch, and a resumed run's ``set_state``
    reset hands it back to the envs instead of zeros (``__call__``: the state at a reset,
    ``(num_envs, size)``; the rows of the envs being reset are used)."""

    def __init__(self, num_envs: int, size: int, device: torch.device) -> None:
        self.shape, self.device = (int(num_envs), int(size)), device
        self.carried: torch.Tensor | None = None  # (num_envs, size) after the last batch
        self.pending: torch.Tensor | None = None  # what the next reset hands back (a resumed run's)

    def keep(self, batch: TensorDictBase) -> None:
        last = batch[..., -1]
        self.carried = torch.where(last["next", "done"], 0.0, last["next", STATE_KEY])  # reset envs start from zeros

    def state_dict(self) -> dict[str, Any]:
        return {"carried": self.carried}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.pending = state["carried"]

    def __call__(self) -> torch.Tensor:
        if self.pending is not None:
            value, self.pending = self.pending, None
            return value
        return torch.zeros(self.shape, device=self.device)


@torch.no_grad()
def observation_stats(env, steps: int, key: Any = "observation") -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and standard deviation ``(obs_size,)`` of the observation (``key``: ``("agents", "observation")``
    for the multi-robot env, every robot slot pooled) under random actions for ``steps``
    steps; 0 and 1 for the features the task marks as already scaled (``task.unit_features``). The env
    is left as it was (episodes, curriculum, generator): the rollout is a look, not training."""
    before = env.state_dict()
    td = env.rollout(steps, break_when_any_done=False)
    env.load_state_dict(before)
    obs = td[key].reshape(-1, td[key].shape[-1]).double()
    loc, scale = obs.mean(0).float(), obs.std(0).clamp(min=1e-2).float()
    unit = env.task.unit_features.to(loc.device)
    return loc.masked_fill(unit, 0.0), scale.masked_fill(unit, 1.0)


def adam(params: Iterable[torch.Tensor], **kwargs: Any) -> torch.optim.Adam:
    """``torch.optim.Adam`` with its fused kernel (one kernel per step for all parameters instead of
    several per parameter), where the parameters' device has one, else the plain one. Same
    algorithm, other rounding (docs/performance.md, "Fused Adam")."""
    params = list(params)
    try:
        return torch.optim.Adam(params, fused=True, **kwargs)
    except RuntimeError:  # a device without a fused Adam
        return torch.optim.Adam(params, **kwargs)


class TwinQ(torch.nn.Module):
    """Two independent critics ``Q1(s, a), Q2(s, a)`` (TD3, SAC), each a ReLU MLP over the concatenated
    observation and action. Their weights are stacked, ``(2, in, out)`` a layer, so both critics run as one
    batched matmul per layer (with :func:`replay_updates`' one draw per round, a TD3 gradient step at the
    quick start's sizes takes 0.86 of the time: ``bench/replay_update.py``); each is initialised as
    ``torch.nn.Linear`` would be."""

    def __init__(self, obs_size: int, act_size: int, hidden: Iterable[int]) -> None:
        super().__init__()
        sizes = [int(obs_size) + int(act_size), *(int(h) for h in hidden), 1]
        self.weight, self.bias = torch.nn.ParameterList(), torch.nn.ParameterList()
        for fan_in, fan_out in zip(sizes[:-1], sizes[1:]):
            bound = fan_in ** -0.5  # nn.Linear's default: U(-1/sqrt(fan_in), 1/sqrt(fan_in)) for weight and bias
            self.weight.append(torch.nn.Parameter(torch.empty(2, fan_in, fan_out).uniform_(-bound, bound)))
            self.bias.append(torch.nn.Parameter(torch.empty(2, 1, fan_out).uniform_(-bound, bound)))

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(Q1, Q2)``, each ``(batch, 1)``, of ``obs (batch, obs_size)`` and ``action (batch, act_size)``."""
        x = torch.cat((obs, action), dim=-1).expand(2, -1, -1)
        last = len(self.weight) - 1
        for i, (w, b) in enumerate(zip(self.weight, self.bias)):
            x = torch.baddbmm(b, x, w)
            x = torch.relu(x) if i < last else x
        return x[0], x[1]

    def q1(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """``Q1`` alone (TD3's actor loss), ``(batch, 1)``."""
        x = torch.cat((obs, action), dim=-1)
        last = len(self.weight) - 1
        for i, (w, b) in enumerate(zip(self.weight, self.bias)):
            x = torch.addmm(b[0], x, w[0])
            x = torch.relu(x) if i < last else x
        return x


@torch.no_grad()
def soft_update(target: torch.nn.Module, source: torch.nn.Module, tau: float) -> None:
    """``target <- (1 - tau) target + tau source``, every parameter in one fused call."""
    torch._foreach_lerp_(list(target.parameters()), list(source.parameters()), tau)


def decay_lr(optim: torch.optim.Optimizer, lr: float, frames: int, total_frames: int) -> None:
    """Set ``optim``'s learning rate to ``lr`` falling linearly to 0 at ``total_frames`` (``train.lr_decay``).
    Computed from the frame count, so a resumed run continues the same schedule."""
    keep = max(0.0, 1.0 - frames / total_frames)
    for group in optim.param_groups:
        group["lr"] = float(lr) * keep


# --------------------------------------------------------------------------- the loop's companions


class Progress:
    """What happens around a recipe's update, one call before it (:meth:`collected`) and one after
    (:meth:`updated`): frame counts and where the time went, training episodes' outcome rates and
    statistics, the progress bar and logs, periodic evaluation and checkpoints at multiples of their
    intervals (a resumed run keeps the same schedule), thread count. As a context manager it turns
    SIGTERM/SIGINT into :attr:`stop` (the loop breaks after the batch) and writes a checkpoint on any
    exit; ``state`` and ``actor`` (a function returning the deterministic actor) are what it saves."""

    def __init__(self, run: Run, state: dict[str, Any], actor: Callable[[], Actor | RecurrentActor]) -> None:
        self.run, self.state, self.actor = run, state, actor
        self.recent: collections.deque = collections.deque(maxlen=RECENT_EPISODES)  # outcome flags of recent training episodes
        self.losses: dict[str, Any] = {}
        self.stop = False

    def __enter__(self) -> Progress:
        c = self.run.counters
        self._old = {sig: signal.signal(sig, self._signal) for sig in (signal.SIGTERM, signal.SIGINT)}
        self.bar = tqdm(total=int(self.run.cfg.train.total_frames), initial=int(c["frames"]), unit="fr",
                        disable=not self.run.cfg.logger.progress, dynamic_ncols=True)
        self.t_start = time.perf_counter() - c["wall_time"]
        self.t_mark = time.perf_counter()
        return self

    def _signal(self, signum, frame) -> None:  # noqa: ARG002
        if self.stop:  # a second signal: give up at once
            signal.signal(signum, self._old[signum])
            raise KeyboardInterrupt
        self.stop = True
        print(f"\nreceived signal {signum}: finishing this batch, writing a checkpoint, then exiting", file=sys.stderr, flush=True)

    def __exit__(self, kind, value, tb) -> bool:
        self.bar.close()
        for sig, h in self._old.items():
            signal.signal(sig, h)
        save(self.run, self.state, self.actor())
        if kind is KeyboardInterrupt:
            print("\ninterrupted: checkpoint written", file=sys.stderr)
            self.stop = True
            return True
        return False

    def collected(self, batch: TensorDictBase) -> None:
        c, now = self.run.counters, time.perf_counter()
        c["collect_s"] += now - self.t_mark
        self.t_mark = now
        self.n = batch.numel()
        c["frames"] += self.n
        c["batches"] += 1
        self._episode_stats(batch.reshape(-1))

    def updated(self, losses: dict[str, Any] | None) -> None:
        run, cfg, c = self.run, self.run.cfg, self.run.counters
        self.losses = losses or self.losses
        now = time.perf_counter()
        c["update_s"] += now - self.t_mark
        c["wall_time"] = now - self.t_start
        rates = {k: sum(r[i] for r in self.recent) / max(len(self.recent), 1) for i, k in enumerate(run.task.outcome_keys)}
        fps = c["frames"] / max(c["wall_time"], 1e-9)
        self.bar.update(self.n)
        self.bar.set_postfix_str(" ".join(f"{k} {100 * v:.0f}%" for k, v in rates.items()) + f" {run.task.status(run.env)} {fps:,.0f} fr/s")
        if c["batches"] % 10 == 0:
            for k, v in {**{f"train/{k}_rate": v for k, v in rates.items()}, "perf/frames_per_s": fps, "time/wall_s": c["wall_time"],
                         **{f"loss/{k}": float(v) for k, v in self.losses.items()}, **run.task.scalars(run.env)}.items():
                run.logger.log_scalar(k, v, step=c["frames"])
        if self._due(cfg.eval.interval_frames):
            self.evaluate()
        if self._due(cfg.checkpoint.interval_frames):
            save(run, self.state, self.actor())
            if cfg.checkpoint.keep:
                keep_copy(run.dir / "checkpoint.pt", run.dir / "checkpoints" / f"{int(c['frames'])}.pt")
        if run.threads.update() is not None:
            t = run.threads
            steal = f", hypervisor steal {t.steal:.1f} of it" if t.steal >= 0.05 else ""
            self.bar.write(f"[threads] {t.threads} (other processes use {t.changes[-1][2]:.1f} of {t.cores} cores{steal})")
        self.t_mark = time.perf_counter()  # evaluation and checkpoints are not collection

    def _due(self, interval: int) -> bool:
        """Whether the last batch crossed a multiple of ``interval`` frames (0: never)."""
        f = int(self.run.counters["frames"])
        return bool(interval) and f // int(interval) > (f - self.n) // int(interval)

    def evaluate(self) -> None:
        run, c = self.run, self.run.counters
        t0 = time.perf_counter()
        s = periodic_evaluation(run, self.actor())
        c["eval_s"] += time.perf_counter() - t0
        c["wall_time"] = time.perf_counter() - self.t_start
        log_rates(run.logger, "eval", s, c["frames"])
        run.logger.log_scalar("eval/wall_s", c["wall_time"], step=c["frames"])
        self.bar.write(f"[eval @ {c['frames']:,} frames, {c['wall_time']:.0f} s] {run.task.describe(s)}")
        if c["time_to_target"] is None and s["score"] >= run.cfg.eval.target_success:
            c["time_to_target"], c["frames_to_target"], c["target_unix"] = c["wall_time"], c["frames"], time.time()

    def _episode_stats(self, flat: TensorDictBase) -> None:
        done = flat["next", "done"].reshape(-1)
        if not done.any():
            return
        nxt = flat["next"][done]
        self.recent.extend(zip(*[nxt[k].reshape(-1).tolist() for k in self.run.task.outcome_keys]))
        if "episode" not in nxt.keys():  # the multi-robot env has no episode statistics
            return
        ep = nxt["episode"]
        for k in ep.keys():
            self.run.logger.log_scalar(f"episode/{k}", ep[k].float().mean().item(), step=self.run.counters["frames"])


def evaluate(run: Run, actor: Actor | RecurrentActor, episodes: int, seed: int) -> dict[str, Any]:
    """The task's evaluation of the deterministic ``actor`` (``episodes`` episodes from ``seed``)."""
    was_training = actor.training
    actor.eval()
    try:
        return run.task.evaluate(to_policy(actor), episodes, seed, run.device)
    finally:
        actor.train(was_training)


def _periodic_summary(run: Run, actor: Actor | RecurrentActor) -> dict[str, Any]:
    return evaluate(run, actor, int(run.cfg.eval.episodes), PERIODIC_EVAL_SEED + int(run.cfg.seed))


def periodic_evaluation(run: Run, actor: Actor | RecurrentActor) -> dict[str, Any]:
    """The periodic evaluation of ``actor`` (``eval.episodes`` episodes from the periodic seeds, never the final
    evaluation's); notes its score in the counters and, with ``eval.keep_best``, writes ``best_actor.pt`` when it
    scores at least the best so far."""
    c = run.counters
    s = _periodic_summary(run, actor)
    c["eval_frames"], c["eval_score"] = int(c["frames"]), float(s["score"])
    if run.cfg.eval.keep_best and (c["best_score"] is None or s["score"] >= c["best_score"]):
        save_policy(run.dir / "best_actor.pt", actor, **policy_meta(run), periodic_eval={"frames": int(c["frames"]), "score": float(s["score"])})
        c["best_frames"], c["best_score"] = int(c["frames"]), float(s["score"])
    return s


def select_best(run: Run, actor: Actor | RecurrentActor) -> dict[str, Any] | None:
    """With ``eval.keep_best``: the last ``actor``'s periodic score (evaluated now if its batch was not; that
    evaluation writes nothing, since the checkpoint is already written), then the best periodic evaluation's
    weights (``best_actor.pt``) loaded into ``actor`` and written as ``actor.pt`` when they scored higher than the
    last; what was chosen (None without ``keep_best``)."""
    c = run.counters
    if not run.cfg.eval.keep_best or c["best_frames"] is None:
        return None
    last = c["eval_score"]
    if c["eval_frames"] != int(c["frames"]):
        t0 = time.perf_counter()
        last = float(_periodic_summary(run, actor)["score"])
        c["eval_s"] += time.perf_counter() - t0
    if last >= c["best_score"]:
        return {"kept": "last", "frames": int(c["frames"]), "periodic_score": last}
    best = load_policy(run.dir / "best_actor.pt", map_location=run.device)
    actor.load_state_dict(best.actor.state_dict())
    save_policy(run.dir / "actor.pt", actor, **policy_meta(run))
    return {"kept": "best", "frames": c["best_frames"], "periodic_score": c["best_score"], "last_periodic_score": last}


def policy_meta(run: Run) -> dict[str, Any]:
    return {"task": run.task.name, "task_config": run.task.task_config(), "algorithm": run.name.split("_")[0], **run.meta}


def save(run: Run, state: dict[str, Any], actor: Actor | RecurrentActor) -> None:
    """``checkpoint.pt`` (everything to resume: ``state``, env, RNGs, counters, config, policy) and
    ``actor.pt`` (the deterministic policy), both content-hashed and written atomically."""
    meta = policy_meta(run)
    save_checked(run.dir / "checkpoint.pt", {
        "format": run.ckpt_format, **{k: m.state_dict() for k, m in state.items()}, "env": run.env.state_dict(), "rng": rng_states(),
        "counters": dict(run.counters), "config": to_dict(run.cfg), "policy": policy_payload(actor, **meta)})
    save_policy(run.dir / "actor.pt", actor, **meta)


def keep_copy(checkpoint: Path, kept: Path) -> None:
    """``kept`` as another name of ``checkpoint`` (a hard link; a copy where links are refused). The next
    save renames a new file onto ``checkpoint``, so ``kept`` goes on holding this one."""
    kept.parent.mkdir(exist_ok=True)
    kept.unlink(missing_ok=True)
    try:
        os.link(checkpoint, kept)
    except OSError:
        shutil.copyfile(checkpoint, kept)


def log_rates(logger, prefix: str, summary: dict[str, Any], step: int) -> None:
    """``<prefix>/<outcome>_rate`` for every rate in an evaluation summary, and ``<prefix>/score``."""
    for k, v in summary.items():
        if isinstance(v, dict) and "rate" in v:
            logger.log_scalar(f"{prefix}/{k}_rate", v["rate"], step=step)
    logger.log_scalar(f"{prefix}/score", summary["score"], step=step)


def stopped(run: Run) -> dict[str, Any]:
    """What a run stopped by a signal returns (its checkpoint is written)."""
    print(f"stopped at {run.counters['frames']:,} frames; checkpoint in {run.dir / 'checkpoint.pt'}; continue with --resume={run.dir}")
    return {"run_dir": str(run.dir), "stopped": True, "counters": run.counters}


def finish(run: Run, actor: Actor | RecurrentActor) -> dict[str, Any]:
    """Final evaluation on ``eval.final_episodes`` episodes, MCAP episodes, ``summary.json``; prints the table."""
    cfg, c = run.cfg, run.counters
    selected = select_best(run, actor)
    t0 = time.perf_counter()
    summary = evaluate(run, actor, int(cfg.eval.final_episodes), FINAL_EVAL_SEED + int(cfg.seed))
    result = {
        "run_dir": str(run.dir), run.task.place: run.task.where(), "frames": c["frames"], "updates": c["updates"],
        "train_wall_s": c["wall_time"], "time_to_target_s": c["time_to_target"],
        "frames_to_target": c["frames_to_target"], "target_unix": c["target_unix"],
        "collect_s": c["collect_s"], "update_s": c["update_s"], "periodic_eval_s": c["eval_s"],
        "threads": run.threads.changes or run.threads.threads,  # [(s into the run, threads, others' cores)] with auto
        "selected": selected, "eval": summary, "eval_wall_s": time.perf_counter() - t0,
    }
    log_rates(run.logger, "final", summary, c["frames"])
    if cfg.eval.record_episodes:
        rec = run.task.record(to_policy(actor), run.dir / "episodes.mcap", int(cfg.eval.record_episodes), FINAL_EVAL_SEED + int(cfg.seed),
                              run.device, {"checkpoint": str(run.dir / "actor.pt"), "config": to_dict(cfg)})
        result["episodes_mcap"] = None if rec.error else str(run.dir / "episodes.mcap")
        if result["episodes_mcap"]:
            result["trajectories_png"] = draw_recorded(run.dir / "episodes.mcap", run.dir / "trajectories.png")
    write_json(run.dir / "summary.json", result)
    print()
    print(run.task.format(summary))
    print(f"  time: collection {c['collect_s']:.0f} s ({c['frames'] / max(c['collect_s'], 1e-9):,.0f} frames/s), "
          f"updates {c['update_s']:.0f} s ({c['frames'] / max(c['update_s'], 1e-9):,.0f} frames/s), periodic evaluation {c['eval_s']:.0f} s")
    print(f"  trained {c['frames']:,} frames, {c['updates']:,} updates in {c['wall_time']:.0f} s"
          + (f"; reached {100 * cfg.eval.target_success:.0f}% at {c['time_to_target']:.0f} s" if c["time_to_target"] else ""))
    if selected is not None and selected["kept"] == "best":
        print(f"  kept the actor of the periodic evaluation at {selected['frames']:,} frames ({100 * selected['periodic_score']:.1f}%; "
              f"the last actor's: {100 * selected['last_periodic_score']:.1f}%); the final evaluation above is of that actor")
    print(f"  files in {run.dir}:")
    print(f"    actor.pt          the policy: python recipes/evaluate.py {run.dir / 'actor.pt'}")
    if result.get("episodes_mcap"):
        print(f"    episodes.mcap     {int(cfg.eval.record_episodes)} final-evaluation episodes: open in Foxglove (docs/foxglove.md), "
              f"or python -m torchnav.record.replay {result['episodes_mcap']} --out episode.gif")
    if result.get("trajectories_png"):
        print("    trajectories.png  the paths of those episodes")
    print("    checkpoint.pt     everything to continue: --resume; summary.json; logs/")
    return result


def draw_recorded(mcap: Path, png: Path) -> str | None:
    """``png``: the paths of every episode in the recording ``mcap`` (``torchnav.record.replay.plot_episodes``); its
    path, or None with the reason printed when it cannot be drawn (the run's results stand without it)."""
    from torchnav.record.reader import read_recording
    from torchnav.record.replay import plot_episodes

    try:
        return str(plot_episodes(read_recording(mcap), png))
    except (OSError, ValueError) as e:
        print(f"  (no trajectories.png: {e})", file=sys.stderr)
        return None


def write_json(path: Path, obj: Any) -> None:
    write_atomic(path, json.dumps(obj, indent=2))


# --------------------------------------------------------------------------- the machine and the command line


class ThreadGovernor:
    """torch's CPU thread count, chosen from the cores other processes leave free and re-checked as a run goes.

    Two torch threads on two cores collapse when another process is busy: OpenMP's threads spin
    waiting for each other while one of them is descheduled (docs/performance.md#contention).
    ``threads: auto`` therefore measures, over each ``interval`` s, the CPU time of the whole
    machine (``/proc/stat``) less this process's own and its finished children's (``os.times``),
    and sets as many threads as cores are left free: at least 1, at most the cores this process
    may use. A fixed ``threads: N`` sets N once and never changes it; so does ``auto`` where
    ``/proc/stat`` is missing or counts other cores than this process may use (not Linux, some containers).
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


def main_guard(main: Callable[[list[str]], Any]) -> None:
    """Run ``main(sys.argv[1:])`` for a command-line tool: bad input (a config, map, track or
    checkpoint error, a missing file, any ValueError naming what is wrong) becomes one line on
    stderr and exit code 2 instead of a traceback."""
    try:
        main(sys.argv[1:])
    except (ConfigError, FileNotFoundError, ValueError) as e:  # MapError, TrackError, CheckpointError are ValueErrors
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
