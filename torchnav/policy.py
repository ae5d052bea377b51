"""Saved policies: one small actor format shared by every recipe, evaluation, comparison and export.

Every recipe saves its deterministic policy as ``actor.pt`` (the format, ``FORMAT``, is in
docs/training.md, "The policy file"): ``normalise -> Linear/activation stack -> head``, with a
``tanh`` head for continuous actions or the ``argmax`` of Q-values over ``action_table``.
Stochastic policies save their deterministic mean action (PPO's and SAC's ``tanh(loc)``).
A recurrent policy (PPO with ``train.recurrent: gru``) is a :class:`RecurrentActor`:
``normalise -> Linear/activation stack -> GRU cell -> head``, whose hidden state each env carries
from step to step (:class:`RecurrentStep`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictModuleBase
from torch import nn
from torchrl.modules import recurrent_mode

from .checkpoint import HASH_KEY, load_checked, save_checked

FORMAT = "torchnav-actor-v2"
RECURRENT_FORMAT = "torchnav-actor-v3"  # v2 plus a GRU cell: a RecurrentActor (feed-forward actors stay v2)
FORMATS = (FORMAT, RECURRENT_FORMAT)
RECURRENT = ("off", "gru")  # train.recurrent of the PPO recipes
STATE_KEY = "recurrent_state"  # the hidden state ``(..., state_size)`` each env carries in its TensorDict
ACTIVATIONS = {"relu": nn.ReLU, "tanh": nn.Tanh}
OUTPUTS = ("tanh", "argmax", "linear")  # "linear": raw outputs (value networks, pre-tanh means); not a saved policy


class _Normalised(nn.Module):
    """What every saved network starts with: sizes, activation, output, and ``(obs - obs_loc) / obs_scale``."""

    recurrent = False

    def __init__(self, obs_size: int, out_size: int, hidden: Sequence[int], activation: str, output: str) -> None:
        super().__init__()
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {activation!r}")
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
        self.obs_size, self.out_size, self.hidden = int(obs_size), int(out_size), [int(h) for h in hidden]
        self.activation, self.output = activation, output
        self.register_buffer("obs_loc", torch.zeros(obs_size))
        self.register_buffer("obs_scale", torch.ones(obs_size))

    def mlp(self) -> tuple[list[nn.Module], int]:
        """The ``Linear/activation`` layers of ``hidden`` and the width they end with."""
        layers: list[nn.Module] = []
        width = self.obs_size
        for h in self.hidden:
            layers += [nn.Linear(width, h), ACTIVATIONS[self.activation]()]
            width = h
        return layers, width

    def normalised(self, obs: torch.Tensor) -> torch.Tensor:
        return (obs - self.obs_loc) / self.obs_scale

    def set_normalization(self, loc: torch.Tensor, scale: torch.Tensor) -> None:
        """Observation statistics ``(obs_size,)``; ``scale`` must be positive."""
        if loc.shape != (self.obs_size,) or scale.shape != (self.obs_size,):
            raise ValueError(f"normalisation needs shapes ({self.obs_size},), got {tuple(loc.shape)} and {tuple(scale.shape)}")
        if not bool((scale > 0).all()):
            raise ValueError("normalisation scale must be positive")
        self.obs_loc.copy_(loc)
        self.obs_scale.copy_(scale)

    def squashed(self, n: int | None = None) -> "_Normalised":
        """A ``tanh`` copy of this network keeping the first ``n`` outputs: the deterministic
        action ``tanh(loc)`` of a Gaussian policy whose (linear) head emits ``loc`` first."""
        n = self.out_size if n is None else n
        with torch.random.fork_rng(devices=[]):  # the copy's random init is overwritten: leave the global RNG as it was
            out = type(self)(**{**self.spec(), "out_size": n, "output": "tanh"}).to(self.obs_loc.device)
        state = {k: v.detach().clone() for k, v in self.state_dict().items()}
        last = self.head_name()
        state[f"{last}.weight"], state[f"{last}.bias"] = state[f"{last}.weight"][:n], state[f"{last}.bias"][:n]
        out.load_state_dict(state)
        return out

    def spec(self) -> dict[str, Any]:
        return {"obs_size": self.obs_size, "out_size": self.out_size, "hidden": list(self.hidden),
                "activation": self.activation, "output": self.output}

    def head_name(self) -> str:
        raise NotImplementedError


class Actor(_Normalised):
    """Deterministic policy network ``obs (..., obs_size) -> out (..., out_size)``.

    ``(obs - obs_loc) / obs_scale`` feeds an MLP with ``hidden`` layers; with
    ``output="tanh"`` the result is squashed into ``[-1, 1]`` (continuous actions),
    with ``output="argmax"`` it is left as Q-values (``to_policy`` picks the best).
    """

    def __init__(self, obs_size: int, out_size: int, hidden: Sequence[int] = (256, 256), activation: str = "relu", output: str = "tanh"):
        super().__init__(obs_size, out_size, hidden, activation, output)
        layers, width = self.mlp()
        self.net = nn.Sequential(*layers, nn.Linear(width, out_size))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        y = self.net(self.normalised(obs))
        return torch.tanh(y) if self.output == "tanh" else y

    def head_name(self) -> str:
        return f"net.{len(self.net) - 1}"

    def linear_layers(self) -> list[nn.Linear]:
        return [m for m in self.net if isinstance(m, nn.Linear)]


class RecurrentActor(_Normalised):
    """Recurrent policy network: ``normalise -> MLP (hidden) -> GRU cell (state_size) -> Linear head``.

    :meth:`step` maps one observation per env and the state each env carries to the output
    and the next state; ``is_init`` marks envs whose episode starts at this step (their state
    is reset to zeros first). :meth:`unroll` runs whole ``(B, T)`` sequences the same way, one
    cell step per time step (the PPO update's minibatches). Outputs as :class:`Actor`'s.
    """

    recurrent = True

    def __init__(self, obs_size: int, out_size: int, hidden: Sequence[int] = (128, 128), activation: str = "relu",
                 output: str = "tanh", state_size: int = 128):
        super().__init__(obs_size, out_size, hidden, activation, output)
        if output == "argmax":
            raise ValueError("a recurrent actor has a 'tanh' or 'linear' head, not 'argmax'")
        if int(state_size) < 1:
            raise ValueError(f"state_size must be >= 1, got {state_size!r}")
        self.state_size = int(state_size)
        layers, width = self.mlp()
        self.encoder = nn.Sequential(*layers)
        self.cell = nn.GRUCell(width, self.state_size)
        self.head = nn.Linear(self.state_size, out_size)

    def initial_state(self, n: int, device: torch.device | str | None = None) -> torch.Tensor:
        """The state ``(n, state_size)`` of ``n`` envs at an episode's start (zeros)."""
        return torch.zeros(n, self.state_size, device=self.obs_loc.device if device is None else device)

    def _out(self, h: torch.Tensor) -> torch.Tensor:
        y = self.head(h)
        return torch.tanh(y) if self.output == "tanh" else y

    def step(self, obs: torch.Tensor, state: torch.Tensor, is_init: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``obs (B, obs_size)``, ``state (B, state_size)``, ``is_init (B,)`` bool -> ``(out (B, out_size), next state)``."""
        h = self._advance(self.encoder(self.normalised(obs)), state, is_init)
        return self._out(h), h

    def _advance(self, x: torch.Tensor, state: torch.Tensor, is_init: torch.Tensor | None) -> torch.Tensor:
        """One GRU step from the encoded observation ``x``, the state zeroed where ``is_init``."""
        if is_init is not None:
            state = torch.where(is_init[..., None], torch.zeros_like(state), state)
        return self.cell(x, state)

    def unroll(self, obs: torch.Tensor, state: torch.Tensor, is_init: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``obs (B, T, obs_size)`` from ``state (B, state_size)`` before the first step, ``is_init (B, T)``
        -> ``(out (B, T, out_size), states after each step (B, T, state_size))``: :meth:`step` T times."""
        x = self.encoder(self.normalised(obs))  # the MLP on every step at once; only the cell runs step by step
        hs = []
        for t in range(obs.shape[1]):
            state = self._advance(x[:, t], state, is_init[:, t])
            hs.append(state)
        h = torch.stack(hs, 1)
        return self._out(h), h

    def forward(self, obs: torch.Tensor, state: torch.Tensor, is_init: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        return self.step(obs, state, is_init)

    def head_name(self) -> str:
        return "head"

    def spec(self) -> dict[str, Any]:
        return {**super().spec(), "state_size": self.state_size}


def with_state(env: Any, actor: RecurrentActor, start: Callable[[], torch.Tensor] | None = None) -> Any:
    """``env`` with the state of ``actor`` that each env carries in its specs (TorchRL's
    ``TensorDictPrimer``: zeros at a reset), so that a collector's ``step_mdp`` carries it from
    one step to the next (it drops entries the specs do not name). The env itself is shared.
    ``start()``, if given, makes the state at a reset instead of zeros: a ``(num_envs, state_size)``
    tensor, of which the rows of the envs being reset are used."""
    from torchrl.data import Unbounded
    from torchrl.envs import TensorDictPrimer, TransformedEnv

    spec = {STATE_KEY: Unbounded(shape=(actor.state_size,), device=env.device)}
    return TransformedEnv(env, TensorDictPrimer(spec, default_value={STATE_KEY: start if start is not None else 0.0}, expand_specs=True))


class RecurrentStep(TensorDictModuleBase):
    """A :class:`RecurrentActor` on TensorDicts: reads ``"observation"``, the state each env carries
    (``"recurrent_state"``; zeros where missing) and ``("episode", "length")`` (0 at an episode's
    first step: the state is reset there), writes ``out_key`` and ``("next", "recurrent_state")``,
    which the env's step carries to the next step's TensorDict (a collector's ``step_mdp`` only
    through an env made by :func:`with_state`).

    One step of a ``(B,)`` TensorDict (collection, evaluation); under TorchRL's
    ``set_recurrent_mode(True)`` a ``(B, T)`` TensorDict of whole per-env sequences, started from
    the state stored at each env's first step (the PPO update)."""

    def __init__(self, actor: RecurrentActor, out_key: str = "action") -> None:
        super().__init__()
        self.actor = actor
        self.in_keys = ["observation", ("episode", "length"), STATE_KEY]
        self.out_keys = [out_key, ("next", STATE_KEY)]

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        obs = td.get("observation")
        is_init = td.get(("episode", "length")).squeeze(-1) == 0
        sequence = recurrent_mode()
        if sequence and td.ndim != 2:
            raise ValueError(f"RecurrentStep in recurrent mode needs a (envs, time) TensorDict, got batch size {tuple(td.batch_size)}")
        lead = td.batch_size[:1] if sequence else td.batch_size
        state = td.get(STATE_KEY, None)
        if state is None:  # an env's first step: stored too, so that a collected batch holds every step's input state
            state = self.actor.initial_state(lead.numel(), obs.device).reshape(*lead, -1)
            td.set(STATE_KEY, state)
        if sequence:
            out, h = self.actor.unroll(obs, state[:, 0], is_init)
        else:
            out, h = self.actor.step(obs.reshape(-1, obs.shape[-1]), state.reshape(-1, state.shape[-1]), is_init.reshape(-1))
            out, h = out.reshape(*lead, -1), h.reshape(*lead, -1)
        td.set(self.out_keys[0], out)
        td.set(self.out_keys[1], h)
        return td


class _ArgmaxOneHot(nn.Module):
    """Q-values ``(..., A)`` -> one-hot action ``(..., A)`` of the best action."""

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.one_hot(q.argmax(-1), q.shape[-1]).to(torch.long)


def to_policy(actor: Actor | RecurrentActor, in_key: str = "observation") -> TensorDictModuleBase:
    """A TensorDict policy writing ``"action"``: the tanh output, or a one-hot argmax for Q-networks;
    a :class:`RecurrentActor`'s is a :class:`RecurrentStep` (it also carries each env's state)."""
    if actor.output == "linear":
        raise ValueError("a 'linear' network is not a policy: use Actor.squashed() for a Gaussian policy's mean action")
    if actor.recurrent:
        if in_key != "observation":
            raise ValueError(f"a recurrent policy reads 'observation', got in_key={in_key!r}")
        return RecurrentStep(actor)
    if actor.output == "tanh":
        return TensorDictModule(actor, in_keys=[in_key], out_keys=["action"])
    return TensorDictModule(nn.Sequential(actor, _ArgmaxOneHot()), in_keys=[in_key], out_keys=["action"])


@dataclass
class SavedPolicy:
    """A loaded ``actor.pt``: the network, its TensorDict policy and what it was trained on."""

    actor: Actor | RecurrentActor
    policy: TensorDictModuleBase
    task: str
    task_config: dict[str, Any]
    algorithm: str
    action_table: torch.Tensor | None = None
    path: Path | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def config(self):
        """The task config object (``NavConfig``, ``LineConfig`` or ``MultiNavConfig``) it was trained with."""
        from .tasks import LineConfig, MultiNavConfig, NavConfig

        configs = {"nav": NavConfig, "line": LineConfig, "multi_nav": MultiNavConfig}
        if self.task not in configs:
            raise ValueError(f"{self.path}: unknown task {self.task!r}")
        return configs[self.task].from_dict(self.task_config, where=f"{self.path}:task_config")


def policy_payload(actor: Actor | RecurrentActor, *, task: str, task_config: dict[str, Any], algorithm: str,
                   action_table: torch.Tensor | None = None, **extra: Any) -> dict[str, Any]:
    """The ``actor.pt`` dictionary (also embedded in training checkpoints under ``"policy"``)."""
    if actor.output == "linear":
        raise ValueError("a 'linear' network is not a policy: save Actor.squashed() for a Gaussian policy's mean action")
    return {"format": RECURRENT_FORMAT if actor.recurrent else FORMAT, **actor.spec(), "state": {k: v.detach().cpu() for k, v in actor.state_dict().items()},
            "action_table": None if action_table is None else action_table.detach().cpu(),
            "task": task, "task_config": task_config, "algorithm": algorithm, **extra}


def save_policy(path: str | Path, actor: Actor | RecurrentActor, **kw: Any) -> None:
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
    if ck.get("format") not in FORMATS and isinstance(ck.get("policy"), dict):
        ck = ck["policy"]
    if ck.get("format") not in FORMATS:
        raise ValueError(f"{path}: not a torchnav policy checkpoint: format {ck.get('format')!r}, expected {FORMAT!r} or {RECURRENT_FORMAT!r} "
                         "(an actor.pt, or a recipe's checkpoint.pt holding one under 'policy')")
    try:
        if ck["format"] == RECURRENT_FORMAT:
            actor = RecurrentActor(ck["obs_size"], ck["out_size"], ck["hidden"], ck["activation"], ck["output"], ck["state_size"])
        else:
            actor = Actor(ck["obs_size"], ck["out_size"], ck["hidden"], ck["activation"], ck["output"])
        actor.load_state_dict(ck["state"])
    except (KeyError, RuntimeError, ValueError) as e:
        raise ValueError(f"{path}: policy checkpoint is inconsistent: {e}") from e
    actor.eval()
    known = {"format", HASH_KEY, "obs_size", "out_size", "hidden", "activation", "output", "state_size", "state", "action_table", "task", "task_config", "algorithm"}
    return SavedPolicy(actor=actor, policy=to_policy(actor), task=ck["task"], task_config=ck["task_config"],
                       algorithm=ck["algorithm"], action_table=ck.get("action_table"), path=path,
                       extra={k: v for k, v in ck.items() if k not in known})


__all__ = ["Actor", "FORMAT", "RECURRENT_FORMAT", "RecurrentActor", "RecurrentStep", "SavedPolicy", "with_state", "load_policy", "policy_payload", "save_policy", "to_policy"]
