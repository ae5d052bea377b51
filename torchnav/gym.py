"""Gymnasium interface: the batched tasks as a Gymnasium vector env and as a single env.

Importing this module registers ``torchnav/Navigation-v0`` and ``torchnav/LineFollowing-v0``
(keyword arguments those of :func:`torchnav.envs.make_nav_env` / :func:`torchnav.envs.make_line_env`).
Needs the ``gym`` extra. Spaces, autoreset (``SAME_STEP``) and the ``info`` keys: docs/gymnasium.md."""

from __future__ import annotations

from typing import Any

try:
    import gymnasium
    from gymnasium import spaces
    from gymnasium.vector import AutoresetMode, VectorEnv
    from gymnasium.vector.utils import batch_space
except ImportError as e:  # pragma: no cover - exercised only without the extra
    raise ImportError('torchnav.gym needs gymnasium: pip install "torchnav[gym]"') from e

import numpy as np
import torch
from tensordict import TensorDict

from .config import ConfigError
from .envs import LineEnv, NavEnv, make_nav_env, make_line_env


def _spaces(env: NavEnv | LineEnv) -> tuple[spaces.Box, spaces.Space]:
    obs = env.observation_spec["observation"]
    n = obs.shape[-1]
    if hasattr(obs.space, "low"):
        lo, hi = float(obs.space.low.min()), float(obs.space.high.max())
    else:
        lo, hi = -np.inf, np.inf
    obs_space = spaces.Box(lo, hi, shape=(n,), dtype=np.float32)
    if env.cfg.action.mode == "discrete":
        act_space: spaces.Space = spaces.Discrete(len(env.cfg.action.discrete_set))
    else:
        act_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
    return obs_space, act_space


def _make(kind: str, num_envs: int | None, seed: int | None, device: str, kwargs: dict[str, Any]) -> NavEnv | LineEnv:
    """``num_envs=None``: one robot, where a ``num_envs`` keyword is refused rather than ignored."""
    if num_envs is None:
        if "num_envs" in kwargs:
            raise ConfigError(f"num_envs: the single {kind} env drives one robot; for a batch use gymnasium.make_vec(id, num_envs=N, "
                              "vectorization_mode=\"vector_entry_point\")")
        num_envs = 1
    if kind == "navigation":
        return make_nav_env(num_envs=num_envs, device=device, seed=seed, **kwargs)
    return make_line_env(num_envs=num_envs, device=device, seed=seed, **kwargs)


def _episode_options(env: NavEnv | LineEnv, options: dict[str, Any] | None, batch: tuple[int, ...] = ()) -> tuple[torch.Tensor, torch.Tensor] | None:
    """The ``start`` and ``goal`` of reset ``options`` as ``(B, 3)`` and ``(B, 2)`` tensors (``batch``: the
    leading shape the caller gives them, reshaped to the env's), or ``None`` without options."""
    options = dict(options or {})
    if not options:
        return None
    unknown = sorted(set(options) - {"start", "goal"})
    if unknown or not isinstance(env, NavEnv):
        takes = "'start' and 'goal'" if isinstance(env, NavEnv) else "no options"
        raise ValueError(f"reset: unknown options {unknown or sorted(options)}; this env takes {takes}")
    if "start" not in options or "goal" not in options:
        raise ValueError("reset: options 'start' and 'goal' go together")
    b = env.num_envs
    start, goal = (torch.as_tensor(np.asarray(options[k], dtype=np.float64), dtype=torch.float32) for k in ("start", "goal"))
    if start.shape != (*batch, 3) or goal.shape != (*batch, 2):
        raise ValueError(f"reset: options 'start' must have shape {(*batch, 3)} [x, y, heading] and 'goal' {(*batch, 2)}, "
                         f"got {tuple(start.shape)} and {tuple(goal.shape)}")
    return start.reshape(b, 3), goal.reshape(b, 2)


# What both adapters do with the TorchRL env. Arrays handed out are copies, never views: they
# must not alias the env's tensors (the vector env edits them at autoreset).

