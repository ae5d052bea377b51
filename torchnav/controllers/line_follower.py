"""A classical line follower: weighted sensor centroid -> PD steering, batched.

Reads only the env's ``observation`` (the stacked sensor history), so it sees
exactly what a learned policy sees and fits on a microcontroller:

    e_t   = sum_i c_i y_i / sum_i c_i       (m; y_i the sensors' lateral positions, left > 0)
    omega = kp * e_t + kd * (e_t - e_{t-1}) / dt
    v     = v_base * (1 - slow * |e_t| / y_max)

When no sensor sees the line, the last error seen in the history is pushed to the
edge of the array (``y_max`` with its sign), so the robot keeps turning towards the
side where it lost the line. Wheel speeds ``v -+ omega * track_width / 2`` are
scaled so that neither exceeds the limit (the turn is kept, the speed gives way).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from ..config import ConfigError
from ..sim import unicycle_to_wheels
from ..tasks.line_config import LineConfig
from .base import parse_gains


@dataclass(frozen=True)
class LineFollowerGains:
    v_base: float = 0.3  # m/s, forward speed on a centred line
    kp: float = 150.0  # rad/s per m of centroid offset
    kd: float = 3.0  # rad/s per (m/s) of centroid rate
    slow: float = 0.5  # fraction of v_base shed at the array's edge
    min_signal: float = 0.05  # summed reading below which the line counts as lost


class LineFollower(TensorDictModuleBase):
    """PD line follower for a continuous-action ``LineEnv``; writes ``action`` ``(B, 2)``."""

    in_keys = ["observation"]
    out_keys = ["action"]

    def __init__(self, cfg: LineConfig | None = None, gains: LineFollowerGains | Mapping[str, Any] | None = None):
        super().__init__()
        self.gains = parse_gains(LineFollowerGains, gains, "line_follower")
        self.configure(cfg or LineConfig())

    def configure(self, cfg: LineConfig) -> None:
        """Adopt the env's sensor layout, history, speed limit and action mapping."""
        if cfg.action.mode != "continuous":
            raise ConfigError(f"LineFollower needs action.mode 'continuous', got {cfg.action.mode!r}")
        if cfg.observation.history < 2:
            raise ConfigError("LineFollower needs observation.history >= 2 (for the derivative)")
        self.cfg = cfg
        offsets = cfg.sensor_params().offsets()
        self.y = torch.tensor([y for _, y in offsets])
        self.y_max = max(float(self.y.abs().max()), 1e-3)

    def bind(self, env: Any) -> "LineFollower":
        self.configure(env.cfg)
        return self

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        c, g = self.cfg, self.gains
        k, h = len(self.y), c.observation.history
        obs = td.get("observation")
        frames = obs[:, : k * h].reshape(obs.shape[0], h, k)  # oldest first
        y = self.y.to(obs)
        w = frames.sum(-1)
        seen = w > g.min_signal
        err = (frames * y).sum(-1) / w.clamp(min=1e-6)  # (B, H)
        # last frame that saw the line, for the lost-line memory
        idx = torch.arange(h, device=obs.device).expand_as(seen)
        last = torch.where(seen, idx, torch.full_like(idx, -1)).amax(-1)
        mem = err.gather(1, last.clamp(min=0)[:, None])[:, 0]
        lost_err = torch.where(last >= 0, torch.sign(mem) * self.y_max, torch.zeros_like(mem))
        e_now = torch.where(seen[:, -1], err[:, -1], lost_err)
        e_prev = torch.where(seen[:, -2], err[:, -2], e_now)
        omega = g.kp * e_now + g.kd * (e_now - e_prev) / c.robot.dt
        v = g.v_base * (1 - g.slow * e_now.abs() / self.y_max)
        wheels = unicycle_to_wheels(torch.stack((v, omega), -1), c.robot.track_width)
        vmax = c.robot.wheel_speed_max
        lo = 0.0 if c.action.forward_only else -vmax
        # keep the turn: shift the pair down if the faster wheel is over the limit, then clamp
        excess = (wheels.amax(-1, keepdim=True) - vmax).clamp(min=0)
        wheels = (wheels - excess).clamp(lo, vmax)
        action = (2 * wheels / vmax - 1) if c.action.forward_only else wheels / vmax
        td.set("action", action.clamp(-1, 1))
        return td
