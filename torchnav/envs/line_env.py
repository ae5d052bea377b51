"""TorchRL environment for the line-following task: a :class:`~torchnav.envs.base.BatchedEnv` around
``LineTask`` (partial resets, an explicit generator, running ``"episode"`` statistics and one
``"reward_terms"`` entry per term, as ``NavEnv``)."""

from __future__ import annotations

from typing import Any

import torch
from torchrl.data import Bounded

from ..tasks.line import LineState, LineTask
from ..tasks.line_config import LineConfig
from .base import BatchedEnv

EPISODE_KEYS = ("return", "length", "progress_m", "lap_fraction", "laps", "lap_time", "time_off_line")
FLAG_KEYS = ("on_line", "left_line", "stalled", "collision", "lap_completed")


class LineEnv(BatchedEnv):
    """Batched line following: observation, action and reward in docs/line.md; the outputs of every
    reset and step (the flags :data:`FLAG_KEYS`, ``episode/*`` :data:`EPISODE_KEYS`) in its "Env outputs"."""

    # For torchnav.record: the flags that say why an episode terminated, in order of precedence.
    end_reasons = ("collision", "left_line", "stalled")

    config_class, task_class = LineConfig, LineTask

    @property
    def track(self):
        """The :class:`~torchnav.tracks.Track` every env drives on."""
        return self.task.track

    def _make_specs(self) -> None:
        b, dev, t = self.batch_size, self.device, self.task
        super()._make_specs(
            observation=Bounded(0.0, 1.0, shape=(*b, t.obs_size), device=dev), sensors=Bounded(0.0, 1.0, shape=(*b, t.n_sensors), device=dev),
            lap_s=Bounded(0.0, t.tt.length, shape=(*b, 1), device=dev),
            ranges=Bounded(0.0, self.cfg.distance_sensor.max_range, shape=(*b, 1), device=dev),
        )

    # -- the task hooks of BatchedEnv ---------------------------------------------------------

    flag_keys = FLAG_KEYS

    def _new_state(self, mask: torch.Tensor | None) -> LineState:
        return self.task.initial_state(self._generator) if mask is None else self.task.reset(self._state, mask, self._generator)

    def _reset_view(self, s: LineState) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        # on_line as at every step: from the noise-free coverage, not from the noisy readings
        return self.task.observe(s.history, s.sim), {"on_line": self.task.on_line(s.sim.pose)[:, None]}

    episode_keys = EPISODE_KEYS

    def _task_outputs(self, s: LineState) -> dict[str, torch.Tensor]:
        return {"sensors": s.readings, "lap_s": s.s[:, None]}

    def _episode_stats(self, s: LineState) -> dict[str, torch.Tensor]:
        f = s.progress.dtype
        return {"progress_m": s.progress, "lap_fraction": s.progress / self.task.tt.length, "laps": s.laps.to(f), "lap_time": s.lap_time,
                "time_off_line": s.time_off_line}

    # -- state for checkpoints and recording ----------------------------------------------

    def scene_lines(self) -> dict[str, dict]:
        """Static lines for recorded scenes (``torchnav.record``): the track's tape, as segments
        ``(S, 4)`` (m) drawn ``width`` thick in white."""
        return {"track": {"segments": self.track.segments, "thickness": self.track.width, "color": (1.0, 1.0, 1.0, 1.0)}}


def make_line_env(track: str = "course", num_envs: int = 64, device: torch.device | str = "cpu", seed: int | None = 0, **overrides: Any) -> LineEnv:
    """Build a ``LineEnv`` from keyword overrides of ``LineConfig`` (nested dicts for sections).

    Example: ``make_line_env("oval", 256, action={"mode": "discrete"}, sensors={"noise_std": 0.05})``.
    Unknown keys raise a ConfigError naming the key.
    """
    cfg = LineConfig.from_dict({"track": track, **overrides})
    return LineEnv(cfg, num_envs=num_envs, device=device, seed=seed)
