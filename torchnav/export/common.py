"""What every exporter shares: the network as plain float32 arrays, the PyTorch reference and test inputs.

The network computes what ``torchnav.policy.Actor`` does (docs/export.md). Its weight matrices
can be stored as float32, float16 (IEEE half, rounded to nearest even) or int8 with one float32
scale per output row (``q = round(W / s)``, ``s = max|row| / 127``); biases, the normalisation
and all arithmetic stay float32. ``quantize(net, weights)`` gives the network with the
dequantised weights, which ``quantized_actor`` puts into the PyTorch reference."""

from __future__ import annotations

import copy
import subprocess
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from .. import __version__
from ..policy import Actor, SavedPolicy

WEIGHT_FORMATS = ("float32", "float16", "int8")
_WEIGHT_BYTES = {"float32": 4, "float16": 2, "int8": 1}


@dataclass
class Network:
    """The network of an actor as float32 numpy arrays, plus what it was trained for.

    ``layers`` holds ``(weight (out, in), bias (out,))`` pairs, first to last;
    ``action_table`` is ``(A, 2)`` for ``output="argmax"`` and ``None`` otherwise.
    """

    obs_loc: np.ndarray
    obs_scale: np.ndarray
    layers: list[tuple[np.ndarray, np.ndarray]]
    activation: str
    output: str
    action_table: np.ndarray | None
    metadata: dict[str, str] = field(default_factory=dict)
    weights: str = "float32"
    #: per layer, what the C code stores: float16 -> uint16 bit patterns (out, in); int8 -> (int8 (out, in), float32 scales (out,))
    stored: list[Any] | None = None

    @property
    def obs_size(self) -> int:
        return int(self.obs_loc.shape[0])

    @property
    def out_size(self) -> int:
        """Width of the last layer: actions (tanh) or Q-values (argmax)."""
        return int(self.layers[-1][0].shape[0])

    @property
    def act_size(self) -> int:
        """Floats written per action: ``out_size`` (tanh) or the action table's width (argmax)."""
        return self.out_size if self.action_table is None else int(self.action_table.shape[1])

    @property
    def output_width(self) -> int:
        """Floats an exported program writes per observation: the action, or (argmax) index, action and Q-values."""
        return 1 + self.act_size + self.out_size if self.output == "argmax" else self.act_size

    @property
    def max_width(self) -> int:
        return max(w.shape[0] for w, _ in self.layers)

    def footprint(self) -> dict[str, int]:
        """Bytes of constant data (flash) and of working buffers (RAM) in the C export, and multiply-adds per call.

        Flash: weights at their storage size (4, 2 or 1 bytes; int8 adds a float32 scale per
        output row), biases, normalisation and action table as float32.
        """
        params = sum(w.size + b.size for w, b in self.layers)
        weight_bytes = sum(_WEIGHT_BYTES[self.weights] * w.size + (4 * w.shape[0] if self.weights == "int8" else 0)
                           for w, _ in self.layers)
        floats = sum(b.size for _, b in self.layers) + 2 * self.obs_size + (0 if self.action_table is None else self.action_table.size)
        return {"parameters": int(params), "flash_bytes": int(weight_bytes + 4 * floats),
                "ram_bytes": 4 * 2 * max(self.max_width, self.obs_size),
                "macs": int(sum(w.size for w, _ in self.layers))}


