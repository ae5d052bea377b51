"""ONNX export of a torchnav actor, built node by node with ``onnx.helper`` (opset 17, dynamic batch).

Not ``torch.onnx.export``: it needs ``onnxscript`` (dynamo) or is deprecated (TorchScript); the
actor's fixed chain of standard operators needs only ``onnx``. The graph: docs/export.md."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..checkpoint import write_atomic
from .common import Network, compare

OPSET = 17
IR_VERSION = 8  # the IR version of opset 17; readable by onnxruntime >= 1.10
EXTRA_HINT = "install the export extra: pip install 'torchnav[export]'"


def _import_onnx():
    try:
        import onnx
    except ImportError as e:
        raise ImportError(f"writing ONNX needs the onnx package; {EXTRA_HINT}") from e
    return onnx


def build_model(net: Network):
    """The ``onnx.ModelProto`` of ``net`` (inputs ``observation``; outputs ``action`` and, for argmax, ``action_index``, ``q_values``)."""
    onnx = _import_onnx()
    from onnx import TensorProto, helper, numpy_helper

    inits, nodes = [], []

    def const(name: str, value: np.ndarray) -> str:
        inits.append(numpy_helper.from_array(np.ascontiguousarray(value), name))
        return name

    nodes.append(helper.make_node("Sub", ["observation", const("obs_loc", net.obs_loc)], ["obs_centred"]))
    nodes.append(helper.make_node("Div", ["obs_centred", const("obs_scale", net.obs_scale)], ["x0"]))
    x = "x0"
    act_op = {"relu": "Relu", "tanh": "Tanh"}[net.activation]
    last = len(net.layers) - 1
    for k, (w, b) in enumerate(net.layers):
        y = "y_out" if k == last else f"h{k}"
        nodes.append(helper.make_node("Gemm", [x, const(f"W{k}", w), const(f"b{k}", b)], [y], transB=1))
        if k < last:
            nodes.append(helper.make_node(act_op, [y], [f"x{k + 1}"]))
            x = f"x{k + 1}"

    batch = "batch"
    outputs = []
    if net.output == "tanh":
        nodes.append(helper.make_node("Tanh", ["y_out"], ["action"]))
        outputs.append(helper.make_tensor_value_info("action", TensorProto.FLOAT, [batch, net.out_size]))
    else:
        nodes.append(helper.make_node("Identity", ["y_out"], ["q_values"]))
        nodes.append(helper.make_node("ArgMax", ["y_out"], ["action_index"], axis=1, keepdims=0))
        nodes.append(helper.make_node("Gather", [const("action_table", net.action_table), "action_index"], ["action"], axis=0))
        outputs += [helper.make_tensor_value_info("action", TensorProto.FLOAT, [batch, net.act_size]),
                    helper.make_tensor_value_info("action_index", TensorProto.INT64, [batch]),
                    helper.make_tensor_value_info("q_values", TensorProto.FLOAT, [batch, net.out_size])]
    graph = helper.make_graph(
        nodes, "torchnav_actor",
        [helper.make_tensor_value_info("observation", TensorProto.FLOAT, [batch, net.obs_size])],
        outputs, initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="torchnav",
                              producer_version=net.metadata.get("torchnav_version", ""), ir_version=IR_VERSION,
                              doc_string="torchnav actor: raw observation -> action (normalisation included)")
    helper.set_model_props(model, {"format": "torchnav-actor-onnx-v1", **net.metadata})
    onnx.checker.check_model(model)
    return model


def export_onnx(net: Network, path: str | Path) -> Path:
    """Write ``net`` as an ONNX model to ``path`` (parent folders are created); returns the path."""
    onnx = _import_onnx()
    path = Path(path)
    model = build_model(net)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, model.SerializeToString())  # a failed write keeps the previous file whole
    return path


def run_onnx(path: str | Path, obs: np.ndarray) -> dict[str, np.ndarray]:
    """Outputs of the ONNX model at ``path`` under onnxruntime (one thread) for ``obs`` ``(n, obs_size)``.

    Keys as in ``common.reference``: ``action`` and, for argmax models, ``index`` and ``q``.
    """
    try:
        import onnxruntime as ort
    except ImportError as e:
        raise ImportError(f"verifying the ONNX model needs onnxruntime; {EXTRA_HINT} (or pass --verify 0)") from e
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = opts.inter_op_num_threads = 1
    sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    names = [o.name for o in sess.get_outputs()]
    res = dict(zip(names, sess.run(None, {"observation": np.ascontiguousarray(obs, dtype=np.float32)})))
    out = {"action": res["action"]}
    if "action_index" in res:
        out.update(index=res["action_index"], q=res["q_values"])
    return out


def verify_onnx(path: str | Path, ref: dict[str, np.ndarray], obs: np.ndarray, tolerance: float) -> dict[str, Any]:
    """Compare the ONNX model at ``path`` against PyTorch outputs ``ref`` on ``obs``; see ``common.compare``."""
    return compare(ref, run_onnx(path, obs), tolerance)
