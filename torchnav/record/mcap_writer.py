"""Episode recorder: a few envs of a batch -> an MCAP file that opens in Foxglove.

JSON messages with JSON Schemas (``schemas.py``) in zstd-compressed chunks, stamped in simulation
time (strictly increasing on every channel). The topics, frames and crash safety (every finished
chunk is on disk; a file cut short still reads) are in docs/foxglove.md. Write errors are reported
once as a warning and turn the recorder off; training goes on."""

from __future__ import annotations

import atexit
import json
import os
import signal
import threading
import time
import warnings
import weakref
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

from .. import __version__
from ..sim import camera_image, mover_world
from . import scene
from .schemas import action_schema, event_schema, foxglove_schema, imu_schema, movers_schema, reward_schema


def mover_rows(sim: Any) -> Any:
    """The movers of a batch of simulator states as recorded: ``(B, M, 6)`` rows ``[x, y, vx, vy, radius,
    exists]``, with ``[half_x, half_y, yaw]`` appended (``(B, M, 9)``, zeros for discs) when the last
    ``K > 0`` movers are boxes (``SimState.mover_boxes``)."""
    m, k = sim.movers, sim.mover_boxes.shape[1]
    rows = torch.cat((m[..., :5], sim.mover_mask[..., None].to(m.dtype)), -1)
    if not k:
        return rows
    return torch.cat((rows, torch.cat((m.new_zeros(m.shape[0], m.shape[1] - k, 3), sim.mover_boxes), 1)), -1)


class RecordingWarning(UserWarning):
    """Recording stopped (write error) or is incomplete; training is not affected."""


_OPEN: "weakref.WeakSet[EpisodeRecorder]" = weakref.WeakSet()
_SIG = {"installed": False, "previous": None, "pending": None}


def _close_all() -> None:
    for rec in list(_OPEN):
        rec.close()


atexit.register(_close_all)


def _on_sigterm(signum, frame):  # noqa: ARG001
    # Raise in the main thread so that ``with`` blocks and ``finally`` clauses unwind
    # and close every recorder; never in the middle of a record write.
    if any(r._writing for r in list(_OPEN)):
        _SIG["pending"] = signum
        return
    raise SystemExit(128 + signum)


def _install_sigterm() -> None:
    if _SIG["installed"] or threading.current_thread() is not threading.main_thread():
        return
    prev = signal.getsignal(signal.SIGTERM)
    if prev not in (signal.SIG_DFL, None):
        return  # the application handles SIGTERM itself
    signal.signal(signal.SIGTERM, _on_sigterm)
    _SIG.update(installed=True, previous=prev)


def _uninstall_sigterm() -> None:
    if _SIG["installed"] and not _OPEN and threading.current_thread() is threading.main_thread():
        if signal.getsignal(signal.SIGTERM) is _on_sigterm:
            signal.signal(signal.SIGTERM, _SIG["previous"])
        _SIG["installed"] = False