def _restart(env: NavEnv | LineEnv, seed: int | None, given: tuple[torch.Tensor, torch.Tensor] | None) -> TensorDict:
    """New episodes in every env; with ``seed`` the env starts over as if new (generator re-seeded,
    navigation curriculum back to its start); ``given`` starts and goals (``NavEnv.reset_to``)."""
    if seed is not None:
        env.set_seed(int(seed))
        if isinstance(env, NavEnv):
            env.restart_curriculum()
    return env.reset() if given is None else env.reset_to(*given)


def _advance(env: NavEnv | LineEnv, td: TensorDict | None, action: torch.Tensor) -> TensorDict:
    """One step of the TorchRL env from its last outputs ``td``; its ``"next"`` outputs (no autoreset)."""
    if td is None:
        raise RuntimeError("call reset() before step()")
    return env.step(td.clone(False).set("action", action))["next"]


def checked_actions(actions: Any, want: tuple[int, ...], n: int | None = None, per: str = "env") -> np.ndarray:
    """``actions`` as a NumPy array of shape ``want``: real numbers (``n`` None), or indices in
    ``[0, n)`` for a ``Discrete(n)`` space; a ValueError names a wrong type, shape, dtype or value
    before anything is converted. Shared by the Gymnasium and PettingZoo adapters."""
    discrete = n is not None
    what = f"{'one index' if discrete else 'two values in [-1, 1]'} per {per}"
    if isinstance(actions, torch.Tensor):
        if actions.device.type == "meta":
            raise ValueError(f"actions are on the meta device (no values); pass {what} as a NumPy array or CPU tensor")
        actions = actions.detach().cpu()
    try:
        a = np.asarray(actions)
    except (TypeError, ValueError) as e:  # ragged lists
        raise ValueError(f"actions must be an array of shape {want} ({what}), got {type(actions).__name__} ({e})") from None
    # Real numbers only: bool, complex, strings and objects have no meaning as commands.
    if a.dtype.kind not in ("i", "u") + (() if discrete else ("f",)):
        raise ValueError(f"actions must be {'integers' if discrete else 'real numbers'} ({what}), got dtype {a.dtype}")
    if a.shape != want:
        raise ValueError(f"actions must have shape {want} ({what}), got {a.shape}")
    if discrete and ((a < 0).any() or (a >= n).any()):
        raise ValueError(f"discrete actions must be integers in [0, {n}), got {actions!r}")
    return a


def _action_tensor(env: NavEnv | LineEnv, space: spaces.Space, actions: Any, single: bool = False) -> torch.Tensor:
    """Gymnasium actions for ``env.num_envs`` envs (indices into a ``Discrete`` ``space``, or ``(B, 2)``
    values; with ``single`` one index or ``(2,)`` values) as the TorchRL env's action (:func:`checked_actions`)."""
    b, discrete = env.num_envs, isinstance(space, spaces.Discrete)
    want = (() if discrete else (2,)) if single else ((b,) if discrete else (b, 2))
    t = torch.as_tensor(checked_actions(actions, want, space.n if discrete else None), device=env.device)
    if discrete:
        return torch.nn.functional.one_hot(t.long().reshape(b), space.n).to(env.action_spec.dtype)
    return t.to(torch.float32).reshape(b, 2)


def _observations(td: TensorDict) -> np.ndarray:
    return np.array(td["observation"].to(torch.float32).cpu().numpy(), copy=True)


def _flags(env: NavEnv | LineEnv, td: TensorDict) -> dict[str, np.ndarray]:
    return {k: np.array(td[k].reshape(-1).cpu().numpy(), copy=True) for k in env.flag_keys}


