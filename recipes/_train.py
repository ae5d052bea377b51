"""The training loop every recipe shares: setup, progress, episode statistics, periodic
evaluation, checkpoints, Ctrl-C/SIGTERM, final evaluation and MCAP episodes.

A recipe builds its networks and loss, names what its checkpoint holds beyond the env,
RNG and counters (``Trainer.restore(modules)``), then hands ``Trainer.train`` a collector
(``Trainer.collector(policy)``) and an ``update(batch) -> {name: loss}`` function.
What differs between tasks (env, evaluation, recording, progress fields) is the task
protocol's (``torchnav.protocol``), picked by the config's ``task`` section (``NavConfig`` or ``LineConfig``).
"""

from __future__ import annotations

import collections
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterable

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.collectors import Collector
from tqdm import tqdm

import _common as C

from torchnav.evaluation import FINAL_EVAL_SEED, PERIODIC_EVAL_SEED
from torchnav.policy import Actor, policy_payload, save_policy, to_policy


RECENT_EPISODES = 500  # training episodes behind the train/<outcome>_rate figures of the progress bar and logs


class Trainer:
    """Setup and loop of one recipe run; see the module docstring."""

    def __init__(self, name: str, argv: list[str], ckpt_format: str, action_mode: str | None = None) -> None:
        self.name, self.ckpt_format = name, ckpt_format
        cfg = C.load_config(name, argv)
        resume = C.find_resume(cfg, name)
        ckpt_path, resume_dir = resume if resume is not None else (None, None)
        self.ckpt: dict[str, Any] | None = None
        if ckpt_path is not None:
            self.ckpt = C.load_checkpoint(ckpt_path)
            if self.ckpt.get("format") != ckpt_format:
                raise C.ConfigError(f"{ckpt_path} is not a {name} checkpoint (format {self.ckpt.get('format')!r})")
            # from a kept checkpoint file: a new run directory (logger.run_dir, or a new automatic one)
            cfg, changes = C.resumed_config(self.ckpt["config"], argv, name, resume_dir or cfg.logger.run_dir,
                                            source=None if resume_dir is not None else ckpt_path)
            for line in changes:
                print(f"resume: {line}")
            if int(self.ckpt["counters"]["frames"]) >= int(cfg.train.total_frames):
                print(f"resume: the run already has {int(self.ckpt['counters']['frames']):,} of train.total_frames={int(cfg.train.total_frames):,} "
                      "frames; raise train.total_frames to train on")
        self.cfg = cfg
        self.threads = C.ThreadGovernor(cfg.threads)
        C.seed_everything(cfg.seed)
        self.device = torch.device(cfg.device)
        self.task = C.task_protocol(cfg)
        if action_mode is not None and self.task.config.action.mode != action_mode:
            raise C.ConfigError(f"{name} needs task.action.mode={action_mode}, got {self.task.config.action.mode!r}")
        self.run = C.make_run_dir(cfg, name, resuming=resume_dir is not None)
        if ckpt_path is not None and resume_dir is None:
            print(f"resume: a new run in {self.run} continues {ckpt_path} at {int(self.ckpt['counters']['frames']):,} frames")
        C.save_config(cfg, self.run)
        self.logger = C.make_logger(cfg, self.run)
        self.env = self.task.make_env(int(cfg.env.num_envs), self.device, int(cfg.seed))
        # collect_s / update_s / eval_s: where the training wall time went (progress output, summary.json);
        # target_unix: the clock time (time.time()) periodic evaluation first reached eval.target_success,
        # so a benchmark that launched the command can tell the time from its start
        self.counters: dict[str, Any] = {"frames": 0, "updates": 0, "batches": 0, "wall_time": 0.0,
                                         "collect_s": 0.0, "update_s": 0.0, "eval_s": 0.0,
                                         "time_to_target": None, "frames_to_target": None, "target_unix": None}
        # the deterministic actor to evaluate and save; each recipe sets this after building its networks
        self.export_actor: Callable[[], Actor] = self._no_actor
        self.modules: dict[str, Any] = {}
        self._collector: Any = None

    @property
    def fresh(self) -> bool:
        return self.ckpt is None

    def restore(self, modules: dict[str, Any]) -> None:
        """``{key: module_or_optimizer}``: what checkpoints save beyond env, RNG and counters; loaded, with
        those, from the resumed checkpoint."""
        self.modules = modules
        if self.ckpt is None:
            return
        for k, m in modules.items():
            if k not in self.ckpt and isinstance(m, ReplayState):
                print(f"resume: {self.run} holds no replay buffer (written by an older torchnav); it starts empty")
                continue
            m.load_state_dict(self.ckpt[k])
        self.env.load_state_dict(self.ckpt["env"])
        C.set_rng_states(self.ckpt["rng"])
        self.counters.update(self.ckpt["counters"])
        print(f"resuming {self.run} at {self.counters['frames']:,} frames, {self.task.status(self.env)}")

    def remaining_frames(self) -> int:
        return int(self.cfg.train.total_frames) - int(self.counters["frames"])

    def collector(self, policy, random_start: bool = False, env: Any = None) -> Collector | None:
        """TorchRL's collector of the env (or ``env``, a transformed view of it) over the remaining frames
        (None when none remain); with ``random_start`` a run's first ``train.init_random_frames`` frames
        take random actions."""
        remaining, fpb = self.remaining_frames(), int(self.cfg.train.frames_per_batch)
        extra = {"init_random_frames": max(0, int(self.cfg.train.init_random_frames) - int(self.counters["frames"]))} if random_start else {}
        return Collector(self.env if env is None else env, policy, frames_per_batch=fpb, total_frames=max(remaining, fpb), device=self.device,
                         auto_register_policy_transforms=False, **extra) if remaining > 0 else None

    def policy_meta(self, **extra: Any) -> dict[str, Any]:
        return {"task": self.task.name, "task_config": self.task.task_config(), "algorithm": self.name.split("_")[0], **extra}

    def save(self, meta: dict[str, Any]) -> None:
        """``checkpoint.pt`` (everything to resume) and ``actor.pt`` (the deterministic policy), both atomic."""
        actor = self.export_actor()
        carrier = getattr(self._collector, "_carrier", None)  # the collector's current step (TorchRL keeps it private)
        C.save_checkpoint(self.run / "checkpoint.pt", {
            "format": self.ckpt_format, **{k: m.state_dict() for k, m in self.modules.items()}, "env": self.env.state_dict(), "rng": C.rng_states(),
            **({"carrier": carrier.clone().to_dict()} if carrier is not None else {}),
            "counters": dict(self.counters), "config": C.config_dict(self.cfg), "policy": policy_payload(actor, **meta),
        })
        save_policy(self.run / "actor.pt", actor, **meta)

    def _no_actor(self) -> Actor:
        raise RuntimeError(f"{self.name}: the recipe did not set Trainer.export_actor")

    def evaluate(self, episodes: int, seed: int) -> dict[str, Any]:
        actor = self.export_actor()
        was_training = actor.training
        actor.eval()
        try:
            return self.task.evaluate(to_policy(actor), episodes, seed, self.device)
        finally:
            actor.train(was_training)

    def train(self, collector: Iterable[TensorDictBase] | None, update: Callable[[TensorDictBase], dict[str, float]],
              meta: dict[str, Any] | None = None, on_frames: Callable[[int], None] | None = None) -> dict[str, Any]:
        """Run the loop, then :meth:`finish`; stopped by a signal, it returns ``{"stopped": True, ...}``
        instead (a checkpoint was written either way)."""
        cfg, c, log = self.cfg, self.counters, self.logger
        meta = meta or self.policy_meta()
        self._collector = collector
        if self.ckpt is not None and collector is not None and "carrier" in self.ckpt:
            # Making the collector reset every env: put back the episodes in flight, the step the
            # collector was at and the RNGs, so a resumed run continues exactly where it stopped.
            self.env.load_state_dict(self.ckpt["env"])
            collector._carrier = TensorDict.from_dict(self.ckpt["carrier"], batch_size=self.env.batch_size, device=self.env.device)
            C.set_rng_states(self.ckpt["rng"])
        recent = collections.deque(maxlen=RECENT_EPISODES)  # outcome flags of recent training episodes
        stop = C.StopFlag()
        bar = tqdm(total=int(cfg.train.total_frames), initial=int(c["frames"]), unit="fr", disable=not cfg.logger.progress, dynamic_ncols=True)
        # evaluation and checkpoints at multiples of their intervals, so a resumed run keeps the same schedule
        every = lambda interval: int(c["frames"]) // int(interval) if interval else 0  # noqa: E731
        last_ckpt, last_eval = every(cfg.checkpoint.interval_frames), every(cfg.eval.interval_frames)
        t_start = time.perf_counter() - c["wall_time"]
        losses: dict[str, float] = {}
        try:
            t_mark = time.perf_counter()
            for batch in collector or ():
                t_got = time.perf_counter()
                c["collect_s"] += t_got - t_mark
                n = batch.numel()
                c["frames"] += n
                c["batches"] += 1
                if on_frames is not None:
                    on_frames(n)
                self._episode_stats(batch.reshape(-1), recent)
                losses = update(batch) or losses
                t_mark = time.perf_counter()
                c["update_s"] += t_mark - t_got
                c["wall_time"] = t_mark - t_start
                rates = {k: sum(r[i] for r in recent) / max(len(recent), 1) for i, k in enumerate(self.task.outcome_keys)}
                fps = c["frames"] / max(c["wall_time"], 1e-9)
                bar.update(n)
                bar.set_postfix_str(" ".join(f"{k} {100 * v:.0f}%" for k, v in rates.items()) + f" {self.task.status(self.env)} {fps:,.0f} fr/s")
                if c["batches"] % 10 == 0:
                    for k, v in {**{f"train/{k}_rate": v for k, v in rates.items()}, "perf/frames_per_s": fps,
                                 "time/wall_s": c["wall_time"], **{f"loss/{k}": float(v) for k, v in losses.items()},
                                 **self.task.scalars(self.env)}.items():
                        log.log_scalar(k, v, step=c["frames"])
                if cfg.eval.interval_frames and every(cfg.eval.interval_frames) > last_eval:
                    last_eval = every(cfg.eval.interval_frames)
                    t_eval = time.perf_counter()
                    s = self.evaluate(int(cfg.eval.episodes), PERIODIC_EVAL_SEED + int(cfg.seed))
                    c["eval_s"] += time.perf_counter() - t_eval
                    c["wall_time"] = time.perf_counter() - t_start
                    _log_rates(log, "eval", s, c["frames"])
                    log.log_scalar("eval/wall_s", c["wall_time"], step=c["frames"])
                    bar.write(f"[eval @ {c['frames']:,} frames, {c['wall_time']:.0f} s] {self.task.describe(s)}")
                    if c["time_to_target"] is None and s["score"] >= cfg.eval.target_success:
                        c["time_to_target"], c["frames_to_target"], c["target_unix"] = c["wall_time"], c["frames"], time.time()
                if every(cfg.checkpoint.interval_frames) > last_ckpt:
                    last_ckpt = every(cfg.checkpoint.interval_frames)
                    self.save(meta)
                    if cfg.checkpoint.keep:
                        _keep(self.run / "checkpoint.pt", self.run / "checkpoints" / f"{int(c['frames'])}.pt")
                if self.threads.update() is not None:
                    steal = f", hypervisor steal {self.threads.steal:.1f} of it" if self.threads.steal >= 0.05 else ""
                    bar.write(f"[threads] {self.threads.threads} (other processes use {self.threads.changes[-1][2]:.1f} of {self.threads.cores} cores{steal})")
                if stop.stop:
                    break
                t_mark = time.perf_counter()  # checkpoints and evaluation are not collection
        except KeyboardInterrupt:
            print("\ninterrupted: writing a checkpoint", file=sys.stderr)
            stop.stop = True
        finally:
            bar.close()
            stop.restore()
            self.save(meta)  # before shutdown, which drops the collector's current step
            if collector is not None and hasattr(collector, "shutdown"):
                collector.shutdown()
        if stop.stop:
            print(f"stopped at {c['frames']:,} frames; checkpoint in {self.run / 'checkpoint.pt'}; continue with --resume={self.run}")
            return {"run_dir": str(self.run), "stopped": True, "counters": c}
        return self.finish()

    def _episode_stats(self, flat: TensorDictBase, recent: collections.deque) -> None:
        done = flat["next", "done"].reshape(-1)
        if not done.any():
            return
        nxt = flat["next"][done]
        flags = [nxt[k].reshape(-1).tolist() for k in self.task.outcome_keys]
        recent.extend(zip(*flags))
        ep = nxt["episode"]
        step = self.counters["frames"]
        for k in ep.keys():
            self.logger.log_scalar(f"episode/{k}", ep[k].float().mean().item(), step=step)

    def finish(self) -> dict[str, Any]:
        """Final evaluation on ``eval.final_episodes`` episodes, MCAP episodes, ``summary.json``; prints the table."""
        cfg, c = self.cfg, self.counters
        t0 = time.perf_counter()
        summary = self.evaluate(int(cfg.eval.final_episodes), FINAL_EVAL_SEED + int(cfg.seed))
        result = {
            "run_dir": str(self.run), self.task.place: self.task.where(), "frames": c["frames"], "updates": c["updates"],
            "train_wall_s": c["wall_time"], "time_to_target_s": c["time_to_target"],
            "frames_to_target": c["frames_to_target"], "target_unix": c["target_unix"],
            "collect_s": c["collect_s"], "update_s": c["update_s"], "periodic_eval_s": c["eval_s"],
            "threads": self.threads.changes or self.threads.threads,  # [(s into the run, threads, others' cores)] with auto
            "eval": summary, "eval_wall_s": time.perf_counter() - t0,
        }
        _log_rates(self.logger, "final", summary, c["frames"])
        if cfg.eval.record_episodes:
            rec = self.task.record(to_policy(self.export_actor()), self.run / "episodes.mcap", int(cfg.eval.record_episodes),
                                   FINAL_EVAL_SEED + int(cfg.seed), self.device,
                                   {"checkpoint": str(self.run / "actor.pt"), "config": C.config_dict(cfg)})
            result["episodes_mcap"] = None if rec.error else str(self.run / "episodes.mcap")
        C.write_json(self.run / "summary.json", result)
        print()
        print(self.task.format(summary))
        print(f"  time: collection {c['collect_s']:.0f} s ({c['frames'] / max(c['collect_s'], 1e-9):,.0f} frames/s), "
              f"updates {c['update_s']:.0f} s ({c['frames'] / max(c['update_s'], 1e-9):,.0f} frames/s), periodic evaluation {c['eval_s']:.0f} s")
        print(f"  trained {c['frames']:,} frames, {c['updates']:,} updates in {c['wall_time']:.0f} s"
              + (f"; reached {100 * cfg.eval.target_success:.0f}% at {c['time_to_target']:.0f} s" if c["time_to_target"] else ""))
        print(f"  run directory: {self.run}  (actor.pt, checkpoint.pt, summary.json, logs/)")
        return result


