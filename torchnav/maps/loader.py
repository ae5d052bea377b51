"""YAML map files -> :class:`~torchnav.maps.spec.MapSpec`.

A map file describes one static world (walls, polygon outlines, fixed circles
and boxes, an occupancy image) plus how many objects the task should re-place at
random on every reset. The schema is documented key by key in ``docs/maps.md``.
Parsing is strict: an unknown key, a wrong type or an obstacle outside the world
raises :class:`MapError` naming the file and the key path
(``maps/foo.yaml: boxes[2].size: ...``), because a typo that is silently ignored
produces a different world than the one the user wrote.
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

from .occupancy import ImageError, mask_boxes, read_mask
from .spec import MapError, MapSpec, RandomBoxes, RandomCircles

# Obstacles may touch the world edge; allow for decimal round-off in the file.
_TOL = 1e-6


# --------------------------------------------------------------------------- YAML


class _DuplicateKey(yaml.YAMLError):
    def __init__(self, key: Any, mark: Any):
        super().__init__(f"duplicate key {key!r}")
        self.key, self.mark = key, mark


class _Loader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys and reads ``1e-3`` as a float.

    PyYAML follows YAML 1.1, where a float needs a dot (``1e-3`` would be the
    string "1e-3") and a repeated key silently overwrites the first one.
    """

    def construct_mapping(self, node, deep=False):
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


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


