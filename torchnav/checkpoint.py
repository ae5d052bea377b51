"""Checkpoint files that say when they are damaged: content-hashed, finite, written durably.

Every ``actor.pt`` and recipe ``checkpoint.pt`` goes through :func:`save_checked` (a ``"sha256"``
of the content; temporary file, ``fsync``, rename) and :func:`load_checked` (refuses a changed
hash or a NaN/inf tensor, naming the file and key). A file without the hash was not written by
torchnav and is refused."""

from __future__ import annotations

import hashlib
import io
import os
from pathlib import Path
from typing import Any

import torch

HASH_KEY = "sha256"


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used: unreadable, damaged, or holding non-finite weights."""


def _feed(h: "hashlib._Hash", obj: Any) -> None:
    if isinstance(obj, torch.Tensor):
        t = obj.detach().cpu().contiguous()
        h.update(f"T{t.dtype}{tuple(t.shape)}".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    elif isinstance(obj, dict):
        h.update(b"{")
        for k in sorted(obj, key=repr):
            h.update(repr(k).encode())
            _feed(h, obj[k])
        h.update(b"}")
    elif isinstance(obj, (list, tuple)):
        h.update(b"[" if isinstance(obj, list) else b"(")
        for x in obj:
            _feed(h, x)
        h.update(b"]")
    else:
        h.update(f"{type(obj).__name__}:{obj!r}".encode())


def content_hash(payload: dict[str, Any]) -> str:
    """SHA-256 of a payload's content, the ``"sha256"`` entry excluded."""
    h = hashlib.sha256()
    _feed(h, {k: v for k, v in payload.items() if k != HASH_KEY})
    return h.hexdigest()


INF_ALLOWED = ("env",)  # payload keys whose tensors may hold inf (an env's "no limit" parameters), never NaN


def _non_finite(obj: Any, path: str = "", allow_inf: bool = False) -> str | None:
    if isinstance(obj, torch.Tensor):
        if not obj.is_floating_point():
            return None
        return path if bool(obj.isnan().any()) or (not allow_inf and not bool(torch.isfinite(obj).all())) else None
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) if isinstance(obj, (list, tuple)) else ()
    for k, v in items:
        bad = _non_finite(v, f"{path}.{k}" if path else str(k), allow_inf or (not path and k in INF_ALLOWED))
        if bad is not None:
            return bad
    return None


def save_checked(path: str | Path, payload: dict[str, Any]) -> None:
    """Write ``payload`` with its content hash to ``path`` (:func:`write_atomic`)."""
    buf = io.BytesIO()
    torch.save({**payload, HASH_KEY: content_hash(payload)}, buf)
    write_atomic(path, buf.getbuffer())


def write_atomic(path: str | Path, data: bytes | memoryview | str) -> None:
    """Write ``data`` to ``path`` through a temporary file beside it, fsync and rename: a write
    that fails half way (disk full, the process killed) leaves the previous ``path`` whole, and the
    error (``OSError``) reaches the caller; the half-written temporary file is removed."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:  # make the rename itself durable
        fd = os.open(path.parent, os.O_RDONLY)
    except OSError:  # directories cannot be opened on some systems
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def load_checked(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Load a payload written by :func:`save_checked`.

    Raises ``FileNotFoundError`` for a missing file and :class:`CheckpointError`, naming
    the file, for one that cannot be read, is not a dict, has no content hash or does not
    match it, or holds a NaN or inf in a floating-point tensor.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    try:
        ck = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as e:  # noqa: BLE001 - re-raised with the file named
        raise CheckpointError(f"cannot load {path}: the file is damaged or not a torch file ({type(e).__name__}: {e})") from e
    if not isinstance(ck, dict):
        raise CheckpointError(f"{path}: not a torchnav checkpoint (a {type(ck).__name__}, not a dict)")
    if HASH_KEY not in ck:
        raise CheckpointError(f"{path}: not a torchnav file: it has no {HASH_KEY!r} content hash (format {ck.get('format')!r}); "
                              "every checkpoint and actor.pt torchnav writes (torchnav.checkpoint.save_checked) has one")
    if ck[HASH_KEY] != content_hash(ck):
        raise CheckpointError(f"{path}: content does not match its sha256 (the file was damaged or edited after it was written)")
    bad = _non_finite({k: v for k, v in ck.items() if k != HASH_KEY})
    if bad is not None:
        raise CheckpointError(f"{path}: {bad} holds NaN or inf values (a diverged run?); refusing to load it")
    return ck
