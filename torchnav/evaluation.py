"""Evaluate a policy on many seeded episodes at once and summarise with 95% confidence intervals.

One loop for both tasks (:func:`run_batched_episodes`): each env of the batch runs exactly one
episode, judged by the task's outcome function. Navigation (``run_episodes``) reads the outcome at
an episode's first ``done``, goals anywhere by default; line following (``run_line_episodes``)
judges lap completion from random starts (docs/line.md, "Evaluating lap completion")."""

from __future__ import annotations

import math
from functools import partial
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm.auto import tqdm

from .config import merge, to_dict
from .envs import LineEnv, NavEnv
from .tasks import LineConfig, NavConfig, NavTask
from .tasks.config import DEFAULT_MAP

Z95 = 1.959964
# Scenario seeds, offset by a run's seed: training envs use the run's seed itself, periodic
# evaluation PERIODIC_EVAL_SEED + seed, the final evaluation and evaluate.py FINAL_EVAL_SEED + seed
# (recipes/benchmark.py's test worlds start at 1,000,000). Disjoint for seeds below 10,000.
PERIODIC_EVAL_SEED = 10_000
FINAL_EVAL_SEED = 20_000


def wilson_interval(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """95% Wilson score interval for a binomial rate ``k / n``."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


def paired_successes(a: Sequence[bool], b: Sequence[bool]) -> dict[str, Any]:
    """Two methods' success flags on the same episodes, compared pair by pair (exact McNemar test).

    Returns ``episodes``, ``only_a`` and ``only_b`` (episodes one method succeeded on and the other
    did not; the episodes both or neither succeeded on say nothing about the difference),
    ``difference`` (success rate of ``a`` minus that of ``b``) and ``p``: the two-sided
    probability of a split at least this uneven if each discordant episode were a fair coin
    (``2 P(X <= min)``, ``X ~ Binomial(only_a + only_b, 1/2)``, at most 1; 1 when there are no
    discordant episodes). Sharper than comparing two Wilson intervals, which ignore the pairing."""
    if len(a) != len(b):
        raise ValueError(f"paired_successes: {len(a)} and {len(b)} episodes; a paired test needs the same episodes")
    only_a = sum(1 for x, y in zip(a, b) if x and not y)
    only_b = sum(1 for x, y in zip(a, b) if y and not x)
    n = only_a + only_b
    tail = sum(math.comb(n, k) for k in range(min(only_a, only_b) + 1)) / 2**n
    return {"episodes": len(a), "only_a": only_a, "only_b": only_b,
            "difference": (only_a - only_b) / len(a) if len(a) else float("nan"), "p": min(1.0, 2 * tail)}


def mean_interval(x: torch.Tensor, z: float = Z95) -> tuple[float, float, float]:
    """Mean and normal-approximation 95% interval of a 1-D sample (nan if empty)."""
    n = x.numel()
    if n == 0:
        return (float("nan"), float("nan"), float("nan"))
    m = x.double().mean().item()
    if n == 1:
        return (m, m, m)
    half = z * x.double().std().item() / math.sqrt(n)
    return (m, m - half, m + half)


def eval_config(cfg: NavConfig, map: str | None = None, anywhere: bool = True,
                worlds: Mapping[str, Any] | None = None, randomize_off: bool | Sequence[str] = ()) -> NavConfig:
    """``cfg`` for evaluation: optionally another map; with ``anywhere`` the curriculum is off.

    ``map`` also turns procedural worlds off, so a policy trained on generated worlds is
    evaluated on that map. ``worlds``: keys of the ``worlds`` section that replace those
    of ``cfg`` (``families`` are replaced, not merged), e.g. ``{"families": {"forest":
    1.0}, "difficulty": 0.5}``; the difficulty curriculum is off, so the difficulty is the
    one given (or ``cfg``'s ``worlds.difficulty``).

    With procedural worlds and ``anywhere``, the difficulty is fixed too: at
    ``worlds.max_difficulty`` when training used the difficulty curriculum (its target),
    else at ``worlds.difficulty``. Evaluation plays every episode at that difficulty with its own
    goal band: ``worlds.anywhere_goals`` and ``worlds.below_level`` (training's shares of easier
    episodes) are set to 0 unless ``worlds`` gives them.

    ``randomize_off`` switches domain randomisation off: True for every parameter, or the
    names of those to fix (``cfg.randomize``'s keys), which then take ``robot``/``lidar``'s values.

    The ``progress`` term is measured in straight lines (``reward.progress_distance: euclidean``):
    evaluation counts outcomes, the geodesic one needs generated worlds and costs a second
    wavefront per episode, and neither changes the episodes.
    """
    if map is not None and worlds is not None:
        raise ValueError("eval_config: give a map or procedural worlds, not both")
    d = to_dict(cfg)
    over: dict[str, Any] = {"reward": {"progress_distance": "euclidean"}}
    if map is not None:
        over["map"] = map
        d["worlds"] = {**d["worlds"], "families": {}, "movers": {}}  # the map's own moving_circles apply
    # training-only shares of easier episodes: evaluation plays each difficulty's own goal band
    plain = {"anywhere_goals": 0.0, "below_level": 0.0}
    if worlds is not None:
        d["worlds"] = {**d["worlds"], **plain, **worlds, "curriculum": False}
        if d["worlds"]["families"]:
            over["map"] = DEFAULT_MAP  # the policy's own map is not used on procedural worlds (NavConfig requires the default)
    if randomize_off:
        names = list(d["randomize"]) if randomize_off is True else list(randomize_off)
        unknown = [k for k in names if k not in d["randomize"]]
        if unknown:
            raise ValueError(f"eval_config: randomize_off names unknown parameters {unknown}; known: {list(d['randomize'])}")
        d["randomize"] = {**d["randomize"], **{k: None for k in names}}
    if anywhere:
        over["curriculum"] = {"mode": "off"}
        w = d["worlds"]
        if w["families"]:
            over["worlds"] = {"curriculum": False, "difficulty": w["max_difficulty"] if w["curriculum"] else w["difficulty"],
                              **(plain if worlds is None else {})}
    return type(cfg).from_dict(merge(d, over))  # a MultiNavConfig stays one


Outcome = Callable[[TensorDictBase], "tuple[torch.Tensor, dict[str, torch.Tensor]]"]


@torch.no_grad()
def run_batched_episodes(
    policy: Callable[[TensorDictBase], TensorDictBase],
    make_env: Callable[[int, int], Any],
    outcome: Outcome,
    n_episodes: int,
    seed: int = 0,
    max_batch: int = 4096,
    progress: str | None = None,
    reset: Callable[[Any, int], TensorDictBase] | None = None,
) -> dict[str, torch.Tensor]:
    """The evaluation loop of every task: ``n_episodes`` episodes, one per env, in batches of at
    most ``max_batch`` envs made by ``make_env(num_envs, seed)`` (seeds ``seed + 7919 k``).

    The deterministic ``policy`` drives each batch until every env's episode has ended;
    ``outcome(next_td)`` returns ``(ended (B,) bool, values {name: (B,)})`` and each env
    keeps the values of its first step where ``ended`` is True. A policy with a ``bind``
    method is bound to each env first. ``progress``: a label for a progress bar of
    finished episodes on stderr (``None``: silent). ``reset(env, first)`` starts a batch
    whose first env plays episode ``first`` (default: ``env.reset()``).
    """
    parts: dict[str, list[torch.Tensor]] = {}
    with tqdm(total=n_episodes, unit="ep", desc=progress, disable=progress is None, leave=False, dynamic_ncols=True) as bar:
        for first, n, env_seed in batches(n_episodes, max_batch, seed):
            env = make_env(n, env_seed)
            bind_policy(policy, env)
            td = env.reset() if reset is None else reset(env, first)
            for k, v in _until_ended(policy, env, td, outcome, bar).items():
                parts.setdefault(k, []).append(v.cpu())
    return {k: torch.cat(v) for k, v in parts.items()}


def batches(n_episodes: int, max_batch: int, seed: int) -> list[tuple[int, int, int]]:
    """The batches of :func:`run_batched_episodes`: ``(first episode, envs, env seed)`` each."""
    return [(first, min(max_batch, n_episodes - first), seed + 7919 * k) for k, first in enumerate(range(0, n_episodes, max_batch))]


def _until_ended(policy, env, td: TensorDictBase, outcome: Outcome, bar) -> dict[str, torch.Tensor]:
    finished = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
    out: dict[str, torch.Tensor] = {}
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(env.cfg.max_steps):
            td = env.step(policy(td))
            nxt = td["next"]
            ended, values = outcome(nxt)
            new = ended & ~finished
            if new.any():
                for k, v in values.items():
                    old = out.get(k, torch.zeros_like(v) if v.dtype == torch.bool else torch.full_like(v, float("nan")))
                    out[k] = torch.where(new, v, old)
                finished |= new
                bar.update(int(new.sum()))
                if finished.all():
                    break
            td = nxt.exclude("reward", "done", "terminated", "truncated")
    return out


def nav_outcome(nxt: TensorDictBase) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """A navigation episode ends at its first ``done``: success, collision or timeout, and its statistics."""
    ep = nxt["episode"]
    flat = lambda x: x.reshape(-1)  # noqa: E731
    return flat(nxt["done"]), {
        "success": flat(nxt["success"]), "collision": flat(nxt["collision"]), "timeout": flat(nxt["truncated"]),
        "length": flat(ep["length"]).float(), "return": flat(ep["return"]).float(),
        "path_length": flat(ep["path_length"]).float(), "straight_line": flat(ep["straight_line"]).float(),
        "speed_change": flat(ep["speed_change"]).float(), "turn_change": flat(ep["turn_change"]).float(),
    }


def outcome_letter(success: bool, collision: bool) -> str:
    """An episode's outcome as one letter: S success, C collision, T timeout."""
    return "S" if success else "C" if collision else "T"


def outcome_letters(res: Mapping[str, torch.Tensor]) -> str:
    """The outcome letter of each episode of :func:`run_episodes`' result, in order."""
    return "".join(map(outcome_letter, res["success"].tolist(), res["collision"].tolist()))


def run_episodes(
    policy: Callable[[TensorDictBase], TensorDictBase],
    cfg: NavConfig,
    n_episodes: int,
    seed: int = 0,
    device: torch.device | str = "cpu",
    max_batch: int = 4096,
    progress: str | None = None,
    given: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> dict[str, torch.Tensor]:
    """Run ``n_episodes`` navigation episodes (one per env, in batches of at most ``max_batch`` envs).

    A policy with a ``bind`` method is bound to each env created here (``policy.bind(env)``).
    ``given`` ``(starts (E, 3), goals (E, 2))`` (:func:`load_episodes`) plays those episodes instead
    of sampled ones (``NavEnv.reset_to``; ``n_episodes`` must be ``E``; a map only).
    Returns per-episode tensors: ``success``, ``collision``, ``timeout`` (bool),
    ``length`` (steps), ``return``, ``path_length`` and ``straight_line`` (m), ``speed_change``
    (m/s) and ``turn_change`` (rad/s), the sums of the driven velocity's absolute changes per step.
    """
    return run_batched_episodes(policy, lambda n, s: NavEnv(cfg, num_envs=n, device=device, seed=s), nav_outcome,
                                n_episodes, seed, max_batch, progress, _given_reset(cfg, n_episodes, given, device))


def _given_reset(cfg: NavConfig, n_episodes: int, given: tuple[torch.Tensor, torch.Tensor] | None, device) -> Callable | None:
    """The ``reset(env, first)`` of :func:`run_batched_episodes` that plays the ``given`` episodes (None: sampled ones)."""
    if given is None:
        return None
    starts, goals = given
    if len(starts) != n_episodes or len(goals) != n_episodes:
        raise ValueError(f"run_episodes: {n_episodes} episodes, but {len(starts)} starts and {len(goals)} goals given")
    NavTask(cfg, 1, device=device).check_places(starts, goals)  # every episode, before any runs
    return lambda env, first: env.reset_to(starts[first : first + env.num_envs], goals[first : first + env.num_envs])


def shortest_episode_paths(cfg: NavConfig, n_episodes: int, seed: int = 0, device: torch.device | str = "cpu", max_batch: int = 4096,
                           given: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
    """The shortest collision-free path ``(E,)`` m from start to goal of each episode :func:`run_episodes`
    plays with these arguments (the same envs and seeds), among the episode's obstacles at its start for
    the robot's disc (``torchnav.controllers.shortest_paths``: A* at 0.05 m, shortcut; moving obstacles
    are not counted); ``inf`` where there is none. The reference of :func:`time_efficiency`."""
    from .controllers import shortest_paths

    reset = _given_reset(cfg, n_episodes, given, device)
    out = []
    for first, n, env_seed in batches(n_episodes, max_batch, seed):
        env = NavEnv(cfg, num_envs=n, device=device, seed=env_seed)
        env.reset() if reset is None else reset(env, first)
        s = env.state
        out.append(torch.as_tensor(shortest_paths(env.task.full_world(s.world), s.start.cpu(), s.goal.cpu(), env.task.params.robot_radius)))
    return torch.cat(out)


def time_efficiency(res: Mapping[str, torch.Tensor], shortest: torch.Tensor, cfg: NavConfig) -> dict[str, Any]:
    """Time to goal against the optimal time: the shortest path (:func:`shortest_episode_paths`) less
    the goal tolerance (an episode ends that far from the goal), driven at the robot's top speed
    (``cfg``'s ``robot.v_max``, ``dt`` a step) with no time to turn. ``time_ratio``: the mean over
    successful episodes' steps over their optimal steps, summed (so that an episode counts by its
    length: on a short one the turn at the start outweighs the path), with a delta-method 95%
    interval; ``time_score``: the mean over all episodes of ``success * min(1, optimal / actual
    time)`` (1 for a method that reaches every goal as fast as that allows), with a normal 95%
    interval; ``no_reference``: episodes without a path on the grid, left out of both."""
    known = shortest.isfinite()
    optimal = (shortest - cfg.goal_tolerance).clamp(min=0.0) / (cfg.robot.v_max * cfg.sim_params().dt)  # steps
    steps = res["length"].double()
    ok = res["success"] & known
    score = torch.where(res["success"], (optimal / steps.clamp(min=1.0)).clamp(max=1.0), 0.0)[known]
    m, lo, hi = mean_interval(score)
    return {"no_reference": int((~known).sum()), "time_ratio": ratio_interval(steps[ok], optimal[ok]), "time_score": {"mean": m, "ci95": [lo, hi]}}


def ratio_interval(a: torch.Tensor, b: torch.Tensor, z: float = Z95) -> dict[str, Any]:
    """``sum(a) / sum(b)`` of paired samples with its delta-method 95% interval (nan when empty)."""
    n = a.numel()
    if n == 0 or float(b.sum()) <= 0:
        return {"mean": float("nan"), "ci95": [float("nan"), float("nan")]}
    a, b = a.double(), b.double()
    r = float(a.sum() / b.sum())
    half = z * float((a - r * b).std()) / (math.sqrt(n) * float(b.mean())) if n > 1 else 0.0
    return {"mean": r, "ci95": [r - half, r + half]}


EPISODE_KEYS = ("start", "goal")


def load_episodes(path: str | Path) -> tuple[str | None, torch.Tensor, torch.Tensor]:
    """A YAML file of navigation episodes -> ``(map or None, starts (E, 3), goals (E, 2))``.

    The file holds ``episodes:``, a list of ``{start: [x, y, heading], goal: [x, y]}`` (m, rad, the
    map's frame), and optionally ``map:``, the map they were written for. Anything else, or an entry
    that is not two lists of 3 and 2 finite numbers, raises ``ValueError`` naming the file and the entry.
    Whether the places are free is checked against the map when the episodes start (``NavEnv.reset_to``).
    """
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: no such episodes file") from None
    except yaml.YAMLError as e:
        raise ValueError(f"{path}: not valid YAML ({e})") from None
    if not isinstance(data, dict) or not isinstance(data.get("episodes"), list) or not data["episodes"]:
        raise ValueError(f"{path}: expected a mapping with a non-empty list 'episodes' of {{start: [x, y, heading], goal: [x, y]}}")
    unknown = sorted(set(data) - {"map", "episodes"})
    if unknown:
        raise ValueError(f"{path}: unknown keys {unknown}; an episodes file holds 'episodes' and optionally 'map'")
    if "map" in data and not isinstance(data["map"], str):
        raise ValueError(f"{path}: 'map' must be a map name or path, got {data['map']!r}")
    rows: dict[str, list[list[float]]] = {k: [] for k in EPISODE_KEYS}
    for i, ep in enumerate(data["episodes"]):
        if not isinstance(ep, dict) or set(ep) != set(EPISODE_KEYS):
            raise ValueError(f"{path}: episodes[{i}] must be {{start: [x, y, heading], goal: [x, y]}}, got {ep!r}")
        for key, size in zip(EPISODE_KEYS, (3, 2)):
            v = ep[key]
            ok = isinstance(v, list) and len(v) == size and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
            if not ok or not all(math.isfinite(x) for x in v):
                raise ValueError(f"{path}: episodes[{i}].{key} must be {size} finite numbers, got {v!r}")
            rows[key].append([float(x) for x in v])
    return data.get("map"), torch.tensor(rows["start"]), torch.tensor(rows["goal"])


def bind_policy(policy: Any, env: Any) -> None:
    """Call ``policy.bind(env)`` if the policy has one (classical planners read the env's worlds)."""
    bind = getattr(policy, "bind", None)
    if callable(bind):
        bind(env)


def summarize_outcomes(res: dict[str, torch.Tensor], outcomes: Sequence[str], means: Mapping[str, torch.Tensor]) -> dict[str, Any]:
    """The summary of any task's evaluation: the rate of each bool outcome of ``res`` with its
    Wilson interval and count, and the mean of each ``means`` sample with a normal interval."""
    n = res[outcomes[0]].numel()
    out: dict[str, Any] = {"episodes": n}
    for k in outcomes:
        c = int(res[k].sum())
        lo, hi = wilson_interval(c, n)
        out[k] = {"rate": c / n if n else float("nan"), "ci95": [lo, hi], "count": c}
    for k, x in means.items():
        m, lo, hi = mean_interval(x)
        out[k] = {"mean": m, "ci95": [lo, hi]}
    return out


def format_table(s: dict[str, Any], title: str, outcomes: Sequence[str], means: Sequence[tuple[str, str]], width: int = 10) -> str:
    """A small fixed-width table of :func:`summarize_outcomes` output: one row per outcome rate and
    per ``(mean, unit)``."""
    rows = [f"{title}  ({s['episodes']} episodes)" if title else f"{s['episodes']} episodes"]
    for k in outcomes:
        r = s[k]
        rows.append(f"  {k:<14}{100 * r['rate']:6.1f} %   95% CI [{100 * r['ci95'][0]:5.1f}, {100 * r['ci95'][1]:5.1f}]")
    for k, unit in means:
        r = s[k]
        rows.append(f"  {k:<14}{r['mean']:8.2f} {unit:<{width}} 95% CI [{r['ci95'][0]:.2f}, {r['ci95'][1]:.2f}]")
    return "\n".join(rows)


# The robustness perturbations of recipes/benchmark.py --perturb: config overrides of a navigation task, each one
# departure of the robot from the simulator's ideal (docs/results.md, "Benchmark suite").
PERTURBATIONS: dict[str, dict[str, Any]] = {
    "lidar_noise": {"lidar": {"noise_std": 0.03}},  # 3 cm Gaussian range noise
    "odom_noise": {"robot": {"odom_v_noise": 0.05, "odom_omega_noise": 0.05}},  # per-step std, m/s and rad/s
    "dropout": {"randomize": {"dropout": [0.05, 0.05]}},  # 5% of the rays read max_range
    "delay": {"randomize": {"delay": [1, 1]}},  # a one-step actuator delay
    "acceleration": {"robot": {"lin_acc_max": 1.0, "ang_acc_max": 3.0}},  # m/s^2 and rad/s^2
}


def perturbed(cfg: NavConfig, name: str) -> NavConfig:
    """``cfg`` with the robustness perturbation ``name`` of :data:`PERTURBATIONS` applied."""
    if name not in PERTURBATIONS:
        raise ValueError(f"unknown perturbation {name!r}; known: {', '.join(PERTURBATIONS)}")
    return type(cfg).from_dict(merge(to_dict(cfg), PERTURBATIONS[name]))


NAV_OUTCOMES = ("success", "collision", "timeout")


def summarize(res: dict[str, torch.Tensor]) -> dict[str, Any]:
    """Rates with Wilson intervals; mean steps to goal (successful episodes), path-length ratio
    (path / straight line, successful episodes), return, and smoothness: ``speed_change`` and
    ``turn_change``, the mean absolute change of the driven speed (m/s) and turn rate (rad/s) per
    step (all episodes), with normal intervals."""
    s = res["success"]
    ratio = res["path_length"][s] / res["straight_line"][s].clamp(min=1e-6)
    steps = res["length"].clamp(min=1.0)
    return summarize_outcomes(res, NAV_OUTCOMES, {"steps_to_goal": res["length"][s], "path_ratio": ratio, "return": res["return"],
                                                  "speed_change": res["speed_change"] / steps, "turn_change": res["turn_change"] / steps})


def format_summary(s: dict[str, Any], title: str = "") -> str:
    """A small fixed-width table of ``summarize`` output."""
    return format_table(s, title, NAV_OUTCOMES, (("steps_to_goal", "steps"), ("path_ratio", "x straight"), ("return", ""),
                                                 ("speed_change", "m/s/step"), ("turn_change", "rad/s/step")))


# -- line following: lap completion from random starts (docs/line.md) --------------------------

LINE_OUTCOMES = ("lap_complete", "left_line", "stalled", "collision", "timeout")


def run_line_episodes(
    policy: Callable[[TensorDictBase], TensorDictBase],
    cfg: LineConfig,
    n_episodes: int,
    seed: int = 0,
    laps: int = 1,
    device: torch.device | str = "cpu",
    max_batch: int = 4096,
    progress: str | None = None,
) -> dict[str, torch.Tensor]:
    """Run ``n_episodes`` episodes (one per env, in batches of at most ``max_batch``) with the
    deterministic ``policy`` until each completes ``laps`` laps or ends.

    A policy with a ``bind(env)`` method (e.g. ``LineFollower``) is bound to each env.
    Returns per-episode tensors: the bool outcomes :data:`LINE_OUTCOMES` (exactly one is True),
    ``lap_time`` (s to the first lap, nan without one), ``length`` (steps), ``lap_fraction``,
    ``time_off_line`` (s) and ``return`` at the outcome.
    """
    if laps < 1:
        raise ValueError(f"laps must be >= 1, got {laps}")
    return run_batched_episodes(policy, lambda n, s: LineEnv(cfg, num_envs=n, device=device, seed=s), partial(lap_outcome, laps=laps),
                                n_episodes, seed, max_batch, progress)


def lap_outcome(nxt: TensorDictBase, laps: int = 1) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """A line-following episode is judged when it completes ``laps`` laps or ends without them."""
    ep = nxt["episode"]
    flat = lambda x: x.reshape(-1)  # noqa: E731
    lap = flat(ep["laps"]) >= laps
    left, stalled = flat(nxt["left_line"]), flat(nxt["stalled"])
    lap_time = flat(ep["lap_time"])
    values = {
        "lap_complete": lap,
        "left_line": ~lap & left,
        "stalled": ~lap & ~left & stalled,
        "collision": ~lap & ~left & ~stalled & flat(nxt["collision"]),
        "timeout": ~lap & flat(nxt["truncated"]),
        "lap_time": torch.where(flat(ep["laps"]) >= 1, lap_time, torch.full_like(lap_time, float("nan"))),
        "length": flat(ep["length"]), "lap_fraction": flat(ep["lap_fraction"]),
        "time_off_line": flat(ep["time_off_line"]), "return": flat(ep["return"]),
    }
    return lap | flat(nxt["done"]), values


def summarize_laps(res: dict[str, torch.Tensor], dt: float = 0.05) -> dict[str, Any]:
    """Outcome rates with Wilson intervals; lap time (s, completed laps) and lap fraction (all
    episodes) with normal intervals; the fraction of driving time with no sensor on the line
    (``off_line``, ``dt`` s per step)."""
    out = summarize_outcomes(res, LINE_OUTCOMES, {"lap_time": res["lap_time"][res["lap_complete"]], "lap_fraction": res["lap_fraction"],
                                                  "return": res["return"]})
    total = float((res["length"] * dt).sum())
    out["off_line"] = {"fraction": float(res["time_off_line"].sum()) / total if total > 0 else float("nan")}
    return out


def format_lap_summary(s: dict[str, Any], title: str = "") -> str:
    """A small fixed-width table of :func:`summarize_laps` output."""
    table = format_table(s, title, LINE_OUTCOMES, (("lap_time", "s"), ("lap_fraction", "laps"), ("return", "")), width=6)
    return table + f"\n  {'off_line':<14}{100 * s['off_line']['fraction']:6.1f} %   of driving time"


def record_episodes(
    policy: Callable[[TensorDictBase], TensorDictBase],
    cfg: NavConfig,
    path,
    n_episodes: int,
    seed: int = 0,
    device: torch.device | str = "cpu",
    metadata: dict[str, Any] | None = None,
) -> Any:
    """Write ``n_episodes`` navigation episodes of the deterministic ``policy`` (one per env) to an MCAP file."""
    return record_to_file(policy, NavEnv(cfg, num_envs=n_episodes, device=device, seed=seed), path, seed, metadata)


def record_to_file(policy: Callable[[TensorDictBase], TensorDictBase], env: Any, path, seed: int = 0, metadata: dict[str, Any] | None = None,
                   reset: Callable[[Any], TensorDictBase] | None = None) -> Any:
    """One deterministic episode per env of ``env`` (any task) written to the MCAP file ``path``
    (``reset`` as for :func:`record_with`).

    Returns the recorder (its ``error`` is set, and a warning was issued, if the file
    could not be written; training code can carry on).
    """
    from .record import EpisodeRecorder

    meta = {"seed": seed, **(metadata or {})}
    return record_with(policy, env, lambda e: EpisodeRecorder(path, e, envs=range(e.num_envs), metadata=meta, episodes=1), reset)


@torch.no_grad()
def record_with(policy: Callable[[TensorDictBase], TensorDictBase], env: Any, make_recorder: Callable[[Any], Any],
                reset: Callable[[Any], TensorDictBase] | None = None) -> Any:
    """One deterministic episode per env of ``env`` (any task), written by ``make_recorder(env)``:
    an ``EpisodeRecorder`` to an MCAP file or a ``LiveView``. ``reset(env)`` starts the episodes
    (default ``env.reset()``; e.g. ``NavEnv.reset_to`` for given starts and goals). Returns the recorder."""
    from .record import record_rollout

    bind_policy(policy, env)
    with make_recorder(env) as rec, set_exploration_type(ExplorationType.DETERMINISTIC):
        td = None if reset is None else reset(env)
        record_rollout(env, policy, max_steps=env.cfg.max_steps, recorder=rec, tensordict=td, stack=False)
    return rec
