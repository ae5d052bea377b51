"""Classical baselines for the navigation task, usable as TorchRL policies.

``make_controller("reactive", lookahead=1.5).bind(env)`` reads ``pose``, ``goal``, ``ranges`` (and
``("episode", "length")`` for the planners) and writes ``action``. Gains, units and failure modes:
docs/controllers.md. ``torchnav.controllers.line_follower`` holds the line-following task's PD
baseline; it drives a different env and is not in this registry."""

from __future__ import annotations

from typing import Any

from ..config import ConfigError
from ..tasks import NavConfig
from .base import Controller
from .planning import Obstacles, OccupancyGrid, RRTParams, astar_cells, plan_astar, plan_rrt, shortcut
from .rollout import drive
from .reactive import GoToGoal, GoToGoalGains, PotentialField, PotentialFieldGains, Reactive, ReactiveGains
from .tracker import AStarController, PlannerController, PlannerGains, RRTController, TrackerGains, WaypointTracker

CONTROLLERS: dict[str, type[Controller]] = {
    "go_to_goal": GoToGoal,
    "reactive": Reactive,
    "potential_field": PotentialField,
    "astar": AStarController,
    "rrt": RRTController,
}


def make_controller(name: str, nav: NavConfig | None = None, **gains: Any) -> Controller:
    """The controller registered as ``name`` with ``gains`` overriding its defaults.

    Nested gains are dicts (``make_controller("astar", tracker={"kp": 3.0})``). An unknown
    name or gain key raises ``ConfigError`` naming it. ``nav`` is the env config the
    controller is for (default ``NavConfig()``; ``bind(env)`` replaces it with ``env.cfg``).
    """
    if name not in CONTROLLERS:
        import difflib

        close = difflib.get_close_matches(name, list(CONTROLLERS), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ConfigError(f"unknown controller {name!r}{hint}; available: {', '.join(CONTROLLERS)}")
    return CONTROLLERS[name](gains, nav=nav)


__all__ = [
    "CONTROLLERS", "make_controller", "Controller",
    "GoToGoal", "GoToGoalGains", "Reactive", "ReactiveGains", "PotentialField", "PotentialFieldGains",
    "PlannerController", "AStarController", "RRTController", "PlannerGains", "TrackerGains", "WaypointTracker",
    "drive", "Obstacles", "OccupancyGrid", "RRTParams", "astar_cells", "plan_astar", "plan_rrt", "shortcut",
]
