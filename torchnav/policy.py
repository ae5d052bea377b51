"""Saved policies: one small actor format shared by every recipe, evaluation, comparison and export.

Every recipe saves its deterministic policy as ``actor.pt`` (the format, ``FORMAT``, is in
docs/training.md, "The policy file"): ``normalise -> Linear/activation stack -> head``, with a
``tanh`` head for continuous actions or the ``argmax`` of Q-values over ``action_table``.
Stochastic policies save their deterministic mean action (PPO's and SAC's ``tanh(loc)``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import torch
from tensordict.nn import TensorDictModule
from torch import nn

from .checkpoint import HASH_KEY, load_checked, save_checked

FORMAT = "torchnav-actor-v2"
ACTIVATIONS = {"relu": nn.ReLU, "tanh": nn.Tanh}
OUTPUTS = ("tanh", "argmax", "linear")  # "linear": raw outputs (value networks, pre-tanh means); not a saved policy


class Actor(nn.Module):
    """Deterministic policy network ``obs (..., obs_size) -> out (..., out_size)``.

    ``(obs - obs_loc) / obs_scale`` feeds an MLP with ``hidden`` layers; with
    ``output="tanh"`` the result is squashed into ``[-1, 1]`` (continuous actions),
    with ``output="argmax"`` it is left as Q-values (``to_policy`` picks the best).
    """

    def __init__(self, obs_size: int, out_size: int, hidden: Sequence[int] = (256, 256), activation: str = "relu", output: str = "tanh"):
        super().__init__()
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}")
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
        self.obs_size, self.out_size, self.hidden = int(obs_size), int(out_size), [int(h) for h in hidden]
        self.activation, self.output = activation, output
        self.register_buffer("obs_loc", torch.zeros(obs_size))
        self.register_buffer("obs_scale", torch.ones(obs_size))
        layers: list[nn.Module] = []
        width = obs_size
        for h in self.hidden:
            layers += [nn.Linear(width, h), ACTIVATIONS[activation]()]
            width = h
        layers.append(nn.Linear(width, out_size))
        self.net = nn.Sequential(*layers)

    def set_normalization(self, loc: torch.Tensor, scale: torch.Tensor) -> None:
        """Observation statistics ``(obs_size,)``; ``scale`` must be positive."""
        if loc.shape != (self.obs_size,) or scale.shape != (self.obs_size,):
            raise ValueError(f"normalisation needs shapes ({self.obs_size},), got {tuple(loc.shape)} and {tuple(scale.shape)}")
        if not bool((scale > 0).all()):
            raise ValueError("normalisation scale must be positive")
        self.obs_loc.copy_(loc)
        self.obs_scale.copy_(scale)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        y = self.net((obs - self.obs_loc) / self.obs_scale)
        return torch.tanh(y) if self.output == "tanh" else y

    def squashed(self, n: int | None = None) -> "Actor":
        """A ``tanh`` copy of this network keeping the first ``n`` outputs: the deterministic
        action ``tanh(loc)`` of a Gaussian policy whose (linear) head emits ``loc`` first."""
        n = self.out_size if n is None else n
        with torch.random.fork_rng(devices=[]):  # the copy's random init is overwritten: leave the global RNG as it was
            out = Actor(self.obs_size, n, self.hidden, self.activation, output="tanh").to(self.obs_loc.device)
        state = {k: v.detach().clone() for k, v in self.state_dict().items()}
        last = f"net.{len(self.net) - 1}"
        state[f"{last}.weight"], state[f"{last}.bias"] = state[f"{last}.weight"][:n], state[f"{last}.bias"][:n]
        out.load_state_dict(state)
        return out

    def linear_layers(self) -> list[nn.Linear]:
        return [m for m in self.net if isinstance(m, nn.Linear)]

    def spec(self) -> dict[str, Any]:
        return {"obs_size": self.obs_size, "out_size": self.out_size, "hidden": list(self.hidden),
                "activation": self.activation, "output": self.output}


class _ArgmaxOneHot(nn.Module):
    """Q-values ``(..., A)`` -> one-hot action ``(..., A)`` of the best action."""

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.one_hot(q.argmax(-1), q.shape[-1]).to(torch.long)


def to_policy(actor: Actor, in_key: str = "observation") -> TensorDictModule:
    """A TensorDict policy writing ``"action"``: the tanh output, or a one-hot argmax for Q-networks."""
    if actor.output == "tanh":
        return TensorDictModule(actor, in_keys=[in_key], out_keys=["action"])
    if actor.output == "linear":
        raise ValueError("a 'linear' network is not a policy: use Actor.squashed() for a Gaussian policy's mean action")
    return TensorDictModule(nn.Sequential(actor, _ArgmaxOneHot()), in_keys=[in_key], out_keys=["action"])


@dataclass
class SavedPolicy:
    """A loaded ``actor.pt``: the network, its TensorDict policy and what it was trained on."""

    actor: Actor
    policy: TensorDictModule
    task: str
    task_config: dict[str, Any]
    algorithm: str
    action_table: torch.Tensor | None = None
    path: Path | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def config(self):
        """The task config object (``NavConfig`` or ``LineConfig``) it was trained with."""
        from .tasks import LineConfig, NavConfig

        configs = {"nav": NavConfig, "line": LineConfig}
        if self.task not in configs:
            raise ValueError(f"{self.path}: unknown task {self.task!r}")
        return configs[self.task].from_dict(self.task_config, where=f"{self.path}:task_config")


def policy_payload(actor: Actor, *, task: str, task_config: dict[str, Any], algorithm: str,
                   action_table: torch.Tensor | None = None, **extra: Any) -> dict[str, Any]:
    """The ``actor.pt`` dictionary (also embedded in training checkpoints under ``"policy"``)."""
    if actor.output == "linear":
        raise ValueError("a 'linear' network is not a policy: save Actor.squashed() for a Gaussian policy's mean action")
    return {"format": FORMAT, **actor.spec(), "state": {k: v.detach().cpu() for k, v in actor.state_dict().items()},
            "action_table": None if action_table is None else action_table.detach().cpu(),
            "task": task, "task_config": task_config, "algorithm": algorithm, **extra}


def save_policy(path: str | Path, actor: Actor, **kw: Any) -> None:
    """Write ``actor.pt`` with its content hash, durably (``torchnav.checkpoint.save_checked``); ``kw`` as in ``policy_payload``."""
    save_checked(path, policy_payload(actor, **kw))


def load_policy(path: str | Path, map_location: str | torch.device = "cpu") -> SavedPolicy:
    """Load an ``actor.pt`` or a recipe's ``checkpoint.pt`` (which embeds one under ``"policy"``).

    Raises ``FileNotFoundError`` for a missing file and ``ValueError`` naming the
    file for anything that is not a torchnav policy (:class:`~torchnav.checkpoint.CheckpointError`
    for a damaged file or non-finite weights).
    """
    path = Path(path)
    ck = load_checked(path, map_location)
    if ck.get("format") != FORMAT and isinstance(ck.get("policy"), dict):
        ck = ck["policy"]
    if ck.get("format") != FORMAT:
        raise ValueError(f"{path}: not a torchnav policy checkpoint (format {ck.get('format')!r}; expected {FORMAT!r})")
    try:
        actor = Actor(ck["obs_size"], ck["out_size"], ck["hidden"], ck["activation"], ck["output"])
        actor.load_state_dict(ck["state"])
    except (KeyError, RuntimeError, ValueError) as e:
        raise ValueError(f"{path}: policy checkpoint is inconsistent: {e}") from e
    actor.eval()
    known = {"format", HASH_KEY, "obs_size", "out_size", "hidden", "activation", "output", "state", "action_table", "task", "task_config", "algorithm"}
    return SavedPolicy(actor=actor, policy=to_policy(actor), task=ck["task"], task_config=ck["task_config"],
                       algorithm=ck["algorithm"], action_table=ck.get("action_table"), path=path,
                       extra={k: v for k, v in ck.items() if k not in known})


__all__ = ["Actor", "FORMAT", "SavedPolicy", "load_policy", "policy_payload", "save_policy", "to_policy"]
