"""TorchRL environments."""

from .line_env import LineEnv, make_line_env
from .nav_env import NavEnv, make_env

__all__ = ["NavEnv", "make_env", "LineEnv", "make_line_env"]
