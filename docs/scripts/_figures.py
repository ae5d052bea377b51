"""What the picture scripts share: writing a finished figure."""

from __future__ import annotations

from pathlib import Path


def save(fig, path, **savefig) -> Path:
    """Lay ``fig`` out tightly, write it to ``path`` (creating its folder) and say so."""
    path = Path(path)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, **savefig)
    print(f"wrote {path}")
    return path