def network_of(policy: SavedPolicy | Actor, action_table: torch.Tensor | None = None) -> Network:
    """Plain arrays of a loaded policy (or a bare ``Actor`` plus its ``action_table`` ``(A, 2)``).

    Raises ``ValueError`` for non-finite parameters or an argmax actor without a
    matching action table.
    """
    meta: dict[str, str] = {"torchnav_version": __version__}
    if isinstance(policy, SavedPolicy):
        actor, table = policy.actor, policy.action_table if action_table is None else action_table
        meta.update(algorithm=str(policy.algorithm), task=str(policy.task))
        if policy.path is not None:
            meta["source"] = policy.path.name
    elif isinstance(policy, Actor):
        actor, table = policy, action_table
    else:
        raise TypeError(f"expected a SavedPolicy or an Actor, got {type(policy).__name__}")

    def arr(t: torch.Tensor) -> np.ndarray:
        a = t.detach().cpu().to(torch.float32).numpy().copy()
        if not np.isfinite(a).all():
            raise ValueError("the policy has non-finite parameters (NaN or inf); cannot export")
        return a

    if actor.recurrent:
        raise ValueError("recurrent (GRU) policies cannot be exported yet: the ONNX and C exports hold a feed-forward "
                         "Linear/activation stack only, with no hidden state to carry between calls; "
                         "train with train.recurrent=off for an exportable policy")
    if actor.output not in ("tanh", "argmax"):
        raise ValueError(f"only policies with a 'tanh' or 'argmax' head can be exported, got output={actor.output!r}")
    layers = [(arr(m.weight), arr(m.bias)) for m in actor.linear_layers()]
    if actor.output == "argmax":
        if table is None:
            raise ValueError("a discrete (argmax) policy needs its action_table (A, 2) to export commands")
        table_np = arr(torch.as_tensor(table)).reshape(len(table), -1)
        if table_np.shape[0] != actor.out_size:
            raise ValueError(f"action_table has {table_np.shape[0]} rows but the network outputs {actor.out_size} Q-values")
    else:
        table_np = None
    meta.update(obs_size=str(actor.obs_size), act_size=str(actor.out_size if table_np is None else table_np.shape[1]),
                hidden=",".join(str(h) for h in actor.hidden), activation=actor.activation, output=actor.output)
    return Network(arr(actor.obs_loc), arr(actor.obs_scale), layers, actor.activation, actor.output, table_np, meta)


def quantize_weight(w: np.ndarray, weights: str, layer: int = 0) -> tuple[np.ndarray, Any]:
    """One weight matrix ``(out, in)`` in format ``weights``: ``(dequantised float32 (out, in), stored)``.

    ``stored`` is ``w`` itself (float32), the uint16 bit patterns of the float16 values
    (float16), or ``(q int8 (out, in), scale float32 (out,))`` with ``dequantised = q * scale``
    (int8). Raises ``ValueError`` for an unknown format or weights beyond float16's range.
    """
    if weights not in WEIGHT_FORMATS:
        raise ValueError(f"unknown weight format {weights!r}; choose one of {', '.join(WEIGHT_FORMATS)}")
    w = np.asarray(w, dtype=np.float32)
    if weights == "float32":
        return w, w
    if weights == "float16":
        with np.errstate(over="ignore"):  # checked just below, with a message naming the layer
            h = w.astype(np.float16)
        if not np.isfinite(h).all():
            raise ValueError(f"layer {layer} has weights beyond float16's range (|w| > 65504); export it as float32 or int8")
        return h.astype(np.float32), h.view(np.uint16)
    scale = (np.abs(w).max(axis=1) / np.float32(127.0)).astype(np.float32)
    scale[scale == 0] = 1.0  # an all-zero row: any scale stores it exactly
    q = np.clip(np.rint(w / scale[:, None]), -127, 127).astype(np.int8)
    return (q.astype(np.float32) * scale[:, None]).astype(np.float32), (q, scale)


def quantize(net: Network, weights: str) -> Network:
    """``net`` with its weight matrices stored as ``weights`` (one of ``WEIGHT_FORMATS``).

    ``layers`` of the result hold the dequantised float32 weights (the values the C code
    multiplies by; for int8 it applies the row's scale after the row sum) and ``stored``
    what the C code keeps in flash (see ``quantize_weight``).
    """
    if net.weights != "float32":
        raise ValueError(f"the network is already quantised ({net.weights}); quantise the float32 network")
    pairs = [quantize_weight(w, weights, k) for k, (w, _) in enumerate(net.layers)]
    if weights == "float32":
        return net
    layers = [(deq, b) for (deq, _), (_, b) in zip(pairs, net.layers)]
    return Network(net.obs_loc, net.obs_scale, layers, net.activation, net.output, net.action_table,
                   {**net.metadata, "weights": weights}, weights, [st for _, st in pairs])


def quantized_actor(actor: Actor, weights: str) -> Actor:
    """A copy of ``actor`` whose weight matrices hold the dequantised ``weights`` values: the quantised
    C export's computation in PyTorch (the reference it is verified against, and what evaluation measures)."""
    out = copy.deepcopy(actor)
    with torch.no_grad():
        for k, m in enumerate(out.linear_layers()):
            deq, _ = quantize_weight(m.weight.detach().cpu().to(torch.float32).numpy(), weights, k)
            m.weight.copy_(torch.from_numpy(deq))
    return out