class TorchnavVectorEnv(VectorEnv):
    """A Gymnasium 1.x vector env over one batched TorchRL env (autoreset ``SAME_STEP``)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, env: NavEnv | LineEnv):
        self.env = env
        self.num_envs = env.num_envs
        self.single_observation_space, self.single_action_space = _spaces(env)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._td: TensorDict | None = None

    def reset(self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start a new episode in every env. With ``seed`` (an int; a list uses its first entry:
        the batch shares one generator) the env starts over as if new: its generator is
        re-seeded and the navigation curriculum goes back to its initial state. Without
        one, both carry on.

        ``options`` (navigation only): ``{"start": (num_envs, 3) [x, y, heading], "goal": (num_envs, 2)}``
        starts these episodes there instead of at sampled places (``NavEnv.reset_to``); any other
        key is an error."""
        if isinstance(seed, (list, tuple)):
            seed = seed[0] if seed else None
        given = _episode_options(self.env, options, (self.num_envs,))  # checked before the env changes
        super().reset(seed=seed)
        if seed is not None:
            self.action_space.seed(int(seed))
        self._td = _restart(self.env, seed, given)
        return _observations(self._td), _flags(self.env, self._td)

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        nxt = self._td = _advance(self.env, self._td, _action_tensor(self.env, self.single_action_space, actions))
        obs, info = _observations(nxt), _flags(self.env, nxt)
        reward = nxt["reward"].reshape(-1).cpu().numpy()
        terminated = nxt["terminated"].reshape(-1).cpu().numpy()
        truncated = nxt["truncated"].reshape(-1).cpu().numpy()
        done = terminated | truncated
        if done.any():
            mask = torch.as_tensor(done, device=self.env.device).reshape(self.num_envs, 1)
            fresh = self.env.reset(TensorDict({"_reset": mask}, batch_size=self.env.batch_size, device=self.env.device))
            final_info = {k: v.copy() for k, v in info.items()}
            final_obs = obs.copy()
            obs[done] = _observations(fresh)[done]
            for k, v in _flags(self.env, fresh).items():  # the finished envs' flags are their new episode's
                info[k][done] = v[done]
            info.update(final_obs=final_obs, _final_obs=done.copy(), final_info=final_info, _final_info=done.copy())
            self._td = fresh
        return obs, reward, terminated, truncated, info

    def close(self, **kwargs: Any) -> None:
        self.env.close()


class TorchnavEnv(gymnasium.Env):
    """One robot as a ``gymnasium.Env`` (a batch of one underneath; no autoreset)."""

    metadata = {"render_modes": []}

    def __init__(self, env: NavEnv | LineEnv):
        if env.num_envs != 1:
            raise ValueError(f"TorchnavEnv wraps a batch of one env, got num_envs={env.num_envs}; use TorchnavVectorEnv for batches")
        self.env = env
        self.observation_space, self.action_space = _spaces(env)
        self._td: TensorDict | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """As :meth:`TorchnavVectorEnv.reset` for one robot: ``options`` ``{"start": (3,), "goal": (2,)}``."""
        given = _episode_options(self.env, options)  # checked before anything changes
        super().reset(seed=seed)
        if seed is not None:
            self.action_space.seed(int(seed))
        self._td = _restart(self.env, seed, given)
        return _observations(self._td)[0], {k: bool(v[0]) for k, v in _flags(self.env, self._td).items()}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        nxt = self._td = _advance(self.env, self._td, _action_tensor(self.env, self.action_space, action, single=True))
        terminated, truncated = bool(nxt["terminated"].item()), bool(nxt["truncated"].item())
        info: dict[str, Any] = {k: bool(v[0]) for k, v in _flags(self.env, nxt).items()}
        if terminated or truncated:
            info["is_success"] = info.get("success", info.get("lap_completed", False))
        return _observations(nxt)[0], float(nxt["reward"].item()), terminated, truncated, info

    def close(self) -> None:
        self.env.close()


def navigation_env(seed: int | None = 0, device: str = "cpu", **kwargs: Any) -> TorchnavEnv:
    """``gymnasium.make("torchnav/Navigation-v0", **kwargs)``: one robot; ``kwargs`` as for ``make_nav_env``."""
    return TorchnavEnv(_make("navigation", None, seed, device, kwargs))


