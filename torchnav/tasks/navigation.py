"""The lidar navigation task: reset sampling, observation, reward terms, termination.

``NavTask.step`` and ``NavTask.reset`` are pure functions of an explicit
``NavState`` (no TorchRL here), so a differentiable rollout through task and
simulator is possible: ``state, out = task.step(state, action)``.
"""

from __future__ import annotations

import contextlib
import math
from typing import Any, Callable

import torch
from tensordict import tensorclass
from torch import Tensor

from ..maps import load_map
from .. import observation as O
from ..observation import FAR, drop_crumb, visit_features  # noqa: F401  (re-exported: the task's breadcrumbs)
from ..maps.free_space import check_room
from ..sim import EnvParams, SimState, World, init_state, nominal_env_params, pad_world, safe_hypot, sample_env_params
from ..sim.kinematics import guard_bearings
from ..sim.movers import Movers
from ..sim.randomize import max_delay
from ..sim.static_map import StaticMap, compiled_march, static_reach
from ..worlds import RobotPlacement, mix_worlds, slot_counts
from ..worlds.guide import GUIDE_CELLS, goal_distance
from ..sim import step as sim_step
from .base import BatchedTask, EpisodePool, TaskState
from .config import NavConfig
from .curriculum import CurriculumState, after_placements
from .rewards import resolve_weights, reward_terms
from .sampling import MoverSource, obstacle_clearance, place_movers, place_random_objects, sample_goals, sample_starts


SHARED_MAP_MIN = 256  # fixed obstacles from which shared_map: auto holds a map once for the batch


