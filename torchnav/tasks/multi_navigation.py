"""Several robots per env, one goal each (docs/multi_robot.md): NavTask's observation, reward terms and
free-space sampling, applied to every robot of ``torchnav.sim.robots``.

Pure like ``NavTask``: ``state, out = task.step(state, action)``. A robot that reaches its goal or
collides parks (``Robots.parked``): it stands still and stays an obstacle the others see and can
hit; the map's random objects are placed first (anywhere, except in ``circle_swap``, whose circle
they could block: none there), then the robots and goals around them. With ``robots.on_collision: team`` a collision ends the whole env's episode instead. The env's
episode ends when no present robot still drives, or at ``max_steps`` (truncation).

With procedural worlds (``worlds.families``; ``random`` and ``crossing``) every episode draws its world
as ``NavTask`` does (``NavTask._generated``: the same generator, families, difficulties and curriculum)
and places the robots with ``torchnav.worlds.place_robots``: each robot's goal reachable from its own
start by its disc, as NavTask's one goal is. Resets then draw from an episode pool, as NavTask's do.

Moving obstacles (a map's, or ``worlds.movers``) are placed as ``NavTask`` places them
(``NavTask._movers``), clear of every robot's start and goal.

What this version leaves out (refused with a clear error): ``circle_swap`` on procedural worlds,
domain randomisation, observation history and visit memory, the speed guard and the geodesic
progress reward. ``crossing`` and ``circle_swap`` place their goals by
their geometry; in ``random`` on a map the goal-radius curriculum (``curriculum``) bounds every robot's
goal distance, one curriculum for all robots: each placed goal is a placement and each robot's finished
episode an episode of it (``CurriculumState``, as for ``NavTask``). The world difficulty curriculum
(``worlds.curriculum``) is likewise one for the batch, each robot's finished episode counting as one
episode of its env's world family.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import torch
from tensordict import tensorclass
from torch import Tensor

from ..config import ConfigError
from ..sim import World, safe_hypot, wrap_angle
from ..sim.robots import Robots, RobotsState, init_robots, robot_clearance, step_robots
from ..worlds import RobotPlacement
from ..worlds.layout import uniform
from .base import EpisodePool
from .config import MultiNavConfig
from .curriculum import CurriculumState, after_episodes, after_family_episodes, after_placements
from .navigation import NavTask
from .rewards import reward_terms
from .sampling import place_random_objects, sample_goals, sample_starts

NEIGHBOUR_FEATURES = 5  # per neighbour: x, y, vx, vy in the robot's frame, and 1 (0 for padding)


@tensorclass
class MultiNavState:
    """``B`` envs of ``N`` robot slots, all ``(B, ...)``."""

    sim: RobotsState  # the robots (batch (B, N)) and the env's movers
    world: World  # (B) the map's obstacles
    goal: Tensor  # (B, N, 2) m
    start: Tensor  # (B, N, 3)
    present: Tensor  # (B, N) bool, the robot exists in this episode
    arrived: Tensor  # (B, N) bool, reached its goal (parked there)
    crashed: Tensor  # (B, N) bool, collided (parked there)
    goal_dist: Tensor  # (B, N) m after the last step
    family: Tensor  # (B,) int64 index of the env's world family in cfg.worlds.families (0 on a map)
    difficulty: Tensor  # (B,) the difficulty the env's world was generated at (0 on a map)
    steps: Tensor  # (B,) int64
    ep_return: Tensor  # (B, N) running sum of each robot's reward
    ep_terms: Tensor  # (B, N, T) running sums of each weighted term
    observation: Tensor  # (B, N, D) each robot's last observation

    @property
    def robots(self) -> Robots:
        return Robots(self.present, self.present & (self.arrived | self.crashed))


class MultiNavTask:
    """Configured multi-robot navigation for ``num_envs`` envs of ``cfg.robots.n`` robot slots on ``device``."""

    def __init__(self, cfg: MultiNavConfig, num_envs: int, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32):
        if not isinstance(cfg, MultiNavConfig):
            raise TypeError(f"MultiNavTask needs a MultiNavConfig, got {type(cfg).__name__}")
        unsupported = [
            (bool(cfg.worlds.families) and cfg.robots.scenario == "circle_swap",
             "robots.scenario: circle_swap on procedural worlds (worlds.families; its circle would cross their walls)"),
            (bool(cfg.randomize.ranges()), "randomize (domain randomisation)"),
            (cfg.shared_map == "on", "shared_map: on (each env holds its copy of the map)"),
            (cfg.observation.history != 1, "observation.history > 1"),
            (cfg.observation.visit_sectors > 0, "observation.visit_sectors"),
            (cfg.action.stop_clearance is not None, "action.stop_clearance"),
            (cfg.reward.progress_distance != "euclidean", "reward.progress_distance: geodesic"),
        ]
        bad = [what for on, what in unsupported if on]
        if bad:
            raise ConfigError(f"the multi-robot task does not support {', '.join(bad)} yet")
        self.nav = NavTask(cfg, num_envs, device, dtype, share_map=False)  # observation, actions, reward weights, the map or the worlds
        self.families = self.nav.families
        rob = cfg.robots
        # On worlds as on maps: starts 2 radii plus the separation apart, goals 2 tolerances plus it.
        self.placement = RobotPlacement(rob.n, 2 * self.nav.max_radius + rob.separation, 2 * cfg.goal_tolerance + rob.separation,
                                        sides=rob.scenario == "crossing")
        self.cfg, self.num_envs, self.device, self.dtype = cfg, num_envs, self.nav.device, dtype
        self.n = cfg.robots.n
        self.k = cfg.robots.neighbours
        self.term_names = self.nav.term_names
        self.obs_size = self.nav.obs_size + NEIGHBOUR_FEATURES * self.k

    # -- observation ----------------------------------------------------------------

    @property
    def unit_features(self) -> Tensor:
        """NavTask's, then every neighbour feature: they are zero where a slot is empty, and a
        mean-std normalisation from a rollout with one robot count would turn the empty slots of
        another count into large inputs (the flag's spread is 0 when every slot is always full)."""
        return torch.cat((self.nav.unit_features, torch.ones(NEIGHBOUR_FEATURES * self.k, dtype=torch.bool, device=self.device)))

    def neighbours(self, sim: RobotsState, present: Tensor) -> Tensor:
        """``(B, N, 5k)``: for each robot its ``k`` nearest other present robots within
        ``robots.neighbour_range``, nearest first, as ``[x, y, vx, vy, 1]`` (position m and velocity m/s
        relative to it, in its frame; divided by the neighbour range and v_max with
        ``observation.normalize``), zeros where fewer are in range. Sorted by distance, so the same robots
        in another slot order give the same features; padded by range, so a policy meets empty slots
        in training whatever its robot count, and runs with fewer or more robots."""
        b, n = present.shape
        if self.k == 0:
            return sim.robots.pose.new_zeros(b, n, 0)
        pose, vel = sim.robots.pose, sim.robots.vel
        x, y, th = pose[..., 0], pose[..., 1], pose[..., 2]
        vx, vy = vel[..., 0] * torch.cos(th), vel[..., 0] * torch.sin(th)
        robot = torch.arange(n, device=self.device)
        other = (robot[:, None] + robot[None, 1:]) % n  # (N, N - 1), as robot_clearance
        c, s = torch.cos(th)[..., None], torch.sin(th)[..., None]

        def frame(ax: Tensor, ay: Tensor) -> tuple[Tensor, Tensor]:
            dx, dy = ax[:, other] - ax[..., None], ay[:, other] - ay[..., None]
            return c * dx + s * dy, c * dy - s * dx

        px, py = frame(x, y)
        qx, qy = frame(vx, vy)
        reach = self.cfg.robots.neighbour_range
        dist = safe_hypot(px, py)
        seen = present[:, other] & present[..., None] & (dist <= reach)  # (B, N, N - 1)
        dist = torch.where(seen, dist, torch.inf)
        feats = torch.stack((px, py, qx, qy, seen.to(pose.dtype)), -1)
        if self.cfg.observation.normalize:
            r = self.cfg.robot
            feats = feats * feats.new_tensor([1 / reach] * 2 + [1 / max(r.v_max, 1e-9)] * 2 + [1.0])
        feats = torch.where(seen[..., None], feats, 0.0)
        order = dist.argsort(dim=-1, stable=True)[..., : self.k]
        feats = feats.gather(2, order[..., None].expand(*order.shape, NEIGHBOUR_FEATURES))
        if feats.shape[2] < self.k:
            feats = torch.cat((feats, feats.new_zeros(b, n, self.k - feats.shape[2], NEIGHBOUR_FEATURES)), 2)
        return feats.reshape(b, n, -1)

    def observe(self, sim: RobotsState, goal: Tensor, present: Tensor) -> Tensor:
        """Each robot's observation ``(B, N, D)``: NavTask's (sectors, goal, twist, ...) then :meth:`neighbours`."""
        b, n = present.shape
        own = self.nav.observe(sim.robots.reshape(b * n), goal.reshape(b * n, 2)).reshape(b, n, -1)
        return torch.cat((own, self.neighbours(sim, present)), -1)

    # -- reset ----------------------------------------------------------------------

    def _counts(self, m: int, generator: torch.Generator) -> Tensor:
        rc = self.cfg.robots
        if rc.min_n == 0 or rc.min_n == rc.n:
            return torch.full((m,), rc.n, dtype=torch.int64, device=self.device)
        return torch.randint(rc.min_n, rc.n + 1, (m,), generator=generator, device=self.device)

    def _places(self, world: World, radius: Tensor, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """Starts ``(m, N, 3)`` and goals ``(m, N, 2)`` of the configured scenario; ``random`` goals lie
        within ``radius`` (0-d, m: the curriculum's) of their starts where there is room."""
        c, rc, rob = self.cfg, self.cfg.reset, self.cfg.robots
        spec, m, n, like = self.nav.spec, world.batch_size[0], self.n, world.segments
        xmin, ymin, xmax, ymax = spec.bounds
        need = self.nav.max_radius + rc.start_clearance
        apart = 2 * self.nav.max_radius + rob.separation  # centre to centre
        goal_apart = 2 * c.goal_tolerance + rob.separation
        if rob.scenario == "circle_swap":
            radius = rob.circle_radius or 0.4 * min(xmax - xmin, ymax - ymin)
            turn = uniform(-math.pi, math.pi, (m, 1), generator, like) + torch.arange(n, device=self.device, dtype=like.dtype) * (2 * math.pi / n)
            cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
            xy = torch.stack((cx + radius * torch.cos(turn), cy + radius * torch.sin(turn)), -1)
            start = torch.cat((xy, wrap_angle(turn + math.pi)[..., None]), -1)
            return start, 2 * xy.new_tensor([cx, cy]) - xy
        bands = [SimpleNamespace(bounds=spec.bounds)] * 2
        if rob.scenario == "crossing":  # group 0 from the left third to the right third, group 1 the other way
            w = (xmax - xmin) / 3
            bands = [SimpleNamespace(bounds=(xmin, ymin, xmin + w, ymax)), SimpleNamespace(bounds=(xmax - w, ymin, xmax, ymax))]
        starts, goals = [], []
        for i in range(n):
            home, away = bands[i % 2], bands[(i + 1) % 2]
            before_s = torch.stack([s[:, :2] for s in starts], 1) if starts else None
            before_g = torch.stack(goals, 1) if goals else None
            start, _ = sample_starts(world, home, need, rc.candidates, generator, before_s, apart)
            # crossing: no near goals (radius 0), only goals in the far band
            r_min, r_max = (0.0, radius * 0) if rob.scenario == "crossing" else (c.curriculum.min_radius, radius)
            goal, _ = sample_goals(world, away, start[:, :2], r_min, r_max, rc.goal_clearance,
                                   rc.candidates, generator, before_g, goal_apart)
            starts.append(start)
            goals.append(goal)
        return torch.stack(starts, 1), torch.stack(goals, 1)

    def _fresh(self, idx: Tensor, cur: CurriculumState, generator: torch.Generator) -> MultiNavState:
        m = idx.shape[0]
        if self.families:  # the world, its family and difficulty, and every robot's start and reachable goal
            world, start, goal, family, difficulty, bounds, _ = self.nav._generated(m, cur, generator, self.placement)
            counts = self._counts(m, generator)
        else:
            world = self.nav.base_world[idx]
            if self.cfg.robots.scenario != "circle_swap":
                nowhere = world.segments.new_full((m, 2), -1.0e6)  # no start or goal to keep clear of yet: the robots come after
                world = place_random_objects(world, self.nav.spec, nowhere, nowhere, self.cfg.reset.candidates, generator)
            counts = self._counts(m, generator)
            start, goal = self._places(world, cur.radius, generator)
            bounds = None
            family = torch.zeros(m, dtype=torch.int64, device=self.device)
            difficulty = torch.zeros(m, dtype=self.dtype, device=self.device)
        present = torch.arange(self.n, device=self.device) < counts[:, None]
        robots = Robots(present, torch.zeros_like(present))
        # Moving obstacles (the map's, or worlds.movers) keep the maps' clearances from every robot's start and goal.
        movers = self.nav._movers(world, start[..., :2], goal, bounds, generator)
        sim = init_robots(start, world, self.nav.params, robots, movers=movers)
        dist = torch.where(present, safe_hypot(goal[..., 0] - start[..., 0], goal[..., 1] - start[..., 1]), 0.0)
        zeros = torch.zeros(m, self.n, dtype=self.dtype, device=self.device)
        return MultiNavState(
            sim=sim, world=world, goal=goal, start=start, present=present, arrived=torch.zeros_like(present), crashed=torch.zeros_like(present),
            goal_dist=dist, family=family, difficulty=difficulty, steps=torch.zeros(m, dtype=torch.int64, device=self.device),
            ep_return=zeros,
            ep_terms=zeros[..., None].expand(m, self.n, len(self.term_names)).clone(), observation=self.observe(sim, goal, present),
            batch_size=[m], device=self.device,
        )

    @property
    def pooled(self) -> bool:
        """Whether partial resets draw from an :class:`EpisodePool` (as ``NavTask.pooled``: ``reset.pool > 0``
        or procedural worlds)."""
        return self.nav.pooled

    def initial_state(self, cur: CurriculumState, generator: torch.Generator) -> tuple[MultiNavState, CurriculumState]:
        """New episodes in every env (sampled afresh: start a new :class:`EpisodePool` with them), and the
        curriculum after their goals."""
        state = self._fresh(torch.arange(self.num_envs, device=self.device), cur, generator)
        return state, self._placed(cur, state.present)

    def reset(self, state: MultiNavState, mask: Tensor, cur: CurriculumState, generator: torch.Generator,
              pool: EpisodePool | None = None) -> tuple[MultiNavState, CurriculumState]:
        """New episodes where ``mask`` ``(B,)`` is True (the other envs are left bit-identical), and the
        curriculum after their goals; when the task is :attr:`pooled`, taken from ``pool`` (required
        then, the same one every time), as ``NavTask.reset`` does."""
        if self.pooled and pool is None:
            raise ValueError("MultiNavTask.reset: this task draws its resets from an episode pool (reset.pool > 0 or worlds.families): "
                             "pass pool=EpisodePool() and the same pool to every later reset")
        fresh = lambda idx: self._fresh(idx, cur, generator)  # noqa: E731
        draw = (lambda idx: self.nav._from_pool(pool, idx.numel(), cur, generator, fresh)) if self.pooled else fresh
        new, n = NavTask.replace_where(state, mask, draw)
        return new, (self._placed(cur, new.present & mask.reshape(-1, 1)) if n else cur)

    def _placed(self, cur: CurriculumState, placed: Tensor) -> CurriculumState:
        """The curriculum after the goals of the robots ``placed`` ``(B, N)`` (only ``random`` draws from it)."""
        if self.cfg.robots.scenario != "random":
            return cur
        return after_placements(cur, self.cfg.curriculum, placed.sum())

    def after_step(self, cur: CurriculumState, before: MultiNavState, out: dict[str, Tensor]) -> CurriculumState:
        """The curriculum after a step from ``before`` with outputs ``out``: every robot whose episode
        ended in it (parked, or its env's ended) is one finished episode, a success if it arrived: of
        the goal radius (``random``) and of its env's world family (``worlds.curriculum``, any scenario)."""
        robots = before.robots
        finished = (out["terminated"] | out["truncated"]) & robots.present & ~robots.parked
        if self.cfg.robots.scenario == "random":
            cur = after_episodes(cur, self.cfg.curriculum, finished, out["success"])
        if self.families:
            per_robot = lambda t: t[:, None].expand_as(finished).reshape(-1)  # noqa: E731
            cur = after_family_episodes(cur, self.cfg.worlds, finished.reshape(-1), out["success"].reshape(-1),
                                        per_robot(before.family), per_robot(before.difficulty))
        return cur

    # -- step -------------------------------------------------------------------------

    def step(self, state: MultiNavState, action: Tensor, generator: torch.Generator | None = None) -> tuple[MultiNavState, dict[str, Tensor]]:
        """Advance every env one step; ``action`` ``(B, N, 2)`` (or one-hot ``(B, N, n)``), ignored for
        parked and absent robots. Returns the new state and ``out`` with, per robot ``(B, N)``:
        ``observation`` ``(B, N, D)``, ``reward``, ``terms`` (dict of weighted terms), ``terminated``,
        ``truncated`` (a parked robot stays terminated until its env resets; absent robots follow the env), ``success``, ``collision``, ``robot_collision``; per env ``(B,)``:
        ``team_terminated``, ``team_truncated``, ``team_success``."""
        b, n = state.present.shape
        robots = state.robots
        active = robots.present & ~robots.parked
        twist = self.nav.command(action.reshape(b * n, -1)).reshape(b, n, 2)
        sim = step_robots(state.sim, twist, state.world, self.nav.params, robots, generator=generator)
        pose = sim.robots.pose
        dist, bearing = NavTask.goal_vector(pose.reshape(b * n, 3), state.goal.reshape(b * n, 2))
        dist, bearing = dist.reshape(b, n), bearing.reshape(b, n)
        collision = sim.robots.collided & active
        robot_collision = collision & (robot_clearance(pose[..., :2], self.nav.params.robot_radius, state.present) <= 0)
        success = (dist < self.cfg.goal_tolerance) & ~collision & active
        progress = torch.where(active, state.goal_dist - dist, 0.0)
        flat = lambda t: t.reshape(b * n, *t.shape[2:])  # noqa: E731
        terms = reward_terms(self.nav.weights, self.cfg.reward, success=flat(success), collision=flat(collision), vel=flat(sim.robots.vel),
                             d_min=flat(sim.robots.ranges.amin(-1)), progress=flat(progress), bearing=flat(bearing))
        terms = {k: torch.where(active, v.reshape(b, n), 0.0) for k, v in terms.items()}  # parked and absent robots earn nothing
        stacked = torch.stack(list(terms.values()), -1) if terms else state.ep_terms[..., :0]
        reward = stacked.sum(-1)
        arrived, crashed = state.arrived | success, state.crashed | collision
        steps = state.steps + 1
        team_crash = collision.any(-1) if self.cfg.robots.on_collision == "team" else torch.zeros_like(collision[:, 0])
        driving = state.present & ~(arrived | crashed)
        team_terminated = ~driving.any(-1) | team_crash
        team_truncated = (steps >= self.cfg.max_steps) & ~team_terminated
        # Absent robots follow the team: flagging them done from the start would read as an episode that never began.
        terminated = arrived | crashed | team_terminated[:, None]
        truncated = team_truncated[:, None] & ~terminated
        team_success = (arrived | ~state.present).all(-1) & state.present.any(-1)
        obs = self.observe(sim, state.goal, state.present)
        new = MultiNavState(
            sim=sim, world=state.world, goal=state.goal, start=state.start, present=state.present, arrived=arrived, crashed=crashed,
            goal_dist=torch.where(active, dist, state.goal_dist), family=state.family, difficulty=state.difficulty, steps=steps,
            ep_return=state.ep_return + reward, ep_terms=state.ep_terms + stacked, observation=obs, batch_size=state.batch_size, device=state.device,
        )
        out = {"observation": obs, "reward": reward, "terms": terms, "terminated": terminated, "truncated": truncated, "success": success,
               "collision": collision, "robot_collision": robot_collision, "team_terminated": team_terminated,
               "team_truncated": team_truncated, "team_success": team_success}
        return new, out
