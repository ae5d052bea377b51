"""The task protocol: one object per task that builds its envs, evaluates and records a policy
on it, and says what a training loop shows of it. The recipes, ``recipes/evaluate.py`` and the
training loop use it for both tasks, so none of them branches on the task.

    from torchnav.protocol import task_protocol
    task = task_protocol(LineConfig(track="oval"), laps=2)     # or task_protocol(NavConfig(...))
    s = task.evaluate(policy, episodes=1000, seed=FINAL_EVAL_SEED, device="cpu")
    print(task.format(s))                                      # s["score"]: the rate a target is set on
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from .config import to_dict
from .envs import LineEnv, MultiNavEnv, NavEnv
from .envs.base import BatchedEnv
from .evaluation import (bind_policy, eval_config, format_lap_summary, format_summary, outcome_letters, record_to_file, record_with, run_episodes, run_line_episodes,
                         summarize, summarize_laps)
from .tasks import LineConfig, MultiNavConfig, NavConfig


class TaskProtocol:
    """What a training loop, evaluation and recording need of a task; see the module docstring."""

    name = ""  # "nav" or "line": the ``task`` of a saved policy (torchnav.policy)
    place = ""  # the config key naming where the task runs: "map" or "track"
    config_class: type = object
    env_class: type = BatchedEnv
    outcome_keys: tuple[str, ...] = ()  # flags of finished training episodes behind the train/<flag>_rate figures
    outcomes: tuple[str, ...] = ()  # evaluation outcomes shown on one line; the first one's rate is the score

    def __init__(self, config: Any, eval_config: Any = None, **env_options: Any) -> None:
        self.config, self.env_options = config, env_options
        self.eval_config = config if eval_config is None else eval_config  # the task as evaluation plays it

    def make_env(self, num_envs: int, device, seed: int) -> BatchedEnv:
        """The training env."""
        return self.env_class(self.config, num_envs=num_envs, device=device, seed=seed, **self.env_options)

    def eval_env(self, num_envs: int, device, seed: int) -> BatchedEnv:
        """An env as evaluation plays it (one episode per env)."""
        return self.env_class(self.eval_config, num_envs=num_envs, device=device, seed=seed)

    def run(self, policy, episodes: int, seed: int, device, progress: str | None = None) -> dict[str, Any]:
        """The summary of ``episodes`` deterministic evaluation episodes, one per env."""
        raise NotImplementedError

    def evaluate(self, policy, episodes: int, seed: int, device, progress: str | None = None, **options: Any) -> dict[str, Any]:
        """:meth:`run`'s summary plus ``"score"``, the rate of the first outcome (compared with a target);
        ``options`` go to :meth:`run` (navigation: ``given`` starts and goals)."""
        s = self.run(policy, episodes, seed, device, progress, **options)
        s["score"] = s[self.outcomes[0]]["rate"]
        return s

    def describe(self, s: dict[str, Any]) -> str:
        """One line of an evaluation summary's rates."""
        return " ".join(f"{k} {100 * s[k]['rate']:.1f}%" for k in self.outcomes)

    def format(self, s: dict[str, Any], title: str | None = None) -> str:
        """The summary as a text table."""
        raise NotImplementedError

    def record_with(self, policy, episodes: int, seed: int, device, make_recorder: Callable[[Any], Any],
                    reset: Callable[[Any], Any] | None = None) -> Any:
        """``torchnav.evaluation.record_with`` on ``eval_env(episodes, ...)`` (an MCAP file or a ``LiveView``;
        ``reset(env)`` starts the episodes, default ``env.reset()``)."""
        return record_with(policy, self.eval_env(episodes, device, seed), make_recorder, reset)

    def record(self, policy, path: Path, episodes: int, seed: int, device, metadata: dict | None = None,
               reset: Callable[[Any], Any] | None = None) -> Any:
        """``episodes`` deterministic evaluation episodes written to the MCAP file ``path``; returns the recorder."""
        return record_to_file(policy, self.eval_env(episodes, device, seed), path, seed, metadata, reset)

    def status(self, env) -> str:
        """A short progress-bar field of a training env (the curriculum), or ``""``."""
        return ""

    def scalars(self, env) -> dict[str, float]:
        """Logged figures of a training env beyond the outcome rates (the curriculum)."""
        return {}

    def task_config(self) -> dict[str, Any]:
        return to_dict(self.config)

    def where(self) -> str:
        """Where the task runs, for titles and ``summary.json``'s ``map``/``track``."""
        return str(getattr(self.config, self.place))