class NavTask(BatchedTask):
    """Configured navigation task for ``num_envs`` envs on ``device``. ``share_map=False`` keeps a copy
    of the map in every env whatever ``cfg.shared_map`` says (the multi-robot task's)."""

    def __init__(self, cfg: NavConfig, num_envs: int, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32,
                 share_map: bool = True):
        super().__init__(cfg, num_envs, device, dtype)
        self.families = tuple(cfg.worlds.families)  # procedural worlds instead of the map when non-empty
        self.spec = None if self.families else load_map(cfg.map)  # the map; None with procedural worlds
        if self.spec is not None:  # a map with no room for a start or a goal is refused before any episode
            check_room(self.spec, cfg.robot.radius + cfg.reset.start_clearance, cfg.reset.goal_clearance)
        self.params = cfg.sim_params()
        share = share_map and self.spec is not None and (cfg.shared_map == "on" or (cfg.shared_map == "auto" and self.spec.n_fixed >= SHARED_MAP_MIN))
        # The map's fixed obstacles once for the batch (sim/static_map.py): indexed for the sensors (a ray
        # scan marches past a short reach) and for the clearance tests of the reset samplers. None:
        # every env's world holds a copy.
        self.static: StaticMap | None = self.spec.static_map(static_reach(self.params, march=True), self.device, dtype) if share else None
        self.randomized = cfg.randomize.ranges()  # domain randomisation: parameter -> (min, max)
        self.delay_steps = max_delay(self.randomized)
        # The largest robot the episode may draw decides how much room a start needs.
        self.max_radius = max(cfg.robot.radius, self.randomized.get("robot_radius", (0.0, 0.0))[1])
        # Moving discs placed at every reset: the map's moving_circles, or worlds.movers in every generated world.
        self.world_movers = cfg.worlds.mover_spec() if self.families else None
        movers = self.world_movers if self.families else self.spec.movers
        self.n_movers = movers.count if movers else 0
        self.weights = resolve_weights(cfg.reward)
        # reward.progress_distance: geodesic keeps each episode's grid of path distances to its goal.
        self.guide_cells = GUIDE_CELLS if cfg.reward.progress_distance == "geodesic" else 0
        self.term_names = tuple(self.weights)
        self.n_sectors, self.n_imu, self.n_depth, self.n_visits = O.frame_sizes(cfg)
        self.visit_memory = cfg.observation.visit_memory if self.n_visits else 0  # breadcrumbs kept per env
        self.frame_size = self.n_sectors + 4 + self.n_imu + self.n_depth + self.n_visits
        self.obs_size = self.frame_size * cfg.observation.history
        if self.families:
            self._family_weights = torch.tensor([cfg.worlds.families[f] for f in self.families], dtype=dtype, device=self.device)
            self.slots = slot_counts(self.families)  # every episode's world is padded to these
            self.base_world = None  # every episode brings its own world
        else:
            # Fixed obstacles with every random slot masked off; resets fill the random slots.
            self.base_world = self.spec.build_world(num_envs, device=self.device, dtype=dtype, fixed=self.static is None)
        self.discrete_twists = O.discrete_twists(cfg, dtype, self.device)
        self._obs_scale = O.obs_scale(cfg, dtype, self.device)
        guarded = cfg.action.stop_clearance is not None
        self._guard_bearings = guard_bearings(self.params.lidar, dtype, self.device) if guarded else None
        self._sim_step, self._guarded = sim_step, O.guarded
        self._first_scans = contextlib.nullcontext  # how fresh episodes' first scans march (compile_step: compiled)
        self._fixed_rows: dict = {}  # full_world's cache: (device, dtype) -> the map's fixed rows of one env

    def full_world(self, world: World) -> World:
        """``world`` (some envs' ``NavState.world``) with the map's fixed obstacles as its first slots, as
        every env holds them without ``shared_map``: for renderers, recorders and planners that read
        every obstacle. ``world`` itself when the map is not shared."""
        if self.static is None:
            return world
        key = (world.device, world.boxes.dtype)
        if key not in self._fixed_rows:  # the map's fixed obstacles of one env, built once (recorders call this every step)
            one = self.spec.build_world(1, device=world.device, dtype=world.boxes.dtype)
            nc, nb = self.spec.n_fixed_circles, self.spec.n_fixed_boxes
            self._fixed_rows[key] = (one.segments, one.segment_mask, one.circles[:, :nc], one.circle_mask[:, :nc], one.boxes[:, :nb], one.box_mask[:, :nb])
        seg, seg_mask, circ, circ_mask, box, box_mask = self._fixed_rows[key]
        b = world.batch_size[0]
        rows = lambda t: t.expand(b, *t.shape[1:])  # noqa: E731
        return world.replace(segments=rows(seg).clone(), segment_mask=rows(seg_mask).clone(),
                             circles=torch.cat((rows(circ), world.circles), 1), circle_mask=torch.cat((rows(circ_mask), world.circle_mask), 1),
                             boxes=torch.cat((rows(box), world.boxes), 1), box_mask=torch.cat((rows(box_mask), world.box_mask), 1))

    def compile_step(self) -> None:
        """Run the simulator step through ``torch.compile`` from now on (same results; the first
        step compiles, 20-60 s on 2 CPU cores). Pays for long runs on many obstacles: the
        generalist's sector scan over 200 padded slots steps 4.5x faster (docs/performance.md). The
        arc speed guard (``action.stop_path: arc``) is compiled with it (4x faster at 2,048 envs), and
        on a shared map the fresh episodes' first scans march with compiled steps."""
        self._sim_step = torch.compile(sim_step)
        self._first_scans = compiled_march
        if self.cfg.action.stop_path == "arc":
            self._guarded = torch.compile(O.guarded)

    # -- actions and observations -------------------------------------------------

    def command(self, action: Tensor) -> Tensor:
        """Policy action -> twist ``(B, 2)`` in m/s and rad/s (``torchnav.observation.command``).

        Continuous: ``(B, 2)`` in [-1, 1] (clamped); a[0] -> v in [0, v_max] (forward only)
        or [-v_max, v_max], a[1] -> omega in [-omega_max, omega_max]. Discrete: one-hot ``(B, n)``.
        """
        return O.command(self.cfg, action, self.discrete_twists, self.dtype)

    @property
    def unit_features(self) -> Tensor:
        """The visit memory's values (:meth:`BatchedTask.unit_features`): random actions hardly
        leave the start, so their spread under them says nothing of a policy's."""
        frame = torch.zeros(self.frame_size, dtype=torch.bool, device=self.device)
        frame[self.frame_size - self.n_visits:] = True
        return frame.repeat(self.cfg.observation.history)

    @staticmethod
    def goal_vector(pose: Tensor, goal: Tensor) -> tuple[Tensor, Tensor]:
        """Distance (m) and bearing (rad, robot frame, CCW) from ``pose`` ``(B, 3)`` to ``goal`` ``(B, 2)``."""
        return O.goal_vector(pose, goal)

    def observe(self, sim: SimState, goal: Tensor, crumbs: Tensor | None = None) -> Tensor:
        """One observation ``(B, D)``: lidar sectors, goal distance and bearing, (v, omega), then the
        IMU reading (``observation.imu``), the camera's depth row (``observation.camera``) and the
        breadcrumbs ``crumbs`` ``(B, K, 2)`` seen per sector (``observation.visit_sectors``);
        ``torchnav.observation.observation_frame``, which a robot's observation is built with too."""
        return O.observation_frame(self.cfg, self._obs_scale, sim.ranges, sim.pose, sim.odom, sim.vel, goal, crumbs,
                                   sim.imu if self.n_imu else None, sim.cam_depth if self.n_depth else None)

    # -- reset ----------------------------------------------------------------------

    def _fresh(self, idx: Tensor, cur: CurriculumState, generator: torch.Generator, given: tuple[Tensor, Tensor] | None = None) -> NavState:
        """New episodes for envs ``idx`` ``(n,)``; ``given`` ``(start (n, 3), goal (n, 2))`` replaces the
        sampled starts and goals (a map only, checked by :meth:`place_episodes`)."""
        c, rc = self.cfg, self.cfg.reset
        n = idx.shape[0]
        guide = None
        if self.families:
            world, start, goal, family, difficulty, bounds, guide = self._generated(n, cur, generator)
        else:
            world = self.base_world[idx]
            if given is None:
                start, _ = sample_starts(world, self.spec, self.max_radius + rc.start_clearance, rc.candidates, generator, static=self.static)
                goal, _ = sample_goals(world, self.spec, start[:, :2], c.curriculum.min_radius, cur.radius, rc.goal_clearance, rc.candidates, generator,
                                       static=self.static)
            else:
                start, goal = given
            world = place_random_objects(
                world, self.spec, start[:, :2], goal, rc.candidates, generator,
                start_need=self.max_radius + rc.start_clearance, goal_need=rc.goal_clearance, static=self.static,
            )
            family = torch.zeros(n, dtype=torch.int64, device=self.device)
            difficulty = torch.zeros(n, dtype=self.dtype, device=self.device)
        if guide is not None:
            goal_field, goal_frame = guide
        else:  # no goal grids (reward.progress_distance: euclidean): (n, 0, 0)
            goal_field = torch.zeros(n, self.guide_cells, self.guide_cells, dtype=torch.int16, device=self.device)
            goal_frame = torch.zeros(n, 3, dtype=self.dtype, device=self.device)
        movers = self._movers(world, start[:, :2], goal, bounds if self.families else None, generator)
        if self.randomized:
            env_params = sample_env_params(self.randomized, self.params, n, generator, start)
        else:
            env_params = nominal_env_params(self.params, n, start)
        with self._first_scans():
            sim = init_state(start, world, self.params, movers=movers, env_params=env_params if self.randomized else None,
                             delay_steps=self.delay_steps, static=self.static)
        crumbs, crumb_count = O.first_crumbs(sim.odom, self.visit_memory)  # the first marks the start (no memory without visit_sectors)
        obs = self.observe(sim, goal, crumbs)
        dist, _ = self.goal_vector(sim.pose, goal)
        return NavState(
            world=world, goal=goal, start=start, goal_dist=dist, goal_field=goal_field, goal_frame=goal_frame,
            goal_path=self._progress_distance(goal_field, goal_frame, goal, sim.pose, dist, torch.full_like(dist, math.inf)),
            ep_path=torch.zeros(n, dtype=self.dtype, device=self.device),
            ep_speed_change=torch.zeros(n, dtype=self.dtype, device=self.device),
            ep_turn_change=torch.zeros(n, dtype=self.dtype, device=self.device),
            straight=dist.detach().clone(), family=family, difficulty=difficulty, env_params=env_params,
            crumbs=crumbs, crumb_count=crumb_count, **self._episode_start(sim, obs),
        )

    def _movers(self, world: World, start_xy: Tensor, goal: Tensor, bounds: Tensor | None, generator: torch.Generator) -> Movers | None:
        """This episode's moving obstacles (None without): the map's, or ``worlds.movers`` inside each
        procedural world's ``bounds`` ``(n, 4)``, kept clear of the starts ``start_xy`` and goals ``goal``
        (``(n, 2)``, or ``(n, J, 2)`` for several robots)."""
        if not self.n_movers:
            return None
        rc = self.cfg.reset
        # With procedural worlds each env's movers live in its world's bounds ((n, 1, 1) per edge).
        where = self.spec if bounds is None else MoverSource(self.world_movers, tuple(bounds[:, i, None, None] for i in range(4)))
        return place_movers(world, where, start_xy, goal, rc.candidates, generator,
                            start_need=self.max_radius + rc.start_clearance, goal_need=rc.goal_clearance, static=self.static)

    def _generated(self, n: int, cur: CurriculumState, generator: torch.Generator, robots: RobotPlacement | None = None,
                   ) -> tuple[World, Tensor, Tensor, Tensor, Tensor, Tensor, tuple[Tensor, Tensor] | None]:
        """``n`` procedural episodes: padded worlds, starts ``(n, 3)``, goals ``(n, 2)``, family
        indices ``(n,)``, difficulties ``(n,)``, bounds ``(n, 4)`` and, with the geodesic progress
        reward, each goal's distance grid and its frame; each family at its curriculum difficulty.
        With ``robots`` (the multi-robot task), starts ``(n, N, 3)`` and goals ``(n, N, 2)`` of its robots."""
        levels = {f: cur.difficulty[i] for i, f in enumerate(self.families)}
        batch = mix_worlds(n, dict(zip(self.families, self._family_weights.tolist())), levels, generator, self.device, self.dtype, robot_radius=self.cfg.robot.radius,
                           anywhere_goals=self.cfg.worlds.anywhere_goals, below_level=self.cfg.worlds.below_level, guide_cells=self.guide_cells,
                           guide_margin=self.cfg.reward.geodesic_margin, robots=robots)
        family = torch.tensor([self.families.index(f) for f in batch.family], dtype=torch.int64, device=self.device)
        guide = None if batch.goal_field is None else (batch.goal_field, batch.goal_frame.to(self.dtype))
        return pad_world(batch.world, **self.slots), batch.start, batch.goal, family, batch.difficulty, batch.bounds, guide

    def _progress_distance(self, field: Tensor, frame: Tensor, goal: Tensor, pose: Tensor, dist: Tensor, last: Tensor) -> Tensor:
        """The distance ``(B,)`` m whose decrease the ``progress`` term rewards: the straight ``dist``,
        or with ``reward.progress_distance: geodesic`` the path distance read from the episode's grid,
        ``last`` (the previous step's; ``inf`` until one is known) where the grid has none."""
        if not self.guide_cells:
            return dist
        path = goal_distance(field, frame, goal, pose[:, :2])
        return torch.where(path.isfinite(), path, last)

    @property
    def pooled(self) -> bool:
        """Whether partial resets draw from an :class:`EpisodePool` (``reset.pool > 0``, or procedural
        worlds: generating worlds costs the same for 1 env or 1,000)."""
        return bool(self.cfg.reset.pool > 0 or self.families)

    def initial_state(self, cur: CurriculumState, generator: torch.Generator) -> tuple[NavState, CurriculumState]:
        """Fresh episodes in every env (sampled afresh, not from a pool: start a new :class:`EpisodePool`
        with them) and the curriculum after their placements."""
        idx = torch.arange(self.num_envs, device=self.device)
        return self._fresh(idx, cur, generator), after_placements(cur, self.cfg.curriculum, torch.tensor(self.num_envs, device=self.device))

    def reset(self, state: NavState, mask: Tensor, cur: CurriculumState, generator: torch.Generator,
              pool: EpisodePool | None = None) -> tuple[NavState, CurriculumState]:
        """New episodes for the envs where ``mask`` ``(B,)`` is True; the others are left bit-identical.
        Returns the new state and the curriculum after the placements (each placed goal advances it).

        Only those envs are sampled (``replace_where``), or, when the task is :attr:`pooled`, their
        episodes are taken from ``pool`` (required then; the caller keeps passing the same one),
        which this call draws from and refills in place.
        """
        if self.pooled and pool is None:
            raise ValueError("NavTask.reset: this task draws its resets from an episode pool (reset.pool > 0 or worlds.families): "
                             "pass pool=EpisodePool() and the same pool to every later reset")
        draw = (lambda idx: self._from_pool(pool, idx.numel(), cur, generator)) if self.pooled else (lambda idx: self._fresh(idx, cur, generator))
        state, n = self.replace_where(state, mask, draw)
        return state, (after_placements(cur, self.cfg.curriculum, torch.tensor(n, device=self.device)) if n else cur)

    def place_episodes(self, state: NavState | None, start: Tensor, goal: Tensor, cur: CurriculumState, generator: torch.Generator,
                       mask: Tensor | None = None) -> NavState:
        """Episodes that start at the poses ``start`` ``(B, 3)`` ``[x, y, heading]`` with goals at ``goal``
        ``(B, 2)``, in the envs where ``mask`` ``(B,)`` is True (every env when ``None``, and ``state`` may
        then be ``None``); the other envs keep their episodes, and their rows of ``start`` and ``goal``
        are not used. The map's random objects and moving obstacles are placed around them as in a
        sampled episode. The curriculum does not move: these goals were not drawn from it.

        Raises ``ValueError`` before placing anything if the task generates its worlds (they bring their
        own starts and goals), if the shapes are wrong or a value is not finite, or if a start lies
        closer than the robot's radius to the map's obstacles or its edge, or a goal inside an obstacle.
        """
        if mask is not None and state is None:
            raise ValueError("place_episodes: a mask needs the current state (the envs outside it keep their episodes)")
        idx = torch.arange(self.num_envs, device=self.device) if mask is None else mask.reshape(-1).nonzero().squeeze(-1)
        start, goal = self.check_episodes(start, goal, idx)
        fresh = lambda i: self._fresh(i, cur, generator, (start[i], goal[i]))  # noqa: E731
        return fresh(idx) if mask is None else self.replace_where(state, mask, fresh)[0]

    def check_episodes(self, start: Tensor, goal: Tensor, idx: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """``start`` ``(B, 3)`` and ``goal`` ``(B, 2)`` as tensors of the task's dtype and device, checked as
        :meth:`place_episodes` says (only the rows ``idx`` for the places); ``ValueError`` names the envs."""
        start = torch.as_tensor(start, dtype=self.dtype, device=self.device)
        goal = torch.as_tensor(goal, dtype=self.dtype, device=self.device)
        b = self.num_envs
        if start.shape != (b, 3) or goal.shape != (b, 2):
            raise ValueError(f"place_episodes: start must be ({b}, 3) [x, y, heading] and goal ({b}, 2) [x, y], "
                             f"got {tuple(start.shape)} and {tuple(goal.shape)}")
        idx = torch.arange(b, device=self.device) if idx is None else idx
        self.check_places(start[idx], goal[idx], "envs", idx)
        return start, goal

    def check_places(self, start: Tensor, goal: Tensor, noun: str = "episodes", names: Tensor | None = None) -> None:
        """Raise ``ValueError`` unless the task is on a map and every start ``(E, 3)`` and goal ``(E, 2)`` is
        finite, every start at least the robot's radius from the map's fixed obstacles and edge and every
        goal outside them (the map's random objects are placed later, around them). The message names
        the rows as ``noun`` with the indices ``names`` (default ``0 .. E-1``)."""
        if self.families:
            raise ValueError("place_episodes: this task generates its worlds (worlds.families), and they bring their own starts "
                             "and goals; given starts and goals need a map (cfg.map)")
        start = torch.as_tensor(start, dtype=self.dtype, device=self.device)
        goal = torch.as_tensor(goal, dtype=self.dtype, device=self.device)
        names = torch.arange(len(start), device=self.device) if names is None else names
        for name, t in (("start", start), ("goal", goal)):
            bad = (~torch.isfinite(t)).any(-1)
            if bad.any():
                raise ValueError(f"place_episodes: {name} is not finite in {noun} {names[bad][:10].tolist()}")
        world = self.base_world[torch.zeros(len(start), dtype=torch.int64, device=self.device)]  # the map's fixed obstacles
        xmin, ymin, xmax, ymax = self.spec.bounds
        for name, xy, need in (("start", start[:, :2], self.max_radius), ("goal", goal, 0.0)):
            edge = torch.stack((xy[:, 0] - xmin, xmax - xy[:, 0], xy[:, 1] - ymin, ymax - xy[:, 1]), -1).amin(-1)
            clear = torch.minimum(obstacle_clearance(xy[:, None], world, self.static)[:, 0], edge)
            bad = (clear < need) if need > 0 else (clear <= 0)
            if bad.any():
                what = f"closer than the robot's radius {need:g} m to" if need > 0 else "inside"
                raise ValueError(f"place_episodes: the {name} of {noun} {names[bad][:10].tolist()} lies {what} an obstacle of map "
                                 f"{self.cfg.map!r} or its edge (clearance {[round(v, 3) for v in clear[bad][:10].tolist()]} m)")

    def _from_pool(self, pool: EpisodePool, n: int, cur: CurriculumState, generator: torch.Generator,
                   fresh: Callable[[Tensor], Any] | None = None) -> NavState:
        """``n`` episodes from ``pool``, refilled with ``reset.pool`` new ones (at least ``n``) when it runs
        short; each pooled episode fits any env. Why, and ``reset.reuse``: docs/tasks.md, "Episode pool".
        ``fresh(idx)``: new episodes for the env indices ``idx`` (default this task's; the multi-robot task passes its own)."""
        fresh = fresh or (lambda idx: self._fresh(idx, cur, generator))

        def refill(n: int) -> NavState:
            size = max(self.cfg.reset.pool or self.num_envs, n)
            return fresh(torch.arange(size, device=self.device) % self.num_envs)

        return pool.take(n, self.cfg.reset.reuse, generator, refill)

    # -- step -------------------------------------------------------------------------

    def step(self, state: NavState, action: Tensor, generator: torch.Generator | None = None) -> tuple[NavState, dict[str, Tensor]]:
        """Advance every env one step. Pure: ``state`` is not modified.

        Returns the new state and ``out`` with ``observation`` ``(B, H*D)``, ``reward`` ``(B,)``,
        ``terms`` (dict of ``(B,)`` weighted reward terms), ``terminated``, ``truncated``,
        ``success``, ``collision`` ``(B,)`` bool.
        """
        twist = self.command(action)
        radius = state.env_params.robot_radius if self.randomized else self.params.robot_radius
        twist = self._guarded(self.cfg, twist, state.sim.ranges, self.params.lidar, radius, self.params.dt, self._guard_bearings,
                              state.sim.cmd_queue)
        sim = self._sim_step(state.sim, twist, state.world, self.params, generator=generator,
                             env_params=state.env_params if self.randomized else None, static=self.static)
        dist, bearing = self.goal_vector(sim.pose, state.goal)
        collision = sim.collided
        success = (dist < self.cfg.goal_tolerance) & ~collision
        goal_path = self._progress_distance(state.goal_field, state.goal_frame, state.goal, sim.pose, dist, state.goal_path)
        # 0 until a first reading (goal_path then carries the last one), so the terms sum to the first known distance minus the last.
        progress = torch.where(state.goal_path.isfinite(), state.goal_path - goal_path, 0.0)
        terms = reward_terms(
            self.weights, self.cfg.reward, success=success, collision=collision, vel=sim.vel,
            d_min=sim.ranges.amin(-1), progress=progress, bearing=bearing,
        )
        crumbs, crumb_count = state.crumbs, state.crumb_count
        if self.visit_memory:
            crumbs, crumb_count = drop_crumb(crumbs, crumb_count, sim.odom, self.cfg.observation.visit_spacing)
        common, reward = self._episode_step(state, sim, self.observe(sim, state.goal, crumbs), terms)
        terminated = success | collision
        truncated = (common["steps"] >= self.cfg.max_steps) & ~terminated
        new = NavState(
            world=state.world, goal=state.goal, start=state.start, goal_dist=dist, goal_field=state.goal_field, goal_frame=state.goal_frame,
            goal_path=goal_path,
            ep_path=state.ep_path + safe_hypot(sim.pose[:, 0] - state.sim.pose[:, 0], sim.pose[:, 1] - state.sim.pose[:, 1]),
            ep_speed_change=state.ep_speed_change + (sim.vel[:, 0] - state.sim.vel[:, 0]).detach().abs(),
            ep_turn_change=state.ep_turn_change + (sim.vel[:, 1] - state.sim.vel[:, 1]).detach().abs(),
            straight=state.straight, family=state.family, difficulty=state.difficulty, env_params=state.env_params,
            crumbs=crumbs, crumb_count=crumb_count, **common,
        )
        history = common["history"]
        out = {
            "observation": history.reshape(history.shape[0], -1), "reward": reward, "terms": terms,
            "terminated": terminated, "truncated": truncated, "success": success, "collision": collision,
        }
        return new, out


@tensorclass
class NavState(TaskState):
    """Per-env navigation state, all ``(B, ...)``: :class:`~torchnav.tasks.base.TaskState`
    (``history`` ``(B, H, D)`` of observation frames) and the episode's world and goal."""

    world: World  # obstacles of this episode
    goal: Tensor  # (B, 2) m
    start: Tensor  # (B, 3) start pose
    goal_dist: Tensor  # (B,) m to the goal after the last step
    goal_field: Tensor  # (B, G, G) int16 cm path distances to the goal (G = 64 with reward.progress_distance: geodesic, else 0); worlds/guide.py
    goal_frame: Tensor  # (B, 3) [x0, y0, cell m] of goal_field
    goal_path: Tensor  # (B,) m, the distance the progress term measures after the last step (goal_dist unless geodesic; inf until known)
    ep_path: Tensor  # (B,) m driven this episode
    ep_speed_change: Tensor  # (B,) m/s, the sum over this episode's steps of |change of the driven speed| (from rest at the start)
    ep_turn_change: Tensor  # (B,) rad/s, the same for the driven turn rate
    straight: Tensor  # (B,) m start-goal distance
    family: Tensor  # (B,) int64 index of the episode's world family in cfg.worlds.families (0 without)
    difficulty: Tensor  # (B,) that family's difficulty in [0, 1]
    env_params: EnvParams  # per-env robot and sensor parameters (cfg.randomize; cfg's values when none)
    crumbs: Tensor  # (B, K, 2) m, breadcrumbs dropped along the odometry's path (K = observation.visit_memory, 0 when off); FAR where none yet
    crumb_count: Tensor  # (B,) int64 breadcrumbs dropped this episode (the newest is at (count - 1) % K)