def _keep(checkpoint: Path, kept: Path) -> None:
    """``kept`` as another name of ``checkpoint`` (a hard link; a copy where links are refused). The next
    save renames a new file onto ``checkpoint``, so ``kept`` goes on holding this one."""
    kept.parent.mkdir(exist_ok=True)
    kept.unlink(missing_ok=True)
    try:
        os.link(checkpoint, kept)
    except OSError:
        shutil.copyfile(checkpoint, kept)


def _log_rates(logger, prefix: str, summary: dict[str, Any], step: int) -> None:
    """``<prefix>/<outcome>_rate`` for every rate in an evaluation summary, and ``<prefix>/score``."""
    for k, v in summary.items():
        if isinstance(v, dict) and "rate" in v:
            logger.log_scalar(f"{prefix}/{k}_rate", v["rate"], step=step)
    logger.log_scalar(f"{prefix}/score", summary["score"], step=step)


REPLAY_KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"), ("next", "done"), ("next", "terminated"))


class ReplayState:
    """A replay buffer's content and write position as checkpoint state: add it to a recipe's
    checkpointed modules (``state_dict``/``load_state_dict``) and a resumed run samples the
    same transitions. Only the filled rows are saved."""

    def __init__(self, buffer) -> None:
        self.buffer = buffer

    def state_dict(self) -> dict[str, Any]:
        b = self.buffer
        rows = b.storage._storage[: len(b)].clone() if len(b) else None  # a copy: a view would save the whole capacity
        return {"rows": None if rows is None else rows.to_dict(), "cursor": b._writer._cursor, "write_count": b._writer._write_count}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["rows"] is not None:
            rows = TensorDict.from_dict(state["rows"], auto_batch_size=True, batch_dims=1)
            self.buffer.extend(rows.exclude("index") if "index" in rows.keys() else rows)
        self.buffer._writer._cursor, self.buffer._writer._write_count = state["cursor"], state["write_count"]


def replay_update(trainer: Trainer, buffer, step_fn) -> Callable[[TensorDictBase], dict[str, float]]:
    """An ``update(batch)`` that stores the batch, then runs ``train.updates_per_batch`` calls of
    ``step_fn(sample) -> {name: loss}`` once the buffer holds ``train.init_random_frames`` (TD3 and SAC)."""
    tc = trainer.cfg.train

    def update(batch):
        buffer.extend(batch.reshape(-1).select(*REPLAY_KEYS))
        out = {}
        if len(buffer) >= int(tc.init_random_frames):
            for _ in range(int(tc.updates_per_batch)):
                out = step_fn(buffer.sample())
                trainer.counters["updates"] += 1
        return out

    return update
