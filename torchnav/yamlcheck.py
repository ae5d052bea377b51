"""Strict YAML input for maps and tracks: a bounded safe loader and value checks that name the key.

Map and track files are user input: a typo silently ignored builds another world
than the one written, and a hostile file must not hang the loader. So

* :func:`load_yaml` uses a ``SafeLoader`` that refuses duplicate keys, reads ``1e-3``
  as a float (YAML 1.1 would read a string), and bounds the document: at most
  :data:`MAX_ALIASES` alias references, :data:`MAX_DEPTH` levels of nesting and
  :data:`MAX_NODES` values once every alias is expanded (a "billion laughs" file
  expands exponentially through a few dozen aliases), all counted while composing,
  before anything is expanded;
* the ``check_*`` helpers validate one value each and raise the caller's error type
  with the file and the dotted key path (``maps/foo.yaml: boxes[2].size: ...``).
"""

from __future__ import annotations

import difflib
import math
import os
import re
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

MAX_ALIASES = 100  # alias references (*name) per document
MAX_DEPTH = 32  # nesting levels of mappings and sequences
MAX_NODES = 2_000_000  # values of the document with every alias expanded


class YamlLimitError(yaml.YAMLError):
    def __init__(self, problem: str, mark: Any):
        super().__init__(problem)
        self.problem, self.problem_mark = problem, mark


class _DuplicateKey(yaml.YAMLError):
    def __init__(self, key: Any, mark: Any):
        super().__init__(f"duplicate key {key!r}")
        self.key, self.mark = key, mark


class _UniqueKeys:
    """Refuses a mapping that repeats a key (PyYAML keeps the last one silently)."""

    def construct_mapping(self, node, deep=False):  # noqa: ANN001
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                if key in seen:
                    raise _DuplicateKey(key, key_node.start_mark)
                seen.add(key)
            except TypeError:  # unhashable key: let SafeLoader raise its own error below
                break
        return super().construct_mapping(node, deep=deep)


