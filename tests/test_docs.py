"""Every Python code block of README.md and docs/*.md runs as written.

Each page runs in a fresh directory that links the repository's ``checkpoints``,
``maps``, ``recipes`` and ``tests`` (so the paths the pages use resolve, and files
the examples write stay out of the repository), its blocks one after another in one
process, each in a fresh namespace. A block preceded by ``<!-- file: PATH -->`` is a
file the page's examples read: it is written to PATH first. Shell blocks are not run.
A ``print(...)`` line whose comment starts with a value (``# 10 5 11``, ``# (1024, 11, 5)``,
``# None {...}``) states what it prints: the block's output must contain that value
(the comment up to a ``": "`` outside brackets, which starts an explanation).
"""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"(?:<!-- file: (?P<file>\S+) -->\n)?```(?P<lang>\w*)\n(?P<code>.*?)```", re.S)
LINKED = ("checkpoints", "examples", "maps", "recipes", "tests")

RUNNER = textwrap.dedent("""
    import contextlib, io, sys, traceback
    blocks, expected = {blocks!r}, {expected!r}
    for i, code in enumerate(blocks):
        out = io.StringIO()
        try:
            with contextlib.redirect_stdout(out):
                exec(compile(code, f"{page}#python-block-{{i}}", "exec"), {{"__name__": "__main__"}})
        except BaseException:
            traceback.print_exc()
            sys.exit(f"{page}: Python block {{i}} failed")
        printed = " ".join(out.getvalue().split())
        for want in expected[i]:
            if " ".join(want.split()) not in printed:
                sys.exit(f"{page}: Python block {{i}} should print {{want!r}}, printed {{out.getvalue()!r}}")
""")
STATED = re.compile(r"^\s*print\(.*\)\s+#\s*(?P<out>[-\d(\[{]|None|True|False)(?P<rest>.*)$")


def _stated_outputs(code: str) -> list[str]:
    """The values the block's ``print`` comments say it prints."""
    out = []
    for line in code.splitlines():
        m = STATED.match(line)
        if m:
            text = m["out"] + m["rest"]
            cut = next((i for i in range(len(text)) if text.startswith(": ", i) and _balanced(text[:i])), len(text))
            out.append(text[:cut].strip())
    return out


def _balanced(s: str) -> bool:
    return all(s.count(a) == s.count(b) for a, b in ("()", "[]", "{}"))


def _blocks(page: Path) -> tuple[list[str], dict[str, str]]:
    code, files = [], {}
    for m in BLOCK.finditer(page.read_text()):
        if m["file"]:
            files[m["file"]] = m["code"]
        elif m["lang"] == "python":
            code.append(m["code"])
    return code, files


@pytest.mark.parametrize("page", [p for p in PAGES if _blocks(p)[0]], ids=lambda p: p.name)
def test_python_blocks_run(page, tmp_path):
    code, files = _blocks(page)
    for name in LINKED:
        (tmp_path / name).symlink_to(ROOT / name)
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    runner = RUNNER.format(blocks=code, expected=[_stated_outputs(c) for c in code], page=page.name)
    p = subprocess.run([sys.executable, "-c", runner], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, f"{page.name}:\n{p.stderr[-4000:]}"