def random_observations(net: Network, n: int, seed: int = 0) -> np.ndarray:
    """``(n, obs_size)`` float32 raw observations, ``obs_loc + obs_scale * N(0, 1)``.

    Drawn in the normalised space the network was trained in, so hidden units and the
    head see realistic magnitudes rather than saturating.
    """
    g = np.random.default_rng(seed)
    return (net.obs_loc + net.obs_scale * g.standard_normal((n, net.obs_size))).astype(np.float32)


def reference(actor: Actor, obs: np.ndarray, action_table: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """PyTorch float32 outputs for ``obs`` ``(n, obs_size)``.

    Returns ``{"action": (n, act_size)}`` and, for argmax actors, ``"index"`` ``(n,)``
    and ``"q"`` ``(n, A)``.
    """
    with torch.no_grad():
        x = torch.from_numpy(np.ascontiguousarray(obs, dtype=np.float32)).to(actor.obs_loc)
        y = actor(x).to(torch.float32).numpy()
    if actor.output == "tanh":
        return {"action": y}
    idx = y.argmax(-1)
    return {"action": action_table[idx], "index": idx, "q": y}


def outputs(vals: np.ndarray, net: Network) -> dict[str, np.ndarray]:
    """An exported program's output rows ``(n, width)`` as :func:`reference` gives them: the action,
    or (argmax) the index, the action and the Q-values."""
    if net.output == "tanh":
        return {"action": vals}
    a = net.act_size
    return {"index": vals[:, 0].astype(np.int64), "action": vals[:, 1:1 + a], "q": vals[:, 1 + a:]}


def run_tool(cmd: list[str], what: str, **kw: Any) -> subprocess.CompletedProcess:
    """Run a compiler, the test program or QEMU; ``RuntimeError`` with its output when it fails."""
    r = subprocess.run(cmd, capture_output=True, text=True, **kw)
    if r.returncode != 0:
        raise RuntimeError(f"{what} failed (exit {r.returncode}: {' '.join(cmd)}):\n{r.stdout}{r.stderr}")
    return r


def compare(ref: dict[str, np.ndarray], got: dict[str, np.ndarray], tolerance: float) -> dict[str, Any]:
    """Max absolute errors between two output sets and whether they are within ``tolerance``.

    For argmax policies the Q-values must agree within ``tolerance * max(1, max |Q|)``
    (relative for large returns); a different index is accepted only where the
    reference's best two Q-values are that close (a tie float rounding may break either way).
    """
    out: dict[str, Any] = {}
    if "q" in ref:
        # Q-values are returns, not bounded like actions; float32 sums err in proportion to their size.
        q_tol = tolerance * max(1.0, float(np.abs(ref["q"]).max()))
        out["q_max_abs_err"], out["q_tolerance"] = float(np.abs(ref["q"] - got["q"]).max()), q_tol
        diff = ref["index"] != got["index"]
        top2 = np.sort(ref["q"], axis=-1)[:, -2:] if ref["q"].shape[-1] > 1 else np.zeros((len(diff), 2))
        out["index_mismatches"] = int(diff.sum())
        out["index_untied_mismatches"] = int((diff & (top2[:, 1] - top2[:, 0] > q_tol)).sum())
        out["action_max_abs_err"] = float(np.abs(ref["action"] - got["action"]).max())
        ok = out["q_max_abs_err"] <= q_tol and out["index_untied_mismatches"] == 0
    else:
        out["action_max_abs_err"] = float(np.abs(ref["action"] - got["action"]).max())
        ok = out["action_max_abs_err"] <= tolerance
    out["ok"] = bool(ok)
    return out


def describe(errors: dict[str, Any]) -> str:
    """One line, e.g. ``max |error| 2.4e-07`` or ``max |Q error| 1.2e-06, 0 index mismatches``."""
    if "q_max_abs_err" in errors:
        return f"max |Q error| {errors['q_max_abs_err']:.2g}, {errors['index_mismatches']} index mismatches"
    return f"max |action error| {errors['action_max_abs_err']:.2g}"


class VerificationError(RuntimeError):
    """An export does not reproduce PyTorch within the tolerance."""
