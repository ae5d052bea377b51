"""Tasks built on the simulator (no TorchRL here)."""

from .base import EpisodePool
from .config import ActionConfig, CurriculumConfig, LidarConfig, NavConfig, ObservationConfig, ResetConfig, RewardConfig, RobotConfig, WorldsConfig
from .config import MultiNavConfig, RobotsConfig
from .line import LineState, LineTask
from .line_config import LINE_TERMS, LineConfig
from .curriculum import CurriculumState, after_episodes, after_family_episodes, after_placements
from .navigation import NavState, NavTask
from .multi_navigation import MultiNavState, MultiNavTask
from .rewards import PRESETS, TERMS, resolve_weights

__all__ = [
    "NavConfig", "RobotConfig", "LidarConfig", "CurriculumConfig", "RewardConfig", "ObservationConfig",
    "ActionConfig", "ResetConfig", "WorldsConfig", "CurriculumState", "after_placements", "after_episodes", "after_family_episodes", "NavState",
    "NavTask", "EpisodePool", "PRESETS", "TERMS", "resolve_weights", "LineConfig", "LineTask", "LineState", "LINE_TERMS",
    "MultiNavConfig", "RobotsConfig", "MultiNavTask", "MultiNavState",
]
