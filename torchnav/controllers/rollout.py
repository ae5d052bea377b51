"""Drive a controller from chosen start poses to chosen goals, without TorchRL (tests, pictures).

The env's reset sampler picks starts, goals and boxes at random; to study a controller
in a constructed situation (a goal behind a cup-shaped wall) use :func:`drive`, which
steps ``NavTask`` directly on the map's fixed obstacles.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict

from ..sim import init_state
from ..tasks import CurriculumState, NavConfig, NavTask


class _TaskView:
    """What ``Controller.bind`` reads from an env: ``cfg``, ``num_envs``, ``device``, ``task``, ``state``."""

    def __init__(self, task: NavTask, state: Any):
        self.cfg, self.num_envs, self.device, self.task, self.state = task.cfg, task.num_envs, task.device, task, state


@torch.no_grad()
def drive(controller: Any, nav: NavConfig, start: Any, goal: Any, steps: int | None = None) -> dict[str, torch.Tensor]:
    """Run ``controller`` on ``nav.map`` (fixed obstacles only, no random objects) from poses
    ``start`` ``(B, 3)`` [x m, y m, theta rad] to goals ``goal`` ``(B, 2)`` m, for at most
    ``steps`` steps (default ``nav.max_steps``), stopping when every episode has ended.

    Returns ``success``, ``collision`` ``(B,)`` bool (outcome of each env's first
    episode end), ``steps`` ``(B,)`` the step it ended at (``steps`` if it did not), and
    ``pose`` ``(B, T + 1, 3)`` the poses, held after an episode ended.
    """
    start = torch.as_tensor(start, dtype=torch.float32).reshape(-1, 3)
    goal = torch.as_tensor(goal, dtype=torch.float32).reshape(-1, 2)
    n, steps = start.shape[0], nav.max_steps if steps is None else steps
    task = NavTask(nav, n)
    state, _ = task.initial_state(CurriculumState.initial(nav.curriculum), torch.Generator().manual_seed(0))
    state.world = task.base_world
    state.sim = init_state(start, task.base_world, task.params, static=task.static)
    state.goal = goal
    view = _TaskView(task, state)
    getattr(controller, "bind", lambda env: None)(view)
    success = torch.zeros(n, dtype=torch.bool)
    collision = torch.zeros(n, dtype=torch.bool)
    done = torch.zeros(n, dtype=torch.bool)
    ended = torch.full((n,), steps, dtype=torch.long)
    poses = [start]
    for t in range(steps):
        view.state = state
        td = TensorDict({"pose": state.sim.pose, "goal": state.goal, "ranges": state.sim.ranges,
                         "observation": state.history.reshape(n, -1),
                         "episode": {"length": state.steps[:, None].float()}}, batch_size=[n])
        state, out = task.step(state, controller(td)["action"])
        new = out["terminated"] & ~done
        success |= out["success"] & new
        collision |= out["collision"] & new
        ended = torch.where(new, t + 1, ended)
        done |= new
        poses.append(torch.where(done[:, None] & ~new[:, None], poses[-1], state.sim.pose))
        if done.all():
            break
    return {"success": success, "collision": collision, "steps": ended, "pose": torch.stack(poses, 1)}
