"""TorchRL environments."""

from .line_env import LineEnv, make_line_env
from .multi_nav_env import MultiNavEnv, make_multi_nav_env
from .nav_env import NavEnv, make_nav_env

__all__ = ["NavEnv", "make_nav_env", "LineEnv", "make_line_env", "MultiNavEnv", "make_multi_nav_env"]
