"""The line-following task: random starts along a track, reflectance observations with history,
progress reward along the lap, termination when the robot leaves the line or stops.

``LineTask.step`` and ``LineTask.reset`` are pure functions of an explicit ``LineState`` (no
TorchRL here). Progress is the arc length gained along the lap path (``tracks.project_on_path``:
crossings never make it jump, and rocking back and forth earns nothing).
"""

from __future__ import annotations

import math

import torch
from tensordict import tensorclass
from torch import Tensor

from ..sim import SimState, init_state, make_world
from ..sim import step as sim_step
from ..sim.floor import band_coverage, floor_readings, nearest_distance, sensor_points
from ..tracks import load_track, path_pose, project_on_path, wrap_delta
from .base import BatchedTask, TaskState
from .line_config import LineConfig
from .rewards import weighted


class LineTask(BatchedTask):
    """Configured line-following task for ``num_envs`` envs on ``device``."""

    def __init__(self, cfg: LineConfig, num_envs: int, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32):
        super().__init__(cfg, num_envs, device, dtype)
        self.track = load_track(cfg.track)
        self.params = cfg.sim_params()
        self.sensor = cfg.sensor_params()
        self.half_width = self.track.width / 2
        reach = self.half_width + self.sensor.radius + 12 * self.sensor.softness
        self.tt = self.track.tensors(reach, device=self.device, dtype=dtype)
        self.world = make_world(num_envs, segments=self.tt.walls, device=self.device, dtype=dtype)
        self.weights = cfg.weights()
        self.term_names = tuple(self.weights)
        self.n_sensors = self.sensor.count
        self.obs_size = self.n_sensors * cfg.observation.history + (1 if cfg.distance_sensor.enabled else 0)
        # Segments searched on each side of the last projection: the farthest a step can move, plus margin.
        reach_s = self.params.v_max * self.params.dt + 0.05
        self.window = max(2, math.ceil(reach_s / self.track.spacing))
        self.discrete_wheels = torch.tensor(cfg.action.discrete_set, dtype=dtype, device=self.device) * cfg.robot.wheel_speed_max
        dt, t = cfg.robot.dt, cfg.termination
        self.off_limit = max(1, round(t.off_line_time / dt))
        self.stop_limit = max(1, round(t.stop_time / dt))

    # -- actions and sensing ------------------------------------------------------------

    def command(self, action: Tensor) -> Tensor:
        """Policy action -> wheel speeds ``(B, 2)`` ``[v_left, v_right]`` in m/s.

        Continuous: ``(B, 2)`` motor commands in [-1, 1] (clamped) times ``wheel_speed_max``
        (with ``forward_only``: [-1, 1] -> [0, wheel_speed_max]). Discrete: one-hot ``(B, n)``
        over ``action.discrete_set``.
        """
        vmax = self.cfg.robot.wheel_speed_max
        if self.cfg.action.mode == "discrete":
            return action.to(self.dtype) @ self.discrete_wheels
        a = action.clamp(-1.0, 1.0)
        return (a + 1.0) * (0.5 * vmax) if self.cfg.action.forward_only else a * vmax

    def sense(self, pose: Tensor, generator: torch.Generator | None) -> tuple[Tensor, Tensor]:
        """Sensor readings ``(B, K)`` (noisy with a generator) and the noise-free on-line flag ``(B,)``
        (some sensor's coverage above the threshold)."""
        d = nearest_distance(sensor_points(pose, self.sensor), self.tt.grid)
        return floor_readings(d, self.half_width, self.sensor, generator), self._on_line(d)

    def on_line(self, pose: Tensor) -> Tensor:
        """``(B,)`` bool: some sensor's noise-free coverage of the line is above the threshold."""
        return self._on_line(nearest_distance(sensor_points(pose, self.sensor), self.tt.grid))

    def _on_line(self, d: Tensor) -> Tensor:
        return (band_coverage(d, self.half_width, self.sensor.radius) > self.sensor.threshold).any(-1)

    def observe(self, history: Tensor, sim: SimState) -> Tensor:
        """Observation ``(B, H*K [+1])``: the sensor history, oldest frame first, each frame in sensor
        order (rightmost first); then the forward range / max_range if the distance sensor is on."""
        obs = history.reshape(history.shape[0], -1)
        if self.cfg.distance_sensor.enabled:
            obs = torch.cat((obs, sim.ranges[:, :1] / self.cfg.distance_sensor.max_range), dim=-1)
        return obs

    # -- reset ----------------------------------------------------------------------------

    def start_poses(self, n: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """``n`` start poses ``(n, 3)`` and their arc lengths ``(n,)``: on the lap path, with the sensor
        array's centre over the line (heading along the chord to the point ``forward`` m ahead),
        plus uniform lateral and heading noise."""
        rc, L = self.cfg.reset, self.tt.length
        u = torch.rand(n, 3, generator=generator, dtype=self.dtype, device=self.device) * 2 - 1
        s = torch.full((n,), rc.start % L, dtype=self.dtype, device=self.device) if rc.start is not None else (u[:, 0] + 1) * (0.5 * L)
        here = path_pose(self.tt.lap, self.tt.lap_s, s)
        ahead = path_pose(self.tt.lap, self.tt.lap_s, s + self.sensor.forward)
        th = torch.atan2(ahead[:, 1] - here[:, 1], ahead[:, 0] - here[:, 0])
        lat = u[:, 1] * rc.lateral_noise
        x = here[:, 0] - torch.sin(here[:, 2]) * lat
        y = here[:, 1] + torch.cos(here[:, 2]) * lat
        th = th + u[:, 2] * rc.heading_noise
        return torch.stack((x, y, torch.atan2(torch.sin(th), torch.cos(th))), dim=-1), s

    def _fresh(self, n: int, generator: torch.Generator) -> LineState:
        pose, s0 = self.start_poses(n, generator)
        sim = init_state(pose, self.world[:n], self.params)
        s, dist = project_on_path(pose[:, :2], self.tt.lap, self.tt.lap_s, s0, self.window)
        readings, _ = self.sense(pose, generator)
        zf = torch.zeros(n, dtype=self.dtype, device=self.device)
        zi = torch.zeros(n, dtype=torch.int64, device=self.device)
        return LineState(
            s=s, path_dist=dist, progress=zf, laps=zi, lap_time=zf.clone(), readings=readings, off_steps=zi.clone(),
            stop_steps=zi.clone(), time_off_line=zf.clone(), **self._episode_start(sim, readings),
        )

    def initial_state(self, generator: torch.Generator) -> LineState:
        """Fresh episodes in every env."""
        return self._fresh(self.num_envs, generator)

    def reset(self, state: LineState, mask: Tensor, generator: torch.Generator) -> LineState:
        """New episodes where ``mask`` ``(B,)`` is True; the other envs are left bit-identical (``replace_where``)."""
        return self.replace_where(state, mask, lambda idx: self._fresh(idx.numel(), generator))[0]

    # -- step -------------------------------------------------------------------------------

    def step(self, state: LineState, action: Tensor, generator: torch.Generator | None = None) -> tuple[LineState, dict]:
        """Advance every env one step. Pure: ``state`` is not modified.

        Returns the new state and ``out`` with ``observation`` ``(B, obs_size)``, ``reward`` ``(B,)``,
        ``terms`` (dict of ``(B,)`` weighted terms), ``terminated``, ``truncated``, ``on_line``,
        ``left_line``, ``stalled``, ``collision``, ``lap_completed`` ``(B,)`` bool.
        """
        c, dt = self.cfg, self.cfg.robot.dt
        sim = sim_step(state.sim, self.command(action), self.world, self.params, wheel_speeds=True, generator=generator)
        readings, on_line = self.sense(sim.pose, generator)
        s, dist = project_on_path(sim.pose[:, :2], self.tt.lap, self.tt.lap_s, state.s, self.window)
        ds = wrap_delta(s - state.s, self.tt.length)
        progress = state.progress + ds
        laps = torch.maximum(state.laps, torch.floor(progress / self.tt.length).to(torch.int64))
        lap_completed = laps > state.laps
        steps = state.steps + 1
        off_steps = torch.where(on_line, torch.zeros_like(state.off_steps), state.off_steps + 1)
        stop_steps = torch.where(sim.vel[:, 0].abs() < c.termination.stop_speed, state.stop_steps + 1, torch.zeros_like(state.stop_steps))
        left_line = (off_steps >= self.off_limit) | (dist > c.termination.max_path_distance)
        stalled = stop_steps >= self.stop_limit
        collision = sim.collided
        terminated = left_line | stalled | collision
        truncated = (steps >= c.max_steps) & ~terminated
        off = (~on_line).to(self.dtype)
        terms = weighted(self.weights, {
            "progress": lambda: ds, "off_line": lambda: off, "failure": lambda: terminated.to(self.dtype),
            "lap": lambda: lap_completed.to(self.dtype), "turning": lambda: sim.vel[:, 1].abs(), "step": lambda: torch.ones_like(ds),
        })
        common, reward = self._episode_step(state, sim, readings, terms)
        first_lap = lap_completed & (state.laps == 0)
        new = LineState(
            s=s, path_dist=dist, progress=progress, laps=laps, lap_time=torch.where(first_lap, steps.to(self.dtype) * dt, state.lap_time),
            readings=readings, off_steps=off_steps, stop_steps=stop_steps, time_off_line=state.time_off_line + off * dt, **common,
        )
        out = {
            "observation": self.observe(common["history"], sim), "reward": reward, "terms": terms, "terminated": terminated,
            "truncated": truncated, "on_line": on_line, "left_line": left_line, "stalled": stalled,
            "collision": collision, "lap_completed": lap_completed,
        }
        return new, out


@tensorclass
class LineState(TaskState):
    """Per-env line-following state, all ``(B, ...)``: :class:`~torchnav.tasks.base.TaskState`
    (``history`` ``(B, H, K)`` of sensor readings) and the robot's place on the lap."""

    s: Tensor  # (B,) m, arc length of the robot's projection on the lap path
    path_dist: Tensor  # (B,) m from the lap path
    progress: Tensor  # (B,) m of arc length gained this episode (negative when driven backwards)
    laps: Tensor  # (B,) int64, most full laps reached this episode
    lap_time: Tensor  # (B,) s at which the first lap was completed (0 until then)
    readings: Tensor  # (B, K) current sensor values in [0, 1]
    off_steps: Tensor  # (B,) int64 consecutive steps with no sensor on the line
    stop_steps: Tensor  # (B,) int64 consecutive steps below the stop speed
    time_off_line: Tensor  # (B,) s with no sensor on the line this episode