class EpisodeRecorder:
    """Record envs ``envs`` of a batched ``NavEnv`` (or ``LineEnv``, or ``MultiNavEnv``: every robot of
    those envs, docs/foxglove.md "Several robots per env") to an MCAP file at ``path``.

    Args:
        path: output file (parent directories are created). Steps are written to
            ``partial_path`` (``<stem>.partial.mcap`` beside it) and renamed onto ``path`` when the
            recording closes, so an existing file is replaced only by a complete one: a recording
            killed or stopped by a write error leaves the previous file whole, and its own steps,
            up to the last flush, readable in ``partial_path``. A ``path`` that exists and is not a
            regular file (a FIFO, ``/dev/full``) is written in place.
        env: the ``NavEnv`` whose steps are recorded (config, lidar layout, reward terms, dt).
        envs: indices of the recorded envs in the batch.
        metadata: extra entries of the ``torchnav`` metadata record (seed, checkpoint, ...);
            values that are not strings are written as JSON.
        episodes: stop recording an env after it has finished this many episodes (None: no limit).
        flush_steps: steps buffered on the env's device before they are copied to the host
            and encoded (one device->host copy per batch, not per step).
        flush_seconds: close the chunk in progress at least this often (s of wall time).
        on_error: ``"warn"`` (default: report once, stop recording, keep training) or ``"raise"``.
        handle_sigterm: turn SIGTERM into ``SystemExit`` while a recorder is open, so the file is
            completed (only if the application installed no SIGTERM handler of its own).

    Use as a context manager, or call :meth:`close`. :meth:`write_step` takes one step
    ``(B,)`` as returned by ``env.step`` (root keys before the step, ``"next"`` after),
    with the env's ``NavState`` after the step for the world, odometry estimate and
    applied twist; :func:`record_rollout` does this for you. :meth:`write_rollout`
    takes a finished ``(B, T)`` rollout.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        env: Any,
        envs: Iterable[int] = (0,),
        metadata: Mapping[str, Any] | None = None,
        *,
        episodes: int | None = None,
        flush_steps: int = 16,
        flush_seconds: float = 10.0,
        on_error: str = "warn",
        handle_sigterm: bool = True,
    ):
        if on_error not in ("warn", "raise"):
            raise ValueError(f"on_error must be 'warn' or 'raise', got {on_error!r}")
        self.path = Path(path)
        special = self.path.exists() and not self.path.is_file()
        self.partial_path = self.path if special else self.path.with_name(f"{self.path.stem}.partial{self.path.suffix or '.mcap'}")
        self.env = env
        self.envs = [int(e) for e in envs]
        if not self.envs or any(not 0 <= e < env.num_envs for e in self.envs):
            raise ValueError(f"envs must be indices in [0, {env.num_envs}), got {self.envs}")
        self.max_episodes = episodes
        self.flush_steps = max(1, int(flush_steps))
        self.flush_seconds = flush_seconds
        self.on_error = on_error
        self.error: str | None = None
        self.enabled = True
        self._writing = False
        self._closed = False
        self._buffer: list[TensorDictBase] = []
        self._last_flush = time.monotonic()
        self._idx = torch.tensor(self.envs, device=env.device)
        self.dt_ns = int(round(env.cfg.robot.dt * 1e9))
        self.term_names = tuple(env.task.term_names)
        # several robots per env (MultiNavEnv): per-robot topics and frames (scene.MultiEnvStream)
        self.multi = getattr(env, "n_robots", None) is not None
        self.lidar = (env.task.nav if self.multi else env.task).params.lidar
        # Extension points for envs other than NavEnv (see docs/foxglove.md): which outputs exist,
        # the flags that name why an episode terminated, and static lines drawn in every scene.
        keys = set(env.observation_spec.keys())
        self.optional = {k: k in keys for k in ("goal", "curriculum_radius", "success")}
        self.end_reasons = tuple(getattr(env, "end_reasons", ()))
        scene_lines = getattr(env, "scene_lines", None)
        self.scene_lines = scene_lines() if callable(scene_lines) else {}
        # Optional sensors: an IMU, a camera (RGB and depth images, rendered for the recorded envs only)
        # and moving obstacles get their own topics when the env's simulator has them.
        params = getattr(env.task, "params", None)
        self.imu = getattr(params, "imu", None) is not None
        self.camera = getattr(params, "camera", None)
        self.styles = getattr(getattr(env.task, "spec", None), "styles", None)  # a map's own obstacle heights and colours
        self.movers = getattr(env.task, "n_movers", 0) > 0
        self.topics = self.TOPICS + (("imu",) if self.imu else ()) + (("camera", "camera_depth") if self.camera else ()) + (("movers",) if self.movers else ())
        self.streams = [(scene.MultiEnvStream if self.multi else scene.EnvStream)(i, env, self) for i in self.envs]
        self._writer = None
        self._file = None
        self._guard(self._open, metadata or {})
        if self.enabled:
            _OPEN.add(self)
            if handle_sigterm:
                _install_sigterm()

    # -- file ------------------------------------------------------------------------------

    TOPICS = ("tf", "scan", "scene", "odom", "odom_estimate", "action", "reward", "events")  # /env<i>/<topic> (one robot per env)

    def schemas(self) -> dict[str, dict]:
        """The JSON Schema of each kind of message (``odom_estimate`` uses ``odom``'s)."""
        return {
            "tf": foxglove_schema("FrameTransforms"), "scan": foxglove_schema("LaserScan"),
            "scene": foxglove_schema("SceneUpdate"), "odom": foxglove_schema("Odometry"),
            "action": action_schema(self.env.action_spec.shape[-1], self.multi), "reward": reward_schema(self.term_names, self.multi),
            "events": event_schema(self.multi),
            **({"imu": imu_schema()} if self.imu else {}),
            **({"camera": foxglove_schema("RawImage")} if self.camera else {}),
            **({"movers": movers_schema()} if self.movers else {}),
        }

    def _open(self, metadata: Mapping[str, Any]) -> None:
        from mcap.writer import CompressionType, Writer

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.partial_path, "wb")
        self._writer = Writer(self._file, compression=CompressionType.ZSTD, chunk_size=1 << 20)
        self._writer.start(profile="", library=f"torchnav {__version__}")
        sid = {k: self._writer.register_schema(s["title"], "jsonschema", json.dumps(s).encode()) for k, s in self.schemas().items()}
        for st in self.streams:
            st.channels = {name: self._writer.register_channel(f"/env{st.env}/{name}", "json", sid[kind]) for name, kind in st.topic_kinds()}
        self._writer.add_metadata("torchnav", self._metadata(metadata))
        self._flush_file()

    def _metadata(self, extra: Mapping[str, Any]) -> dict[str, str]:
        from ..config import to_dict

        cfg, li = self.env.cfg, self.lidar
        meta = {
            "version": __version__, "map": str(getattr(cfg, "map", getattr(cfg, "track", ""))), "seed": "", "checkpoint": "",
            "config": json.dumps(to_dict(cfg), default=str),
            "envs": json.dumps(self.envs), "num_envs": str(self.env.num_envs), "dt": repr(cfg.robot.dt),
            "lidar": json.dumps({"n_rays": li.n_rays, "fov": li.fov, "min_range": li.min_range, "max_range": li.max_range,
                                 "offset": list(li.offset), "angles": li.angles()}),
            "robot_radius": repr(cfg.robot.radius), "goal_tolerance": repr(getattr(cfg, "goal_tolerance", 0.0)),
            "reward_terms": json.dumps(list(self.term_names)), "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        if self.multi:
            meta["n_robots"] = str(self.env.n_robots)
        for k, v in extra.items():
            meta[str(k)] = v if isinstance(v, str) else json.dumps(v, default=str)
        return meta

    def _flush_file(self) -> None:
        self._writer.flush()  # closes the chunk in progress and flushes the stream

    def _guard(self, fn: Callable, *args: Any) -> Any:
        """Run a file operation; on OSError report once and switch recording off."""
        if not self.enabled:
            return None
        self._writing = True
        try:
            return fn(*args)
        except OSError as e:
            self._fail(e)
            return None
        finally:
            self._writing = False
            if _SIG["pending"] is not None:
                signum, _SIG["pending"] = _SIG["pending"], None
                raise SystemExit(128 + signum)

    def _fail(self, e: BaseException) -> None:
        self.error = f"{type(e).__name__}: {e}"
        self.enabled = False
        _OPEN.discard(self)
        try:
            if self._file is not None:
                self._file.close()
        except OSError:
            pass
        kept = "" if self.partial_path == self.path else f"; {self.path} is as it was before this recording"
        msg = (f"torchnav.record: recording to {self.path} stopped ({self.error}); "
               f"the run goes on, and {self.partial_path} keeps the episodes flushed before the error{kept}")
        if self.on_error == "raise":
            raise e
        warnings.warn(msg, RecordingWarning, stacklevel=3)

    # -- public API --------------------------------------------------------------------------

    @property
    def finished(self) -> bool:
        """True once every recorded env has finished ``episodes`` episodes (never without a limit)."""
        return self.max_episodes is not None and all(s.finished_episodes >= self.max_episodes for s in self.streams)

    @property
    def steps_written(self) -> dict[int, int]:
        """Steps written so far per recorded env (buffered steps not included)."""
        return {s.env: s.steps_written for s in self.streams}

    def write_step(self, td: TensorDictBase, state: Any | None = None, before: Any | None = None) -> None:
        """Buffer one step ``(B,)``: root keys before it, ``("next", ...)`` after it; ``state``: the env's
        state right after ``env.step``, for the episode's world, the odometry estimate and the applied
        twist (without it: the map's fixed obstacles and the commanded twist; docs/foxglove.md).
        ``before``: the env's state before the step, needed for several robots (their scans at an
        episode's start are in no key of ``td``); ignored for one robot."""
        if not self.enabled or self.finished:
            return
        if self.multi:
            if state is None or before is None:
                raise ValueError("EpisodeRecorder.write_step: a MultiNavEnv step needs state=env.state after the step and "
                                 "before=env.state before it (record_rollout passes both)")
            self._buffer.append(self._select_multi(td, state, before))
        else:
            self._buffer.append(self._select(td, state))
        if len(self._buffer) >= self.flush_steps:
            self._drain()

    def write_rollout(self, td: TensorDictBase, states: Iterable[Any] | None = None) -> None:
        """Write a rollout ``(B, T)`` (``env.rollout(..., break_when_any_done=False)`` layout), with the
        state after each step in ``states`` if given; without them the episodes show the map's fixed
        obstacles only (docs/foxglove.md, "Recording"). Not for several robots, whose steps need the states
        before and after each step: record those with :func:`record_rollout` or :meth:`write_step`."""
        if self.multi:
            raise ValueError("EpisodeRecorder.write_rollout: a MultiNavEnv rollout lacks the robots' scans; record it with "
                             "record_rollout(env, policy, max_steps, recorder=rec) or write_step(td, state, before)")
        if td.batch_dims == 1:
            td = td.unsqueeze(-1)
        states = list(states) if states is not None else [None] * td.shape[1]
        for t in range(td.shape[1]):
            self.write_step(td[:, t], states[t])
        self._drain()

    def flush(self) -> None:
        """Encode buffered steps and put everything written so far on disk."""
        self._drain(force_flush=True)

    def close(self) -> None:
        """Write buffered steps and the summary; the file is complete afterwards. Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self.enabled:
            self._drain()
            self._guard(self._finish)
        _OPEN.discard(self)
        _uninstall_sigterm()

    def _finish(self) -> None:
        self._writer.finish()
        self._file.flush()
        if self.partial_path != self.path:
            os.fsync(self._file.fileno())  # the data is on disk before the rename makes it the recording
        self._file.close()
        if self.partial_path != self.path:
            os.replace(self.partial_path, self.path)
        self.enabled = False

    def __enter__(self) -> "EpisodeRecorder":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- internals -------------------------------------------------------------------------------

    def _select(self, td: TensorDictBase, state: Any | None) -> TensorDictBase:
        """The recorded envs' slice of one step, still on the env's device."""
        idx, nxt = self._idx, td.get("next")
        terms = nxt.get("reward_terms")
        ep = nxt.get("episode")
        pose0 = td.get("pose")
        zero = lambda: pose0.new_zeros(pose0.shape[0])  # noqa: E731
        flag = lambda key: nxt.get(key)[..., 0] if self.optional.get(key, True) else zero().bool()  # noqa: E731
        stat = lambda key: ep.get(key)[..., 0] if key in ep.keys() else zero()  # noqa: E731
        out = {
            "pose0": pose0, "ranges0": td.get("ranges"), "action": td.get("action"),
            "goal": td.get("goal") if self.optional["goal"] else pose0.new_zeros(pose0.shape[0], 2),
            "pose1": nxt.get("pose"), "ranges1": nxt.get("ranges"),
            "reward": nxt.get("reward")[..., 0],
            "radius": nxt.get("curriculum_radius")[..., 0] if self.optional["curriculum_radius"] else zero(),
            "success": flag("success"), "collision": flag("collision"),
            "terminated": nxt.get("terminated")[..., 0], "truncated": nxt.get("truncated")[..., 0],
            "ret": ep.get("return")[..., 0], "path": stat("path_length"), "straight": stat("straight_line"),
            **{f"reason_{k}": nxt.get(k)[..., 0] for k in self.end_reasons},
        }
        if self.term_names:
            out["terms"] = torch.cat([terms.get(k) for k in self.term_names], -1)
        if state is not None:
            out.update(odom1=state.sim.odom, vel1=state.sim.vel)
            if self.imu:
                out["imu1"] = state.sim.imu
            if self.movers:
                out["movers1"] = mover_rows(state.sim)
        else:
            out["vel1"] = self.env.task.command(td.get("action"))
        sel = {k: v.index_select(0, idx).detach() for k, v in out.items()}
        w = getattr(state, "world", None) if state is not None else None
        if w is not None:  # the recorded envs' obstacles, the map's shared ones included (NavTask.full_world)
            w = getattr(self.env.task, "full_world", lambda w: w)(w[idx]).detach()
            sel.update(segments=w.segments, segment_mask=w.segment_mask, circles=w.circles, circle_mask=w.circle_mask,
                       boxes=w.boxes, box_mask=w.box_mask)
        if w is not None and self.camera is not None:  # rendered for the recorded envs only
            sim = state.sim[idx]
            mw = mover_world(sim.movers, sim.mover_mask, sim.mover_boxes) if sim.movers.shape[1] else None
            sel["depth1"], sel["rgb1"] = camera_image(sim.pose, w, self.camera, mw, self.styles)
        return TensorDict(sel, batch_size=[len(self.envs)])

    def _select_multi(self, td: TensorDictBase, state: Any, before: Any) -> TensorDictBase:
        """The recorded envs' slice of one ``MultiNavEnv`` step: per robot ``(E, N, ...)``, per env ``(E,)``."""
        nxt = td.get("next")
        a0, a1, r0, r1 = td.get("agents"), nxt.get("agents"), before.sim.robots, state.sim.robots
        flag = lambda key: a1.get(key)[..., 0]  # noqa: E731
        w = state.world
        out = {
            "pose0": r0.pose, "ranges0": r0.ranges, "goal": state.goal, "present": state.present, "action": a0.get("action"),
            "vel1": r1.vel, "pose1": r1.pose, "ranges1": r1.ranges, "reward": a1.get("reward")[..., 0], "ret": state.ep_return,
            "success": flag("success"), "collision": flag("collision"), "robot_collision": flag("robot_collision"),
            "arrived": state.arrived, "crashed": state.crashed, "terminated": nxt.get("terminated")[..., 0],
            "truncated": nxt.get("truncated")[..., 0], "team_success": nxt.get("team_success")[..., 0],
            "radius": self.env.curriculum.radius.expand(state.present.shape[0]),
            "segments": w.segments, "segment_mask": w.segment_mask, "circles": w.circles, "circle_mask": w.circle_mask,
            "boxes": w.boxes, "box_mask": w.box_mask,
        }
        if self.term_names:
            terms = a1.get("reward_terms")
            out["terms"] = torch.cat([terms.get(k) for k in self.term_names], -1)
        return TensorDict({k: v.index_select(0, self._idx).detach() for k, v in out.items()}, batch_size=[len(self.envs)])

    def _drain(self, force_flush: bool = False) -> None:
        if not self.enabled:
            self._buffer.clear()
            return
        if self._buffer:
            batch = torch.stack(self._buffer, dim=1).cpu()  # (E, T): one device->host copy
            self._buffer = []
            arrays = {k: v.numpy() for k, v in batch.items()}
            ended = self._guard(self._encode, arrays)
            if ended:
                force_flush = True
        if force_flush or time.monotonic() - self._last_flush > self.flush_seconds:
            self._guard(self._flush_file)
            self._last_flush = time.monotonic()

    def _encode(self, a: dict[str, np.ndarray]) -> bool:
        """Encode steps ``(E, T)`` time-major; True if an episode ended among them."""
        ended = False
        n_steps = next(iter(a.values())).shape[1]
        for t in range(n_steps):
            for e, st in enumerate(self.streams):
                ended |= st.step({k: v[e, t] for k, v in a.items()})
        return ended

    def add_message(self, channel: int, t_ns: int, payload: str) -> None:
        """One JSON message ``payload`` on ``channel`` (an id this recorder registered) at ``t_ns`` ns of episode time."""
        self._writer.add_message(channel, log_time=t_ns, data=payload.encode(), publish_time=t_ns)


@torch.no_grad()
def record_rollout(
    env: Any,
    policy: Callable[[TensorDictBase], TensorDictBase] | None,
    max_steps: int,
    recorder: EpisodeRecorder | None = None,
    tensordict: TensorDictBase | None = None,
    stack: bool = True,
) -> TensorDictBase | list[TensorDictBase]:
    """``env.rollout(max_steps, policy, break_when_any_done=False)`` that also records the state after
    each step, before the auto-reset (docs/foxglove.md, "Recording"). Returns the ``(B, T)`` rollout
    (or the list of ``(B,)`` steps with ``stack=False``)."""
    from torchrl.envs.utils import step_mdp

    td = env.reset() if tensordict is None else tensordict
    steps = []
    for i in range(max_steps):
        if policy is None:
            td = env.rand_action(td)
        else:
            td.update(policy(td))
        before = env.state  # a step makes a new state (the tasks are pure), so this one stays as it was
        td = env.step(td)
        if recorder is not None:
            recorder.write_step(td, env.state, before)
        steps.append(td)
        if i == max_steps - 1 or (recorder is not None and recorder.finished):
            break
        # the env's own keys: a multi-agent env's reward and done flags are under ("agents", ...)
        td = env.maybe_reset(step_mdp(td, reward_keys=env.reward_keys, done_keys=env.done_keys, action_keys=env.action_keys))
    if recorder is not None:
        recorder.flush()
    return torch.stack(steps, dim=env.batch_dims) if stack else steps