class _Ctx:
    """Carries the file name so that every error can name it."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, key: str, msg: str) -> MapError:
        return MapError(f"{self.source}: {key}: {msg}" if key else f"{self.source}: {msg}")


def _show(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 60 else s[:57] + "..."


def _is_number(v: Any) -> bool:
    # bool is an int subclass in python; `size: [true, 1]` is a typo, not a number.
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _mapping(ctx: _Ctx, v: Any, key: str, required: tuple[str, ...], optional: tuple[str, ...]) -> dict:
    if not isinstance(v, dict):
        raise ctx.fail(key, f"expected a mapping with keys {', '.join(required + optional)}, got {_show(v)}")
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


def _number(ctx: _Ctx, v: Any, key: str, lo: str = "") -> float:
    """A finite number; ``lo`` is "" (any), "nonneg" (>= 0) or "pos" (> 0)."""
    kind = {"": "a number", "nonneg": "a number >= 0", "pos": "a positive number"}[lo]
    if not _is_number(v) or (lo == "nonneg" and v < 0) or (lo == "pos" and v <= 0):
        raise ctx.fail(key, f"expected {kind}, got {_show(v)}")
    return float(v)


def _vector(ctx: _Ctx, v: Any, key: str, n: int, lo: str = "") -> tuple[float, ...]:
    kind = {"": "numbers", "nonneg": "numbers >= 0", "pos": "positive numbers"}[lo]
    ok = isinstance(v, list) and len(v) == n and all(_is_number(x) for x in v)
    if ok and lo:
        ok = all(x > 0 if lo == "pos" else x >= 0 for x in v)
    if not ok:
        raise ctx.fail(key, f"expected {n} {kind}, got {_show(v)}")
    return tuple(float(x) for x in v)


def _range(ctx: _Ctx, v: Any, key: str, lo: str = "") -> tuple[float, float]:
    a, b = _vector(ctx, v, key, 2, lo)
    if a > b:
        raise ctx.fail(key, f"expected [min, max] with min <= max, got {_show(v)}")
    return (a, b)


def _count(ctx: _Ctx, v: Any, key: str) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or v < 0:
        raise ctx.fail(key, f"expected an integer >= 0, got {_show(v)}")
    return v


def _bool(ctx: _Ctx, v: Any, key: str) -> bool:
    if not isinstance(v, bool):
        raise ctx.fail(key, f"expected true or false, got {_show(v)}")
    return v


def _grey_level(ctx: _Ctx, v: Any, key: str) -> float:
    if not _is_number(v) or not 0 < v < 1:
        raise ctx.fail(key, f"expected a grey level in (0, 1), got {_show(v)}")
    return float(v)


def _inside(ctx: _Ctx, key: str, what: str, xs: list[float], ys: list[float], size: tuple[float, float]) -> None:
    hw, hh = size[0] / 2 + _TOL, size[1] / 2 + _TOL
    for x, y in zip(xs, ys):
        if abs(x) > hw or abs(y) > hh:
            raise ctx.fail(
                key,
                f"{what} ({x:.4g}, {y:.4g}) lies outside the world x in [{-size[0] / 2:g}, {size[0] / 2:g}], "
                f"y in [{-size[1] / 2:g}, {size[1] / 2:g}] m",
            )


def _walls(ctx: _Ctx, v: Any, size: tuple[float, float]) -> tuple:
    if v == "boundary":
        v = ["boundary"]
    if not isinstance(v, list):
        raise ctx.fail("walls", f"expected 'boundary' or a list of walls, got {_show(v)}")
    hw, hh = size[0] / 2, size[1] / 2
    segments: list[tuple[float, float, float, float]] = []
    has_boundary = False
    for i, w in enumerate(v):
        key = f"walls[{i}]"
        if isinstance(w, str):
            if w != "boundary":
                raise ctx.fail(key, f"expected 'boundary' or [x1, y1, x2, y2], got {_show(w)}")
            if has_boundary:
                raise ctx.fail(key, "'boundary' is listed twice")
            has_boundary = True
            # Counter-clockwise around the world: bottom, right, top, left.
            segments += [(-hw, -hh, hw, -hh), (hw, -hh, hw, hh), (hw, hh, -hw, hh), (-hw, hh, -hw, -hh)]
            continue
        seg = _vector(ctx, w, key, 4)
        if seg[0] == seg[2] and seg[1] == seg[3]:
            raise ctx.fail(key, f"wall has zero length: {_show(w)}")
        _inside(ctx, key, "an endpoint", [seg[0], seg[2]], [seg[1], seg[3]], size)
        segments.append(seg)
    return tuple(segments)


def _circles(ctx: _Ctx, v: Any, size: tuple[float, float]) -> tuple:
    if not isinstance(v, list):
        raise ctx.fail("circles", f"expected a list of {{center, radius}} or [cx, cy, r], got {_show(v)}")
    out = []
    for i, c in enumerate(v):
        key = f"circles[{i}]"
        if isinstance(c, list):  # the compact row form, for maps with hundreds of circles
            cx, cy, r = _vector(ctx, c, key, 3)
            if r <= 0:
                raise ctx.fail(key, f"expected [cx, cy, r] with a positive radius r, got {_show(c)}")
        elif isinstance(c, dict):
            c = _mapping(ctx, c, key, ("center", "radius"), ())
            cx, cy = _vector(ctx, c["center"], f"{key}.center", 2)
            r = _number(ctx, c["radius"], f"{key}.radius", "pos")
        else:
            raise ctx.fail(key, f"expected {{center, radius}} or [cx, cy, r], got {_show(c)}")
        _inside(ctx, key, "the circle's edge point", [cx - r, cx + r, cx, cx], [cy, cy, cy - r, cy + r], size)
        out.append((cx, cy, r))
    return tuple(out)


def _boxes(ctx: _Ctx, v: Any, size: tuple[float, float]) -> tuple:
    if not isinstance(v, list):
        raise ctx.fail("boxes", f"expected a list of {{center, size, yaw}}, got {_show(v)}")
    out = []
    for i, b in enumerate(v):
        key = f"boxes[{i}]"
        b = _mapping(ctx, b, key, ("center", "size"), ("yaw",))
        cx, cy = _vector(ctx, b["center"], f"{key}.center", 2)
        sx, sy = _vector(ctx, b["size"], f"{key}.size", 2, "pos")
        yaw = _number(ctx, b.get("yaw", 0.0), f"{key}.yaw")
        c, s = math.cos(yaw), math.sin(yaw)
        corners = [(cx + c * dx - s * dy, cy + s * dx + c * dy) for dx in (-sx / 2, sx / 2) for dy in (-sy / 2, sy / 2)]
        _inside(ctx, key, "a corner of the box", [p[0] for p in corners], [p[1] for p in corners], size)
        out.append((cx, cy, sx / 2, sy / 2, yaw))
    return tuple(out)


def _polygons(ctx: _Ctx, v: Any, size: tuple[float, float]) -> tuple:
    """Walls along each outline: ``[[x, y], ...]`` (closed) or ``{points, closed}``."""
    if not isinstance(v, list):
        raise ctx.fail("polygons", f"expected a list of outlines [[x, y], ...] or {{points, closed}}, got {_show(v)}")
    segments: list[tuple[float, float, float, float]] = []
    for i, p in enumerate(v):
        key, closed = f"polygons[{i}]", True
        if isinstance(p, dict):
            p = _mapping(ctx, p, key, ("points",), ("closed",))
            closed = _bool(ctx, p.get("closed", True), f"{key}.closed")
            key, p = f"{key}.points", p["points"]
        need = 3 if closed else 2
        if not isinstance(p, list) or len(p) < need:
            raise ctx.fail(key, f"expected a list of at least {need} [x, y] vertices, got {_show(p)}")
        pts = [_vector(ctx, q, f"{key}[{j}]", 2) for j, q in enumerate(p)]
        for j, (x, y) in enumerate(pts):
            _inside(ctx, f"{key}[{j}]", "the vertex", [x], [y], size)
        n = len(pts)
        for j in range(n if closed else n - 1):
            a, b = pts[j], pts[(j + 1) % n]
            if a == b:
                again = " (a closed outline must not repeat its first vertex at the end)" if j == n - 1 else ""
                raise ctx.fail(key, f"edge from vertex {j} to vertex {(j + 1) % n} has zero length at ({a[0]:g}, {a[1]:g}){again}")
            segments.append((*a, *b))
    return tuple(segments)


def _occupancy(ctx: _Ctx, v: Any, size: tuple[float, float], base_dir: str | os.PathLike | None) -> tuple:
    """Boxes covering exactly the occupied pixels of the ``occupancy`` image (see :mod:`.occupancy`)."""
    k = "occupancy"
    v = _mapping(ctx, v, k, ("image", "resolution"), ("origin", "threshold", "invert"))
    img = v["image"]
    if not isinstance(img, str) or not img:
        raise ctx.fail(f"{k}.image", f"expected a path to a PNG file, got {_show(img)}")
    res = _number(ctx, v["resolution"], f"{k}.resolution", "pos")
    thr = _grey_level(ctx, v.get("threshold", 0.5), f"{k}.threshold")
    invert = _bool(ctx, v.get("invert", False), f"{k}.invert")
    path = Path(img) if base_dir is None or os.path.isabs(img) else Path(base_dir) / img
    try:
        # Dark pixels are occupied (black on white, as drawn and as ROS map_server images), light ones with invert.
        mask = read_mask(path, thr, invert=not invert)
    except ImageError as e:
        raise ctx.fail(f"{k}.image", str(e)) from None
    h, w = mask.shape
    origin = _vector(ctx, v["origin"], f"{k}.origin", 2) if "origin" in v else (-w * res / 2, -h * res / 2)
    if not mask.any():
        side = "above" if invert else "below"
        raise ctx.fail(f"{k}.image", f"{path}: no pixel has a grey level {side} the threshold {thr:g}; check threshold and invert")
    boxes = mask_boxes(mask, res, origin)
    lo, hi = boxes[:, :2] - boxes[:, 2:4], boxes[:, :2] + boxes[:, 2:4]
    _inside(ctx, k, "a corner of an occupied pixel", [*lo[:, 0], *hi[:, 0]], [*lo[:, 1], *hi[:, 1]], size)
    return tuple(tuple(b) for b in boxes.tolist())


def _fits(ctx: _Ctx, key: str, extent: float, size: tuple[float, float]) -> None:
    # The reset sampler cannot place an object wider than the world; say so now, not at reset.
    if extent > min(size):
        raise ctx.fail(key, f"maximum {extent:g} m does not fit in a {size[0]:g} x {size[1]:g} m world")


def _random_boxes(ctx: _Ctx, v: Any, size: tuple[float, float]) -> RandomBoxes:
    k = "random_boxes"
    v = _mapping(ctx, v, k, ("count", "size_x", "size_y"), ("yaw", "clearance", "margin"))
    d = RandomBoxes.__dataclass_fields__
    rb = RandomBoxes(
        count=_count(ctx, v["count"], f"{k}.count"),
        size_x=_range(ctx, v["size_x"], f"{k}.size_x", "pos"),
        size_y=_range(ctx, v["size_y"], f"{k}.size_y", "pos"),
        yaw=_range(ctx, v.get("yaw", list(d["yaw"].default)), f"{k}.yaw"),
        clearance=_number(ctx, v.get("clearance", d["clearance"].default), f"{k}.clearance", "nonneg"),
        margin=_number(ctx, v.get("margin", d["margin"].default), f"{k}.margin", "nonneg"),
    )
    _fits(ctx, f"{k}.size_x", rb.size_x[1], size)
    _fits(ctx, f"{k}.size_y", rb.size_y[1], size)
    return rb


def _random_circles(ctx: _Ctx, v: Any, size: tuple[float, float]) -> RandomCircles:
    k = "random_circles"
    v = _mapping(ctx, v, k, ("count", "radius"), ("clearance", "margin"))
    d = RandomCircles.__dataclass_fields__
    rc = RandomCircles(
        count=_count(ctx, v["count"], f"{k}.count"),
        radius=_range(ctx, v["radius"], f"{k}.radius", "pos"),
        clearance=_number(ctx, v.get("clearance", d["clearance"].default), f"{k}.clearance", "nonneg"),
        margin=_number(ctx, v.get("margin", d["margin"].default), f"{k}.margin", "nonneg"),
    )
    _fits(ctx, f"{k}.radius", 2 * rc.radius[1], size)
    return rc


_TOP_KEYS = ("name", "size", "walls", "polygons", "circles", "boxes", "occupancy", "random_boxes", "random_circles")


def parse_map(
    data: Any, source: str = "<dict>", default_name: str = "map", base_dir: str | os.PathLike | None = None
) -> MapSpec:
    """Validate an already-parsed map (the dict a YAML file loads to) into a :class:`MapSpec`.

    ``source`` is only used in error messages and :attr:`MapSpec.source`. ``base_dir``
    resolves a relative ``occupancy.image`` path (``load_map`` passes the file's folder;
    None: the current directory). Segments are the ``walls`` followed by the ``polygons``
    edges; boxes are the ``boxes`` followed by the ``occupancy`` boxes.
    """
    ctx = _Ctx(source)
    if data is None:
        raise ctx.fail("", "the map file is empty; it needs at least `size: [w, h]`")
    d = _mapping(ctx, data, "", (), _TOP_KEYS)
    if "size" not in d:
        raise ctx.fail("size", "required key is missing")
    name = d.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise ctx.fail("name", f"expected a non-empty string, got {_show(name)}")
    size = _vector(ctx, d["size"], "size", 2, "pos")
    return MapSpec(
        name=name,
        source=source,
        size=size,
        segments=(_walls(ctx, d["walls"], size) if "walls" in d else ())
        + (_polygons(ctx, d["polygons"], size) if "polygons" in d else ()),
        circles=_circles(ctx, d["circles"], size) if "circles" in d else (),
        boxes=(_boxes(ctx, d["boxes"], size) if "boxes" in d else ())
        + (_occupancy(ctx, d["occupancy"], size, base_dir) if "occupancy" in d else ()),
        random_boxes=_random_boxes(ctx, d["random_boxes"], size) if "random_boxes" in d else None,
        random_circles=_random_circles(ctx, d["random_circles"], size) if "random_circles" in d else None,
    )


def _parse_text(text: str, source: str, default_name: str, base_dir: str | os.PathLike) -> MapSpec:
    try:
        data = yaml.load(text, Loader=_Loader)  # noqa: S506 - _Loader is a SafeLoader
    except _DuplicateKey as e:
        raise MapError(f"{source}: {e.key}: duplicate key at line {e.mark.line + 1}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e)
        raise MapError(f"{source}: YAML syntax error{where}: {problem}") from None
    return parse_map(data, source, default_name, base_dir)


# --------------------------------------------------------------------------- lookup


def _data_dir():
    # importlib.resources, not __file__, so that shipped maps are found inside a wheel or zip too.
    return resources.files(__package__).joinpath("data")


def available_maps() -> list[str]:
    """Names of the maps shipped with torchnav (the stems of ``torchnav/maps/data/*.yaml``)."""
    return sorted(p.name[: -len(".yaml")] for p in _data_dir().iterdir() if p.name.endswith(".yaml"))


def _looks_like_path(s: str) -> bool:
    return "/" in s or os.sep in s or s.endswith((".yaml", ".yml"))


def load_map(name_or_path: str | os.PathLike) -> MapSpec:
    """Load a shipped map by name (``"arena"``) or a map file by path (``"my_maps/lab.yaml"``).

    A string counts as a path when it contains a path separator or ends in
    ``.yaml``/``.yml``; anything else is looked up among :func:`available_maps`.
    """
    if isinstance(name_or_path, os.PathLike) or _looks_like_path(str(name_or_path)):
        path = Path(name_or_path)
        source = str(name_or_path)
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise MapError(f"{source}: map file not found") from None
        except (OSError, UnicodeDecodeError) as e:
            raise MapError(f"{source}: cannot read map file: {e}") from None
        return _parse_text(text, source, path.stem, path.parent)
    if not isinstance(name_or_path, str):
        raise MapError(f"load_map expects a map name or a path, got {_show(name_or_path)}")
    res = _data_dir().joinpath(name_or_path + ".yaml")
    if not res.is_file():
        raise MapError(
            f"unknown map {name_or_path!r}; available maps: {', '.join(available_maps())} "
            "(or pass a path to a .yaml file)"
        )
    return _parse_text(res.read_text(encoding="utf-8"), str(res), name_or_path, _data_dir())