class NavProtocol(TaskProtocol):
    """Lidar navigation: evaluation with goals anywhere (``anywhere``; the curriculum off) and
    procedural worlds at a fixed difficulty; the curriculum in the progress output."""

    name, place, config_class, env_class = "nav", "map", NavConfig, NavEnv
    outcome_keys = ("success", "collision")
    outcomes = ("success", "collision", "timeout")

    def __init__(self, config: NavConfig, anywhere: bool = True, compile_step: bool = False, map: str | None = None) -> None:
        """``map``: evaluate on that map instead of where ``config`` trains (for a policy trained on
        procedural worlds too: ``eval_config`` turns them off)."""
        evaluation = eval_config(config, map=map, anywhere=anywhere)
        if not evaluation.worlds.families:
            from .maps import load_map

            load_map(evaluation.map)  # an unknown or malformed map is named now, before any run starts
        super().__init__(config, evaluation, compile_step=bool(compile_step))
        self.anywhere = anywhere

    def run(self, policy, episodes: int, seed: int, device, progress: str | None = None,
            given: tuple[Any, Any] | None = None) -> dict[str, Any]:
        """With ``given`` ``(starts (E, 3), goals (E, 2))`` the summary has ``"outcomes"`` too, one letter
        per episode in order: ``S`` success, ``C`` collision, ``T`` timeout."""
        res = run_episodes(policy, self.eval_config, episodes, seed=seed, device=device, progress=progress, given=given)
        s = summarize(res)
        if given is not None:
            s["outcomes"] = outcome_letters(res)
        return s

    def where(self) -> str:
        w = self.eval_config.worlds
        return f"worlds {'+'.join(w.families)} at difficulty {w.difficulty:g}" if w.families else self.eval_config.map

    def format(self, s: dict[str, Any], title: str | None = None) -> str:
        goals = "goals anywhere" if self.anywhere else "the training curriculum's goals"
        return format_summary(s, title=title or f"final evaluation on {self.where()}, {goals}, deterministic policy")

    def status(self, env) -> str:
        if self.config.worlds.families:
            return "difficulty " + "/".join(f"{d:.2f}" for d in env.curriculum.difficulty.tolist())
        return f"radius {env.curriculum.radius.item():.2f}m"

    def scalars(self, env) -> dict[str, float]:
        out = {"curriculum/radius": env.curriculum.radius.item()}
        for name, d, rate in zip(self.config.worlds.families, env.curriculum.difficulty.tolist(), env.curriculum.family_success.tolist()):
            out[f"curriculum/difficulty/{name}"] = d
            out[f"curriculum/success/{name}"] = rate
        return out


class LineProtocol(TaskProtocol):
    """Line following: evaluation on completing ``laps`` laps from random starts."""

    name, place, config_class, env_class = "line", "track", LineConfig, LineEnv
    outcome_keys = ("left_line", "stalled")
    outcomes = ("lap_complete", "left_line", "stalled", "timeout")

    def __init__(self, config: LineConfig, laps: int = 1) -> None:
        super().__init__(config)
        from .tracks import load_track

        load_track(config.track)  # an unknown or malformed track is named now, before any run starts
        self.laps = int(laps)

    def run(self, policy, episodes: int, seed: int, device, progress: str | None = None) -> dict[str, Any]:
        res = run_line_episodes(policy, self.config, episodes, seed=seed, laps=self.laps, device=device, progress=progress)
        return summarize_laps(res, dt=self.config.robot.dt)

    def format(self, s: dict[str, Any], title: str | None = None) -> str:
        return format_lap_summary(s, title=title or f"final evaluation on {self.where()}: {self.laps} lap(s) from random starts, deterministic policy")


