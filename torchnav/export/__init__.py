"""Export a trained torchnav actor for deployment: ONNX, and dependency-free C99 for microcontrollers.

``export(checkpoint, onnx_path=..., c_dir=...)`` and ``python -m torchnav.export`` write the files
and verify them against PyTorch on random observations (``VerificationError`` beyond the
tolerance); the options (quantised weights, the Cortex-M4F target) are in docs/export.md."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..policy import SavedPolicy, load_policy
from .c import check_name, compile_test, export_c, find_compiler, verify_c
from .common import (WEIGHT_FORMATS, Network, VerificationError, compare, describe, network_of, quantize, quantized_actor,
                     random_observations, reference)
from .cortex_m import (TARGETS, MissingToolError, describe_cost, export_cortex_m4f, missing_tools, toolchain_hint,
                       verify_cortex_m4f)
from .onnx import build_model, export_onnx, run_onnx, verify_onnx


def export(checkpoint: str | Path | SavedPolicy, *, onnx_path: str | Path | None = None, c_dir: str | Path | None = None,
           name: str = "policy", verify: int = 1000, tolerance: float = 1e-5, seed: int = 0, weights: str = "float32",
           target: str = "host") -> dict[str, Any]:
    """Export ``checkpoint`` (an ``actor.pt``/``checkpoint.pt`` path or a loaded policy) to ONNX and/or C.

    ``weights`` (``WEIGHT_FORMATS``) is the C export's weight storage; the ONNX model always
    holds the float32 network. ``target`` is ``"host"`` (the C files, checked with the host
    compiler) or ``"cortex-m4f"`` (also a bare-metal build, checked in QEMU).
    ``verify`` random observations (0: none) are run through PyTorch and each export.
    Returns ``{"files": [Path, ...], "footprint": {...}, "onnx": errors | None,
    "c": errors | None, "c_skipped": reason | None, "weights": str, "quantization": errors | None,
    "cortex_m4f": errors and size/cost report | None}`` (errors as in ``common.compare``;
    ``quantization`` compares PyTorch with float32 and with the dequantised weights).
    Raises ``VerificationError`` if an export differs from PyTorch by more than ``tolerance``,
    ``FileNotFoundError``/``ValueError`` for a missing or non-policy checkpoint or a bad option,
    ``ImportError`` naming the extra to install when onnx/onnxruntime are missing,
    ``MissingToolError`` naming the packages when the cortex-m4f toolchain or QEMU is missing.
    """
    if onnx_path is None and c_dir is None:
        raise ValueError("nothing to export: give an ONNX path and/or a C output folder")
    if weights not in WEIGHT_FORMATS:
        raise ValueError(f"unknown weight format {weights!r}: choose one of {', '.join(WEIGHT_FORMATS)}")
    if target not in TARGETS:
        raise ValueError(f"unknown target {target!r}: choose one of {', '.join(TARGETS)}")
    if c_dir is None and (weights != "float32" or target != "host"):
        raise ValueError("--weights and --target apply to the C export: give --c DIR as well")
    check_name(name)
    if target == "cortex-m4f" and verify > 0 and missing_tools():  # fail before writing anything
        raise MissingToolError(f"{', '.join(missing_tools())} not found; {toolchain_hint()}")
    saved = checkpoint if isinstance(checkpoint, SavedPolicy) else load_policy(checkpoint)
    net = network_of(saved)
    cnet = quantize(net, weights)
    obs = random_observations(net, verify, seed) if verify > 0 else None
    ref = reference(saved.actor, obs, net.action_table) if obs is not None else None
    cref = ref
    report: dict[str, Any] = {"files": [], "footprint": cnet.footprint(), "onnx": None, "c": None, "c_skipped": None,
                              "weights": weights, "quantization": None, "cortex_m4f": None}
    if ref is not None and weights != "float32":
        cref = reference(quantized_actor(saved.actor, weights), obs, net.action_table)
        report["quantization"] = compare(ref, cref, tolerance)
    failures = []
    if onnx_path is not None:
        if ref is not None:  # fail on a missing onnxruntime before writing anything
            try:
                import onnxruntime  # noqa: F401
            except ImportError as e:
                raise ImportError("verifying the ONNX model needs onnxruntime; install the export extra: "
                                  "pip install 'torchnav[export]' (or pass --verify 0)") from e
        report["files"].append(export_onnx(net, onnx_path))
        if ref is not None:
            report["onnx"] = verify_onnx(onnx_path, ref, obs, tolerance)
            if not report["onnx"]["ok"]:
                failures.append(f"ONNX model {onnx_path}: {describe(report['onnx'])} exceeds tolerance {tolerance:g}")
    if c_dir is not None:
        report["files"] += export_c(cnet, c_dir, name)
        if target == "cortex-m4f":
            report["files"] += export_cortex_m4f(cnet, c_dir, name)
        if cref is None:
            report["c_skipped"] = "verification disabled"
        else:
            res = verify_c(c_dir, cnet, cref, obs, tolerance, name)
            if res is None:
                report["c_skipped"] = "no C compiler found (set CC or install gcc/clang)"
            else:
                report["c"] = res
                if not res["ok"]:
                    failures.append(f"C code in {c_dir}: {describe(res)} exceeds tolerance {tolerance:g}")
            if target == "cortex-m4f":
                res = report["cortex_m4f"] = verify_cortex_m4f(c_dir, cnet, cref, obs, tolerance, name)
                if not res["ok"]:
                    failures.append(f"Cortex-M4F build of {c_dir} in QEMU: {describe(res)} exceeds tolerance {tolerance:g}")
    if failures:
        raise VerificationError("export does not match PyTorch: " + "; ".join(failures))
    return report


__all__ = ["TARGETS", "WEIGHT_FORMATS", "MissingToolError", "Network", "VerificationError", "build_model", "check_name",
           "compare", "compile_test", "describe", "describe_cost", "export", "export_c", "export_cortex_m4f", "export_onnx",
           "find_compiler", "missing_tools", "network_of", "quantize", "quantized_actor", "random_observations", "reference",
           "run_onnx", "verify_c", "verify_cortex_m4f", "verify_onnx"]
