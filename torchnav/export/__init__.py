"""Export a trained torchnav actor for deployment: ONNX, and dependency-free C99 for microcontrollers.

Command line (see docs/export.md)::

    python -m torchnav.export CHECKPOINT --onnx out.onnx --c out_dir/ [--name policy] [--verify 1000] [--tolerance 1e-5]

Python::

    from torchnav.export import export
    report = export("checkpoints/td3_arena_actor.pt", onnx_path="actor.onnx", c_dir="actor_c")

Both verify the exports against PyTorch (float32) on random observations and raise
``VerificationError`` when the largest absolute error exceeds the tolerance. The ONNX
part needs the ``export`` extra (``pip install 'torchnav[export]'``: onnx, onnxruntime);
the C part needs nothing but a C compiler to verify.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..policy import SavedPolicy, load_policy
from .c import check_name, compile_test, export_c, find_compiler, verify_c
from .common import Network, VerificationError, compare, describe, network_of, random_observations, reference
from .onnx import build_model, export_onnx, run_onnx, verify_onnx


def export(checkpoint: str | Path | SavedPolicy, *, onnx_path: str | Path | None = None, c_dir: str | Path | None = None,
           name: str = "policy", verify: int = 1000, tolerance: float = 1e-5, seed: int = 0) -> dict[str, Any]:
    """Export ``checkpoint`` (an ``actor.pt``/``checkpoint.pt`` path or a loaded policy) to ONNX and/or C.

    ``verify`` random observations (0: none) are run through PyTorch and each export.
    Returns ``{"files": [Path, ...], "footprint": {...}, "onnx": errors | None,
    "c": errors | None, "c_skipped": reason | None}`` (errors as in ``common.compare``).
    Raises ``VerificationError`` if an export differs from PyTorch by more than ``tolerance``,
    ``FileNotFoundError``/``ValueError`` for a missing or non-policy checkpoint,
    ``ImportError`` naming the extra to install when onnx/onnxruntime are missing.
    """
    if onnx_path is None and c_dir is None:
        raise ValueError("nothing to export: give an ONNX path and/or a C output folder")
    check_name(name)
    saved = checkpoint if isinstance(checkpoint, SavedPolicy) else load_policy(checkpoint)
    net = network_of(saved)
    obs = random_observations(net, verify, seed) if verify > 0 else None
    ref = reference(saved.actor, obs, net.action_table) if obs is not None else None
    report: dict[str, Any] = {"files": [], "footprint": net.footprint(), "onnx": None, "c": None, "c_skipped": None}
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
        report["files"] += export_c(net, c_dir, name)
        if ref is None:
            report["c_skipped"] = "verification disabled"
        else:
            res = verify_c(c_dir, net, ref, obs, tolerance, name)
            if res is None:
                report["c_skipped"] = "no C compiler found (set CC or install gcc/clang)"
            else:
                report["c"] = res
                if not res["ok"]:
                    failures.append(f"C code in {c_dir}: {describe(res)} exceeds tolerance {tolerance:g}")
    if failures:
        raise VerificationError("export does not match PyTorch: " + "; ".join(failures))
    return report


__all__ = ["Network", "VerificationError", "build_model", "check_name", "compare", "compile_test", "export", "export_c",
           "export_onnx", "find_compiler", "network_of", "random_observations", "reference", "run_onnx", "verify_c",
           "verify_onnx"]