class MultiNavProtocol(TaskProtocol):
    """Several robots per env (``MultiNavEnv``): evaluation plays ``episodes`` envs of the training
    config (its scenario and robot count) to their first episode's end with one
    deterministic policy for every robot. The summary's rates: ``team_success`` (envs whose every
    present robot reached its goal), ``at_goal`` (present robots at their goal), ``robot_collision``
    (present robots that hit another robot), ``collision`` (present robots that hit anything),
    ``timeout`` (envs truncated at ``max_steps``); ``robots``: the present robots counted. Goals are
    drawn anywhere (the curriculum off) unless ``anywhere=False``."""

    name, place, config_class, env_class = "multi_nav", "map", MultiNavConfig, MultiNavEnv
    outcome_keys = ("team_success",)  # top-level flags of a finished env's episode
    outcomes = ("team_success", "at_goal", "robot_collision", "collision", "timeout")

    def __init__(self, config: MultiNavConfig, anywhere: bool = True, map: str | None = None) -> None:
        """As ``NavProtocol``: ``anywhere`` turns the goal curriculum off for evaluation (the
        ``random`` scenario's goals anywhere on the map; the other scenarios place theirs by their
        geometry), ``map`` evaluates on another map."""
        evaluation = eval_config(config, map=map, anywhere=anywhere)
        if not evaluation.worlds.families:
            from .maps import load_map

            load_map(evaluation.map)  # an unknown or malformed map is named now, before any run starts
        super().__init__(config, evaluation)

    def run(self, policy, episodes: int, seed: int, device, progress: str | None = None) -> dict[str, Any]:
        """``policy``: a TensorDict module reading ``"observation"`` ``(..., D)`` and writing ``"action"``
        (``torchnav.policy.to_policy``), applied to the agent group ``td["agents"]`` (batch ``(E, N)``: every
        robot's observation, and the pose, goal, ranges, ... that a classical controller reads)."""
        import torch

        env = self.eval_env(int(episodes), device, seed)
        act = _AgentGroupPolicy(policy)
        bind_policy(act, env)
        td = env.reset()
        E, N = env.num_envs, env.n_robots
        finished = torch.zeros(E, dtype=torch.bool, device=env.device)
        at_goal = torch.zeros(E, N, dtype=torch.bool, device=env.device)
        hit_robot, hit = torch.zeros_like(at_goal), torch.zeros_like(at_goal)
        team, timeout = torch.zeros_like(finished), torch.zeros_like(finished)
        present = td["agents", "mask"].reshape(E, N).clone()
        with torch.no_grad():
            for _ in range(int(self.config.max_steps) + 1):
                nxt = env.step(act(td))["next"]
                live = ~finished
                a = nxt["agents"]
                at_goal |= a["success"].reshape(E, N) & live[:, None]
                hit_robot |= a["robot_collision"].reshape(E, N) & live[:, None]
                hit |= a["collision"].reshape(E, N) & live[:, None]
                done = nxt["done"].reshape(E) & live
                team |= nxt["team_success"].reshape(E) & done
                timeout |= nxt["truncated"].reshape(E) & done
                finished |= done
                if bool(finished.all()):
                    break
                td = nxt  # an env that finished keeps stepping unread: no auto-reset here
        robots = int(present.sum())

        def rate(flags: torch.Tensor, over: int) -> dict[str, float]:
            return {"rate": float(flags.sum()) / max(over, 1), "count": int(flags.sum())}

        return {"episodes": E, "robots": robots, "team_success": rate(team, E), "at_goal": rate(at_goal & present, robots),
                "robot_collision": rate(hit_robot & present, robots), "collision": rate(hit & present, robots), "timeout": rate(timeout, E)}

    def format(self, s: dict[str, Any], title: str | None = None) -> str:
        title = title or (f"final evaluation on {self.where()}, {self.config.robots.n} robots ({self.config.robots.scenario}), "
                          f"shared deterministic policy")
        lines = [title, f"  {s['episodes']} episodes, {s['robots']} robots"]
        lines += [f"  {k:<16} {100 * s[k]['rate']:6.1f}%  ({s[k]['count']})" for k in self.outcomes]
        return "\n".join(lines)

    def record(self, policy, path: Path, episodes: int, seed: int, device, metadata: dict | None = None,
               reset: Callable[[Any], Any] | None = None) -> Any:
        """As :meth:`TaskProtocol.record`, every robot of each env in the file (docs/foxglove.md, "Several
        robots"); ``policy`` as for :meth:`run`."""
        return super().record(_AgentGroupPolicy(policy), path, episodes, seed, device, metadata, reset)

    def record_with(self, policy, episodes: int, seed: int, device, make_recorder: Callable[[Any], Any],
                    reset: Callable[[Any], Any] | None = None) -> Any:
        """As :meth:`TaskProtocol.record_with` (an MCAP file or a ``LiveView``); ``policy`` as for :meth:`run`."""
        return super().record_with(_AgentGroupPolicy(policy), episodes, seed, device, make_recorder, reset)

    def where(self) -> str:
        return NavProtocol.where(self) if self.config.worlds.families else super().where()

    def status(self, env) -> str:
        if self.config.worlds.families:  # the world difficulties, as for one robot
            return NavProtocol.status(self, env)
        return f"radius {env.curriculum.radius.item():.2f}m" if self.config.robots.scenario == "random" else ""

    def scalars(self, env) -> dict[str, float]:
        if self.config.worlds.families:
            return NavProtocol.scalars(self, env)
        return {"curriculum/radius": env.curriculum.radius.item()} if self.config.robots.scenario == "random" else {}


class _AgentGroupPolicy:
    """``policy`` (``"observation"`` -> ``"action"``, or a multi-robot controller) as a policy of the env's
    agent group: ``td["agents"]`` (batch ``(E, N)``: every robot's observation, pose, goal, ranges, ...)
    in, ``("agents", "action")`` out; ``bind(env)`` binds a controller to the env."""

    def __init__(self, policy) -> None:
        self.policy = policy

    def bind(self, env) -> None:
        bind_policy(self.policy, env)

    def __call__(self, td):
        td["agents", "action"] = self.policy(td["agents"].exclude("action"))["action"]
        return td


PROTOCOLS: dict[str, type[TaskProtocol]] = {p.name: p for p in (NavProtocol, LineProtocol, MultiNavProtocol)}


def task_protocol(config: NavConfig | LineConfig | MultiNavConfig, **options: Any) -> TaskProtocol:
    """The protocol of a task config: ``NavProtocol(config, anywhere=, compile_step=, map=)``,
    ``LineProtocol(config, laps=)`` or ``MultiNavProtocol(config)``."""
    if isinstance(config, MultiNavConfig):  # a NavConfig too: checked first
        return MultiNavProtocol(config, **options)
    for p in PROTOCOLS.values():
        if isinstance(config, p.config_class):
            return p(config, **options)
    raise TypeError(f"task_protocol: expected a NavConfig or a LineConfig, got {type(config).__name__}")
