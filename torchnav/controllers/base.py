"""What every classical controller shares: TensorDict policy plumbing, twist -> action, gains.

A controller reads ``pose`` ``(B, 3)``, ``goal`` ``(B, 2)`` and ``ranges`` ``(B, R)`` and writes
``action`` ``(B, 2)`` (the env's continuous convention, ``NavTask.command``) for the whole batch.
The ``NavConfig`` given at construction, or adopted by ``bind(env)``, fixes the speed limits,
the lidar layout and whether it may reverse (docs/controllers.md)."""

from __future__ import annotations

from typing import Any, Mapping

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor

from ..config import ConfigError, from_dict
from ..tasks import NavConfig


def parse_gains(cls: type, gains: Any, where: str):
    """A gains dataclass from None, an instance of ``cls`` or a mapping (strict: unknown keys raise)."""
    if gains is None:
        return cls()
    if isinstance(gains, cls):
        return gains
    if isinstance(gains, Mapping):
        return from_dict(cls, gains, where)
    raise ConfigError(f"{where}: expected a {cls.__name__} or a mapping of gains, got {type(gains).__name__}")


def check_positive(**values: float) -> None:
    """Refuse a gain that is not > 0; the message names the key within its gains class (``parse_gains``
    puts the controller's name in front)."""
    for k, v in values.items():
        if not v > 0:
            raise ConfigError(f"{k} must be > 0, got {v!r}")


class Controller(TensorDictModuleBase):
    """Base class: subclasses implement ``twist(td) -> (v m/s, omega rad/s)``, each ``(B,)``."""

    in_keys = ["pose", "goal", "ranges"]
    out_keys = ["action"]

    def __init__(self, nav: NavConfig | None = None):
        super().__init__()
        self.configure(nav or NavConfig())

    def configure(self, nav: NavConfig) -> None:
        """Adopt the env settings the controller depends on (limits, lidar layout, action mode)."""
        if nav.action.mode != "continuous":
            raise ConfigError(f"{type(self).__name__}: classical controllers need action.mode 'continuous', got {nav.action.mode!r}")
        self.nav = nav
        self.v_max, self.omega_max = nav.robot.v_max, nav.robot.omega_max
        self.v_min = 0.0 if nav.action.forward_only else -nav.robot.v_max
        self.radius = nav.robot.radius
        self.dt = nav.robot.dt
        lidar = nav.sim_params().lidar
        self._ray_angles = torch.tensor(lidar.angles(), dtype=torch.float64)
        self._sensor = lidar.offset
        self.max_range = lidar.max_range

    def bind(self, env: Any) -> "Controller":
        """Use ``env.cfg`` (a ``NavConfig``); planners also keep the env to read its worlds."""
        self.configure(env.cfg)
        return self

    # -- helpers for subclasses ----------------------------------------------------------

    def ray_angles(self, ref: Tensor) -> Tensor:
        """Robot-frame angles ``(R,)`` in rad of the lidar rays (sensor yaw included)."""
        return self._ray_angles.to(ref) + self._sensor[2]

    def hit_points(self, ranges: Tensor) -> Tensor:
        """Lidar returns as points ``(B, R, 2)`` in the robot frame (m, x forward, y left)."""
        a = self.ray_angles(ranges)
        ox, oy, _ = self._sensor
        return torch.stack((ox + ranges * torch.cos(a), oy + ranges * torch.sin(a)), dim=-1)

    def heading_speed(self, dist: Tensor, heading_err: Tensor, k_v: float, k_omega: float, turn_in_place: float) -> tuple[Tensor, Tensor]:
        """Shared proportional law: ``omega = k_omega * err``; ``v = k_v * dist`` scaled by
        ``cos(err)`` and zero once ``|err| > turn_in_place`` (turn on the spot first)."""
        omega = k_omega * heading_err
        v = k_v * dist * torch.cos(heading_err).clamp(min=0.0)
        v = torch.where(heading_err.abs() > turn_in_place, torch.zeros_like(v), v)
        return v, omega

    def to_action(self, v: Tensor, omega: Tensor) -> Tensor:
        """Twist ``(B,)`` m/s and rad/s -> action ``(B, 2)`` in [-1, 1], after the robot's limits."""
        v = v.clamp(self.v_min, self.v_max)
        omega = omega.clamp(-self.omega_max, self.omega_max)
        if self.nav.action.forward_only:
            a0 = 2.0 * v / self.v_max - 1.0
        else:
            a0 = v / self.v_max
        a1 = omega / max(self.omega_max, 1e-9)
        return torch.stack((a0, a1), dim=-1).clamp(-1.0, 1.0)

    # -- TensorDict policy --------------------------------------------------------------

    def twist(self, td: TensorDictBase) -> tuple[Tensor, Tensor]:
        raise NotImplementedError

    @torch.no_grad()
    def forward(self, td: TensorDictBase) -> TensorDictBase:
        pose = td.get("pose")
        v, omega = self.twist(td)
        td.set("action", self.to_action(v, omega).to(pose.dtype))
        return td

    def extra_repr(self) -> str:
        g = getattr(self, "gains", None)
        return "" if g is None else repr(g)

