"""Classical baselines for the navigation task, usable as TorchRL policies.

``make_controller("reactive", lookahead=1.5).bind(env)`` reads ``pose``, ``goal``, ``ranges`` (and
``("episode", "length")`` for the planners) and writes ``action``. Gains, units and failure modes:
docs/controllers.md. ``make_controller("orca")`` is the multi-robot task's (``MULTI_CONTROLLERS``:
it reads and writes ``MultiNavEnv``'s ``("agents", ...)`` keys). ``torchnav.controllers.line_follower`` holds the line-following task's PD
baseline; it drives a different env and is not in this registry."""

from __future__ import annotations

from typing import Any

from ..config import ConfigError
from ..tasks import NavConfig
from .base import Controller
from .planning import Obstacles, OccupancyGrid, RRTParams, astar_cells, plan_astar, plan_rrt, shortcut, shortest_paths
from .orca import ORCA, ORCAGains
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
# controllers of the multi-robot task (MultiNavEnv's ("agents", ...) keys), kept apart: recipes/compare.py
# runs every entry of CONTROLLERS on single-robot maps
MULTI_CONTROLLERS: dict[str, type[Controller]] = {"orca": ORCA}


def make_controller(name: str, nav: NavConfig | None = None, **gains: Any) -> Controller:
    """The controller registered as ``name`` (in ``CONTROLLERS`` or ``MULTI_CONTROLLERS``) with ``gains``
    overriding its defaults.

    Nested gains are dicts (``make_controller("astar", tracker={"kp": 3.0})``). An unknown
    name or gain key raises ``ConfigError`` naming it. ``nav`` is the env config the
    controller is for (default ``NavConfig()``, ``MultiNavConfig()`` for a multi-robot one;
    ``bind(env)`` replaces it with ``env.cfg``).
    """
    known = {**CONTROLLERS, **MULTI_CONTROLLERS}
    if name not in known:
        import difflib

        close = difflib.get_close_matches(name, list(known), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ConfigError(f"unknown controller {name!r}{hint}; available: {', '.join(known)}")
    return known[name](gains, nav=nav)


__all__ = [
    "CONTROLLERS", "MULTI_CONTROLLERS", "make_controller", "Controller", "ORCA", "ORCAGains",
    "GoToGoal", "GoToGoalGains", "Reactive", "ReactiveGains", "PotentialField", "PotentialFieldGains",
    "PlannerController", "AStarController", "RRTController", "PlannerGains", "TrackerGains", "WaypointTracker",
    "drive", "Obstacles", "OccupancyGrid", "RRTParams", "astar_cells", "plan_astar", "plan_rrt", "shortcut", "shortest_paths",
]