class Loader(_UniqueKeys, yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys, reads ``1e-3`` as a float and bounds aliases and depth."""

    def __init__(self, stream: Any):
        super().__init__(stream)
        self._aliases = 0
        self._depth = 0
        self._sizes: dict[int, int] = {}  # id(node) -> values under it with aliases expanded

    def compose_node(self, parent, index):  # noqa: ANN001 - PyYAML's signature
        mark = self.peek_event().start_mark
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_ALIASES:
                raise YamlLimitError(f"more than {MAX_ALIASES} alias references (*name)", mark)
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                raise YamlLimitError(f"nested deeper than {MAX_DEPTH} levels", mark)
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        size = self._sizes.get(id(node))
        if size is None:
            get = lambda n: self._sizes.get(id(n), 1)  # noqa: E731
            if isinstance(node, yaml.SequenceNode):
                size = 1 + sum(get(c) for c in node.value)
            elif isinstance(node, yaml.MappingNode):
                size = 1 + sum(get(k) + get(v) for k, v in node.value)
            else:
                size = 1
            self._sizes[id(node)] = size
        if size > MAX_NODES:
            raise YamlLimitError(f"expands to more than {MAX_NODES:,} values through its aliases", mark)
        return node


Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


class _FastLoader(_UniqueKeys, getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
    """:class:`Loader`'s rules on libyaml's parser, for documents without anchors or aliases (so no
    alias limit applies; the depth is checked after): a map of 10,000 rows parses in a second, not
    half a minute."""


_FastLoader.yaml_implicit_resolvers = Loader.yaml_implicit_resolvers


def _depth(x: Any, limit: int) -> int:
    """Nesting depth of lists and dicts in ``x``, counted up to ``limit + 1``."""
    if limit < 0 or not isinstance(x, (list, dict)):
        return 0
    items = x.values() if isinstance(x, dict) else x
    return 1 + max((_depth(v, limit - 1) for v in items), default=0)


def _parse(text: str) -> Any:
    if "&" not in text and "*" not in text:
        data = yaml.load(text, Loader=_FastLoader)  # noqa: S506 - a SafeLoader
        if _depth(data, MAX_DEPTH) <= MAX_DEPTH:
            return data
    return yaml.load(text, Loader=Loader)  # noqa: S506 - Loader is a SafeLoader (its errors name the line)


def load_yaml(text: str, source: str, error: type[Exception]) -> Any:
    """Parse ``text`` with :class:`Loader`; any problem raises ``error`` naming ``source`` and the line."""
    try:
        return _parse(text)
    except _DuplicateKey as e:
        raise error(f"{source}: {e.key}: duplicate key at line {e.mark.line + 1}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        kind = "YAML limit exceeded" if isinstance(e, YamlLimitError) else "YAML syntax error"
        raise error(f"{source}: {kind}{where}: {getattr(e, 'problem', None) or e}") from None
    except RecursionError:
        raise error(f"{source}: YAML nested too deeply") from None


class Ctx:
    """Carries the file name and the error type, so that every error names the file."""

    def __init__(self, source: str, error: type[Exception]):
        self.source, self.error = source, error

    def fail(self, key: str, msg: str) -> Exception:
        return self.error(f"{self.source}: {key}: {msg}" if key else f"{self.source}: {msg}")


def show(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 60 else s[:57] + "..."


def is_number(v: Any) -> bool:
    # bool is an int subclass in python; `size: [true, 1]` is a typo, not a number.
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def check_mapping(ctx: Ctx, v: Any, key: str, required: tuple[str, ...], optional: tuple[str, ...]) -> dict:
    if not isinstance(v, dict):
        raise ctx.fail(key, f"expected a mapping with keys {', '.join(required + optional)}, got {show(v)}")
    allowed = required + optional
    for k in v:
        if k not in allowed:
            where = f"{key}.{k}" if key else str(k)
            close = difflib.get_close_matches(str(k), allowed, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ctx.fail(where, f"unknown key{hint}; allowed keys are {', '.join(allowed)}")
    for k in required:
        if k not in v:
            raise ctx.fail(f"{key}.{k}" if key else k, "required key is missing")
    return v


def check_number(ctx: Ctx, v: Any, key: str, lo: str = "") -> float:
    """A finite number; ``lo`` is "" (any), "nonneg" (>= 0) or "pos" (> 0)."""
    kind = {"": "a number", "nonneg": "a number >= 0", "pos": "a positive number"}[lo]
    if not is_number(v) or (lo == "nonneg" and v < 0) or (lo == "pos" and v <= 0):
        raise ctx.fail(key, f"expected {kind}, got {show(v)}")
    return float(v)


def check_vector(ctx: Ctx, v: Any, key: str, n: int, lo: str = "") -> tuple[float, ...]:
    kind = {"": "numbers", "nonneg": "numbers >= 0", "pos": "positive numbers"}[lo]
    ok = isinstance(v, list) and len(v) == n and all(is_number(x) for x in v)
    if ok and lo:
        ok = all(x > 0 if lo == "pos" else x >= 0 for x in v)
    if not ok:
        raise ctx.fail(key, f"expected {n} {kind}, got {show(v)}")
    return tuple(float(x) for x in v)


def check_range(ctx: Ctx, v: Any, key: str, lo: str = "") -> tuple[float, float]:
    a, b = check_vector(ctx, v, key, 2, lo)
    if a > b:
        raise ctx.fail(key, f"expected [min, max] with min <= max, got {show(v)}")
    return (a, b)


def check_count(ctx: Ctx, v: Any, key: str, most: int | None = None) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or v < 0 or (most is not None and v > most):
        raise ctx.fail(key, f"expected an integer in [0, {most:,}], got {show(v)}" if most is not None else f"expected an integer >= 0, got {show(v)}")
    return v


def check_bool(ctx: Ctx, v: Any, key: str) -> bool:
    if not isinstance(v, bool):
        raise ctx.fail(key, f"expected true or false, got {show(v)}")
    return v


def check_grey_level(ctx: Ctx, v: Any, key: str) -> float:
    if not is_number(v) or not 0 < v < 1:
        raise ctx.fail(key, f"expected a grey level in (0, 1), got {show(v)}")
    return float(v)


def check_image(ctx: Ctx, v: Any, key: str, base_dir: Any) -> Path:
    """The path of a PNG image given as a string, relative to ``base_dir`` (the file's folder; None: the current one)."""
    if not isinstance(v, str) or not v:
        raise ctx.fail(key, f"expected a path to a PNG file, got {show(v)}")
    return Path(v) if base_dir is None or os.path.isabs(v) else Path(base_dir) / v


def check_list(ctx: Ctx, v: Any, key: str, expected: str, item: Any) -> tuple:
    """``item(f"{key}[{i}]", entry)`` of every entry of the list ``v``; anything but a list fails naming ``key`` and ``expected``."""
    if not isinstance(v, list):
        raise ctx.fail(key, f"expected {expected}, got {show(v)}")
    return tuple(item(f"{key}[{i}]", x) for i, x in enumerate(v))


def shipped_folder(package: str) -> Any:
    """A package's ``data`` folder, through ``importlib.resources`` (not ``__file__``) so that shipped files
    are found inside a wheel or zip too."""
    return resources.files(package).joinpath("data")


def load_named(name_or_path: Any, package: str, kind: str, error: type[Exception], parse: Any) -> Any:
    """``parse(data, source, default name, folder for relative paths)`` of the shipped ``kind`` file of
    ``package``'s data folder by name, or of any file by path (:func:`read_named`, :func:`load_yaml`)."""
    text, source, name, base_dir = read_named(name_or_path, shipped_folder(package), kind, error)
    return parse(load_yaml(text, source, error), source, name, base_dir)


def shipped_names(folder: Any) -> list[str]:
    """Stems of the ``*.yaml`` files of a package data folder (an ``importlib.resources`` traversable)."""
    return sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def read_named(name_or_path: Any, shipped: Any, kind: str, error: type[Exception]) -> tuple[str, str, str, Any]:
    """The text of a shipped ``kind`` file by name (``"arena"``) or of any file by path: ``(text,
    source, default name, folder for relative paths)``. A string is a path when it contains a path
    separator or ends in ``.yaml``/``.yml``. A missing or unreadable file raises ``error``."""
    s = str(name_or_path)
    if isinstance(name_or_path, os.PathLike) or "/" in s or os.sep in s or s.endswith((".yaml", ".yml")):
        path = Path(name_or_path)
        try:
            return path.read_text(encoding="utf-8"), s, path.stem, path.parent
        except FileNotFoundError:
            raise error(f"{s}: {kind} file not found") from None
        except (OSError, UnicodeDecodeError) as e:
            raise error(f"{s}: cannot read {kind} file: {e}") from None
    if not isinstance(name_or_path, str):
        raise error(f"load_{kind} expects a {kind} name or a path, got {show(name_or_path)}")
    res = shipped.joinpath(s + ".yaml")
    if not res.is_file():
        raise error(f"unknown {kind} {s!r}; available {kind}s: {', '.join(shipped_names(shipped))} (or pass a path to a .yaml file)")
    return res.read_text(encoding="utf-8"), str(res), s, shipped