def navigation_vector_env(num_envs: int = 64, seed: int | None = 0, device: str = "cpu", **kwargs: Any) -> TorchnavVectorEnv:
    """``gymnasium.make_vec("torchnav/Navigation-v0", num_envs, vectorization_mode="vector_entry_point")``."""
    return TorchnavVectorEnv(_make("navigation", num_envs, seed, device, kwargs))


def line_env(seed: int | None = 0, device: str = "cpu", **kwargs: Any) -> TorchnavEnv:
    """``gymnasium.make("torchnav/LineFollowing-v0", **kwargs)``: one robot; ``kwargs`` as for ``make_line_env``."""
    return TorchnavEnv(_make("line", None, seed, device, kwargs))


def line_vector_env(num_envs: int = 64, seed: int | None = 0, device: str = "cpu", **kwargs: Any) -> TorchnavVectorEnv:
    """``gymnasium.make_vec("torchnav/LineFollowing-v0", num_envs, vectorization_mode="vector_entry_point")``."""
    return TorchnavVectorEnv(_make("line", num_envs, seed, device, kwargs))


def register_envs() -> None:
    """Register the torchnav ids with Gymnasium (done on import; safe to call again)."""
    for name, single, vector in (("Navigation-v0", "navigation_env", "navigation_vector_env"), ("LineFollowing-v0", "line_env", "line_vector_env")):
        env_id = f"torchnav/{name}"
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=f"torchnav.gym:{single}", vector_entry_point=f"torchnav.gym:{vector}")


register_envs()


def sb3_vec_env(vec: TorchnavVectorEnv):
    """The batched env as a Stable-Baselines3 ``VecEnv`` (needs ``pip install "torchnav[sb3]"``).

    SB3 does not take Gymnasium vector envs; this adapter gives SB3's algorithms the
    whole batch in one call per step instead of ``num_envs`` single envs. Finished
    episodes carry ``terminal_observation``, ``TimeLimit.truncated`` and ``is_success``
    in their info dict, as SB3 expects. Wrap it in ``VecMonitor`` for episode returns.
    """
    try:
        from stable_baselines3.common.vec_env import VecEnv
    except ImportError as e:
        raise ImportError('torchnav.gym.sb3_vec_env needs stable-baselines3: pip install "torchnav[sb3]"') from e

    class TorchnavSB3VecEnv(VecEnv):
        render_mode = None

        def __init__(self) -> None:
            super().__init__(vec.num_envs, vec.single_observation_space, vec.single_action_space)
            self.vec = vec
            self._actions: np.ndarray | None = None

        def reset(self) -> np.ndarray:
            seed = next((s for s in self._seeds if s is not None), None)
            obs, _ = self.vec.reset(seed=seed)
            self._reset_seeds()
            return obs

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = actions

        def step_wait(self):
            obs, reward, terminated, truncated, info = self.vec.step(self._actions)
            done = terminated | truncated
            infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
            if done.any():
                final, success = info["final_obs"], info["final_info"].get("success", info["final_info"].get("lap_completed"))
                for i in np.flatnonzero(done):
                    infos[i] = {"terminal_observation": final[i], "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                                "is_success": bool(success[i])}
            return obs, reward, done, infos

        def close(self) -> None:
            self.vec.close()

        def get_attr(self, attr_name: str, indices=None) -> list[Any]:
            return [getattr(self.vec, attr_name)] * len(self._get_indices(indices))

        def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
            if len(self._get_indices(indices)) != self.num_envs:  # one object holds every env's attributes
                raise ValueError(f"set_attr({attr_name!r}): the envs of a torchnav batch share their attributes; "
                                 f"set it for all {self.num_envs} (indices=None), not for {list(self._get_indices(indices))}")
            setattr(self.vec, attr_name, value)

        def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
            raise NotImplementedError("the envs of a torchnav batch are one object; call methods on .vec")

        def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
            return [False] * len(self._get_indices(indices))

    return TorchnavSB3VecEnv()
