"""What NavEnv and LineEnv share: the batch, the explicit generator, the specs every task has,
the action checks, resets and steps around a pure task, and the checkpoint state.

A task env subclasses :class:`BatchedEnv`, builds its specs with ``_make_specs(**fields)`` and
fills in the hooks listed in docs/api.md (``torchnav.envs``)."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, OneHot, Unbounded
from torchrl.envs import EnvBase

from ..tasks import EpisodePool


def _leaves(d: dict[str, Any]):
    for v in d.values():
        if isinstance(v, dict):
            yield from _leaves(v)
        else:
            yield v


MAX_ENVS = 1 << 24  # envs of one batch: more would not fit the per-env state in memory

class BatchedEnv(EnvBase):
    """``batch_size=(num_envs,)`` env stepping a pure task with one ``torch.Generator`` seeded by ``seed``."""

    _has_dynamic_specs = False
    config_class: type = object  # the task's config (its default when ``cfg`` is None) and the task
    task_class: type = object

    def __init__(self, cfg: Any = None, num_envs: int = 64, device: torch.device | str = "cpu", seed: int | None = 0) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or not 1 <= num_envs <= MAX_ENVS:
            raise ValueError(f"num_envs must be an integer in [1, {MAX_ENVS:,}], got {num_envs!r}")
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self._generator = torch.Generator(device=self.device)
        self._generator.manual_seed(0 if seed is None else int(seed))
        self._state: Any = None
        self.cfg = cfg or self.config_class()
        self.task = self.task_class(self.cfg, num_envs, device=self.device)
        self._make_specs()

    def _flag_spec(self) -> Categorical:
        return Categorical(2, shape=(*self.batch_size, 1), dtype=torch.bool, device=self.device)

    episode_keys: tuple[str, ...] = ("return", "length")  # a task's own statistics follow, then one per reward term

    def _make_specs(self, **fields: Any) -> None:
        """The observation spec: ``observation`` and the task's ``fields``, then what every task outputs:
        ``pose``, ``ranges``, the outcome flags, ``reward_terms`` and ``episode``; the action and done specs."""
        b, dev, terms = self.batch_size, self.device, self.task.term_names
        scalar = lambda: Unbounded(shape=(*b, 1), device=dev)  # noqa: E731
        self.observation_spec = Composite(
            **fields, pose=Unbounded(shape=(*b, 3), device=dev), **{f: self._flag_spec() for f in self.flag_keys},
            reward_terms=Composite({k: scalar() for k in terms}, shape=b, device=dev),
            episode=Composite({k: scalar() for k in (*self.episode_keys, *(f"term_{k}" for k in terms))}, shape=b, device=dev),
            shape=b, device=dev,
        )
        self._make_action_done_specs(self.cfg.action)

    def _make_action_done_specs(self, action_cfg) -> None:
        """One-hot over ``action_cfg.discrete_set`` (mode ``discrete``) or 2 values in [-1, 1]; reward and done flags."""
        b, dev = self.batch_size, self.device
        if action_cfg.mode == "discrete":
            n = len(action_cfg.discrete_set)
            self.action_spec = OneHot(n, shape=(*b, n), device=dev)
        else:
            self.action_spec = Bounded(-1.0, 1.0, shape=(*b, 2), device=dev)
        self.reward_spec = Unbounded(shape=(*b, 1), device=dev)
        self.done_spec = Composite(done=self._flag_spec(), terminated=self._flag_spec(), truncated=self._flag_spec(), shape=b, device=dev)

    def _assert_tensordict_shape(self, tensordict: TensorDictBase) -> None:
        # TorchRL's ``step`` and ``reset`` call this before anything else; its own check raises a
        # bare RuntimeError, and a TensorDict of another batch size is almost always an action of
        # another batch size (``TensorDict({"action": a}, batch_size=a.shape[:1])``).
        if tensordict.batch_size != self.batch_size:
            raise ValueError(f"{type(self).__name__}: the input TensorDict has batch size {tuple(tensordict.batch_size)}, expected "
                             f"{tuple(self.batch_size)} (one row per env; an action is {tuple(self.action_spec.shape)})")

    def _checked_action(self, tensordict, key: str | tuple[str, ...] = "action", spec: Any = None, per: str = "env") -> torch.Tensor:
        """The action under ``key`` (of ``spec``, default the action spec): a tensor on the env's
        device of the spec's shape, real, floating point when continuous (else a ValueError naming
        what is allowed). With ``cfg.check_actions`` (one host sync) a NaN or inf, or in mode
        ``discrete`` a row that is not one-hot (one 1, the rest 0), raises naming the envs."""
        spec = self.action_spec if spec is None else spec
        name = key if isinstance(key, str) else repr(key)
        action = tensordict.get(key, None)
        if not isinstance(action, torch.Tensor):
            shown = f'"{key}"' if isinstance(key, str) else repr(key)
            raise ValueError(f"{type(self).__name__}.step: the input needs an {shown} tensor of shape {tuple(spec.shape)}, "
                             f"got {type(action).__name__}")
        self._check_action_layout(action, spec.shape, name, per)
        if self.cfg.check_actions:
            discrete = self.cfg.action.mode == "discrete"
            # one reduction, one sync on the good path; the envs are named only on the error path
            ok = (((action == 0) | (action == 1)).all(-1) & (action.sum(-1) == 1)) if discrete else torch.isfinite(action).all(-1)
            if not bool(ok.all()):
                bad = (~ok).reshape(action.shape[0], -1).any(-1).nonzero().squeeze(-1).tolist()
                envs = f"envs {bad[:10]}{'...' if len(bad) > 10 else ''}"
                if not bool(torch.isfinite(action).all()):
                    raise ValueError(f"{type(self).__name__}.step: action contains NaN or inf in {envs}; fix the policy, or pass "
                                     "check_actions=False to let the simulator treat them as a stop command")
                raise ValueError(f"{type(self).__name__}.step: a discrete action must be one-hot over the {spec.shape[-1]} entries of "
                                 f"action.discrete_set (one 1 per {per}, the rest 0); not so in {envs}")
        return action

    def _check_action_layout(self, action: torch.Tensor, shape: tuple[int, ...], name: str = "action", per: str = "env") -> None:
        """Device, shape and dtype of an action, from its metadata only (no host sync)."""
        where = type(self).__name__
        if action.device != self.device:
            raise ValueError(f"{where}.step: {name} is on device {action.device}, expected the env's device {self.device}")
        if action.shape != shape:
            raise ValueError(f"{where}.step: {name} has shape {tuple(action.shape)}, expected {tuple(shape)} "
                             f"({shape[-1]} values per {per}{f', {shape[1]} robots,' if len(shape) == 3 else ' for'} {self.num_envs} envs)")
        if self.cfg.action.mode != "discrete" and not action.is_floating_point():
            raise ValueError(f"{where}.step: a continuous action must be a floating-point tensor, got {action.dtype}")
        if action.is_complex():
            raise ValueError(f"{where}.step: {name} must be a real tensor, got {action.dtype}")

    # -- TorchRL hooks: one reset and one step for every task ------------------------------

    flag_keys: tuple[str, ...] = ()  # the task's outcome flags, each (B, 1) bool in every output
    reset_options: tuple[str, ...] = ()  # keyword arguments ``reset`` passes on to ``_new_state`` (NavEnv: start, goal)

    # ``reset(set_state=True)`` (TorchRL's deterministic reset) continues the episodes the env holds,
    # drawing nothing: after ``load_state_dict``, a collector's ``reset(set_state=True)`` resumes a run.
    _supports_set_state = True

    def _reset(self, tensordict: TensorDictBase | None = None, set_state: bool = False, **options: Any) -> TensorDictBase:
        """New episodes in every env, or where the ``"_reset"`` mask ``(B, 1)`` of ``tensordict`` is set;
        ``options`` (``env.reset(td, **options)``, one of :attr:`reset_options` each) say how to place them.
        With ``set_state=True`` the episodes the env holds go on (nothing is drawn)."""
        unknown = sorted(set(options) - set(self.reset_options))
        if unknown:
            raise ValueError(f"{type(self).__name__}.reset: unknown options {unknown}; it takes {list(self.reset_options) or 'none'}")
        if set_state:
            if self._state is None:
                raise RuntimeError(f"{type(self).__name__}.reset(set_state=True): the env holds no episodes to continue")
            if options:
                raise ValueError(f"{type(self).__name__}.reset: set_state=True continues the episodes it holds; it takes no {sorted(options)}")
        else:
            mask = None if tensordict is None else tensordict.get("_reset", None)
            # Out of place: the previous step's outputs share storage with the old state.
            self._state = self._new_state(None if self._state is None or mask is None else mask.reshape(-1), **options)
        s = self._state
        # Separate tensors per key: TorchRL may write into them in place, so they must not alias.
        false = lambda: torch.zeros(*self.batch_size, 1, dtype=torch.bool, device=self.device)  # noqa: E731
        obs, flags = self._reset_view(s)
        terms = {k: torch.zeros(self.batch_size, dtype=obs.dtype, device=self.device) for k in self.task.term_names}
        out = self._outputs(s, obs, terms, {f: flags[f] if f in flags else false() for f in self.flag_keys})
        out.update({"done": false(), "terminated": false(), "truncated": false()})
        return out

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = self._checked_action(tensordict)
        self._state, out = self.task.step(self._state, action, self._generator)
        self._after_step(out)
        terminated, truncated = out["terminated"][:, None], out["truncated"][:, None]
        td = self._outputs(self._state, out["observation"], out["terms"], {f: out[f][:, None] for f in self.flag_keys})
        td.update({"reward": out["reward"][:, None], "done": terminated | truncated, "terminated": terminated, "truncated": truncated})
        return td

    # -- differentiable rollouts: the task on the env's state, outside TorchRL's step ---------

    def advance(self, action: torch.Tensor) -> tuple[Any, dict[str, torch.Tensor]]:
        """One step of the task on the env's current state, then new episodes where one ended.

        What ``step`` does without TorchRL's specs, output TensorDict or the action's value checks
        (NaN, one-hot: they would cost a host sync; device, shape and dtype are checked), and
        without ``torch.no_grad``: the new state keeps the autograd graph from ``action`` (and
        from earlier steps, until :meth:`detach_state`), so a loss on the task's outputs can be
        backpropagated through the simulator (recipes/apg_lidar.py). The curriculum advances
        as in ``step``. A reset replaces only the finished envs' rows, out of place: their fresh
        state carries no graph, the others keep theirs.

        Returns the state before the reset (the finished episodes' last state) and the task's
        ``out`` dict (``observation`` is also the one before the reset).
        """
        self._check_action_layout(action, self.action_spec.shape)
        state, out = self.task.step(self._state, action, self._generator)
        self._state = state
        self._after_step(out)
        self._state = self._new_state(out["terminated"] | out["truncated"])
        return state, out

    def observation(self) -> torch.Tensor:
        """The policy's observation ``(B, obs_size)`` of the current state (with its graph, after :meth:`advance`)."""
        return self._reset_view(self._state)[0]

    def detach_state(self) -> None:
        """Cut the autograd graph of the current state (between the horizons of a differentiable rollout)."""
        self._state = self._state.detach()

    def _new_state(self, mask: torch.Tensor | None, **options: Any) -> Any:
        """The state after new episodes in every env (``mask`` None) or where ``mask`` ``(B,)`` is True."""
        raise NotImplementedError

    def _reset_view(self, state: Any) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        raise NotImplementedError

    def _after_step(self, out: dict[str, torch.Tensor]) -> None:
        pass

    def _task_outputs(self, state: Any) -> dict[str, torch.Tensor]:
        return {}

    def _episode_stats(self, state: Any) -> dict[str, torch.Tensor]:
        return {}

    def _outputs(self, s: Any, obs: torch.Tensor, terms: dict[str, torch.Tensor], flags: dict[str, torch.Tensor]) -> TensorDict:
        """The output TensorDict of a reset or step (``reward`` and the done flags are added by the caller)."""
        col = lambda x: x.reshape(*self.batch_size, 1)  # noqa: E731
        episode = {"return": s.ep_return, "length": s.steps.to(s.ep_return.dtype), **self._episode_stats(s),
                   **{f"term_{k}": s.ep_terms[:, i] for i, k in enumerate(self.task.term_names)}}
        return TensorDict({
            "observation": obs, **self._task_outputs(s), "pose": s.sim.pose, "ranges": s.sim.ranges, **flags,
            "reward_terms": {k: col(v) for k, v in terms.items()}, "episode": {k: col(v) for k, v in episode.items()},
        }, batch_size=self.batch_size, device=self.device)

    def _set_seed(self, seed: int | None) -> None:
        self._generator.manual_seed(0 if seed is None else int(seed))

    @property
    def num_envs(self) -> int:
        return self.batch_size[0]

    @property
    def state(self):
        """The current task state (read-only use: worlds, goals, poses of every env); None before the first reset."""
        return self._state

    @property
    def generator(self) -> torch.Generator:
        """The ``torch.Generator`` every reset and step of this env draws from (seeded by ``seed``)."""
        return self._generator

    # The env's whole state (generator, episodes in flight, and NavEnv's curriculum and episode
    # pool) goes through nn.Module's extra-state hooks, so ``env.state_dict()`` and
    # ``env.load_state_dict(sd)`` keep nn.Module's signatures and a TransformedEnv's state_dict
    # includes it (under ``base_env._extra_state``). ``state_dict()`` holds copies: taking it,
    # running the env (an observation-statistics rollout, say) and loading it back leaves the env
    # as if that run never happened. The episodes are saved as plain nested dicts of tensors
    # (checkpoints load with ``weights_only=True``).

    extra_state_keys: tuple[str, ...] = ("generator",)  # what every saved env state holds ("episodes" once reset)

    def get_extra_state(self) -> dict[str, Any]:
        """The generator's state and the episodes in flight (:class:`CurriculumPoolState` adds the curriculum and the episode pool)."""
        out: dict[str, Any] = {"generator": self._generator.get_state()}
        if self._state is not None:
            out["episodes"] = self._state.clone().to_dict()  # copies: a view would save its whole storage
        return out

    def set_extra_state(self, state: dict[str, Any]) -> None:
        missing = [k for k in self.extra_state_keys if k not in state]
        if missing:
            raise ValueError(f"{type(self).__name__}.load_state_dict: the saved env state lacks {missing} "
                             f"(it holds {sorted(state)}; an env's state_dict() holds {list(self.extra_state_keys)})")
        # Rebuilding the episodes may place new ones first (a template of the state's structure),
        # which draws from the generator: restore it after them.
        self._state = self.state_from_dict(state["episodes"]) if "episodes" in state else None
        self._generator.set_state(state["generator"])

    def state_from_dict(self, d: dict[str, Any]) -> Any:
        """A task state (of any batch size) rebuilt from its ``to_dict()`` form, in the structure
        of this env's states; a ValueError names a key whose shape does not fit."""
        if self._state is None:
            self._state = self._new_state(None)
        n = next(_leaves(d)).shape[0]
        like = self._state[torch.zeros(n, dtype=torch.long, device=self.device)]
        try:
            return like.apply(lambda old, new: new.to(device=old.device, dtype=old.dtype).expand_as(old).clone(),
                              TensorDict.from_dict(d, batch_size=[n]))
        except (RuntimeError, KeyError) as e:
            raise ValueError(f"{type(self).__name__}: saved episodes do not fit this env's task config ({e})") from None


class CurriculumPoolState:
    """The saved state of an env with a goal curriculum (``self.curriculum``) and a pool of
    pre-sampled episodes (``self.pool``): NavEnv and MultiNavEnv. Put before ``BatchedEnv`` in the
    bases, so that ``super()`` reaches its generator and episodes."""

    extra_state_keys = ("curriculum", "generator", "pool")

    def _drawn_state(self, mask: torch.Tensor | None) -> Any:
        """New episodes in every env (``mask`` None: a fresh pool too) or where ``mask`` is True, and
        the curriculum after their goals."""
        if mask is None:
            self.pool = EpisodePool()
            state, self.curriculum = self.task.initial_state(self.curriculum, self._generator)
        else:
            state, self.curriculum = self.task.reset(self._state, mask, self.curriculum, self._generator, self.pool)
        return state

    def get_extra_state(self) -> dict[str, Any]:
        """Curriculum, generator, episodes in flight and the pool of pre-sampled ones: ``env.state_dict()["_extra_state"]``."""
        return {"curriculum": self.curriculum.state_dict(), **super().get_extra_state(), "pool": self.pool.state_dict()}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        super().set_extra_state(state)  # first: rebuilding the episodes may place new ones, which moves the curriculum and the pool
        self.curriculum.load_state_dict(state["curriculum"])
        self.pool.load_state_dict(state["pool"], self.state_from_dict)
