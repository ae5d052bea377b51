"""TorchRL environments."""

from .nav_env import NavEnv, make_env

__all__ = ["NavEnv", "make_env"]
