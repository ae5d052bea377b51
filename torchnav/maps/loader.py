"""YAML map files -> :class:`~torchnav.maps.spec.MapSpec`.

A map file describes one static world (walls, polygon outlines, fixed circles
and boxes, an occupancy image, a ROS map_server map) plus how many objects the task should
re-place at random on every reset. The schema is documented key by key in ``docs/maps.md``.
A ROS map_server YAML (``image`` and no ``size``) loads as it is (:mod:`.map_server`).
Parsing is strict: an unknown key, a wrong type or an obstacle outside the world
raises :class:`MapError` naming the file and the key path
(``maps/foo.yaml: boxes[2].size: ...``), because a typo that is silently ignored
produces a different world than the one the user wrote.
"""

from __future__ import annotations

import math
import os
from typing import Any

from ..yamlcheck import (Ctx, check_bool, check_count, check_grey_level, check_image, check_list, check_mapping, check_number, check_range, check_vector, load_named,
                         load_yaml, read_named, shipped_folder, shipped_names, show)
from . import map_server as ms
from .occupancy import ImageError, mask_boxes, read_mask
from ..sim.camera import ObstacleStyles
from ..sim.params import is_rgb
from .spec import MOTIONS, MapError, MapSpec, RandomBoxes, RandomCircles, RandomMovers

# Obstacles may touch the world edge; allow for decimal round-off in the file.
_TOL = 1e-6
MAX_SIZE = 10_000.0  # m per side
# Random boxes and circles (and, separately, movers) re-placed per reset. The reset places them one
# after another, each tested against all placed before it over every env and candidate: the work
# grows with the square of the count, so 64 keeps a 64-env reset within seconds where 10,000
# would run for hours.
MAX_RANDOM = 64
MAX_FIXED = 100_000  # fixed obstacles of one map (walls, polygon edges, circles, boxes)


# --------------------------------------------------------------------------- checks


def _inside(ctx: Ctx, key: str, what: str, xs: list[float], ys: list[float], size: tuple[float, float]) -> None:
    hw, hh = size[0] / 2 + _TOL, size[1] / 2 + _TOL
    for x, y in zip(xs, ys):
        if abs(x) > hw or abs(y) > hh:
            raise ctx.fail(
                key,
                f"{what} ({x:.4g}, {y:.4g}) lies outside the world x in [{-size[0] / 2:g}, {size[0] / 2:g}], "
                f"y in [{-size[1] / 2:g}, {size[1] / 2:g}] m",
            )


def _boundary(size: tuple[float, float]) -> tuple:
    """The world's four edges as walls, counter-clockwise: bottom, right, top, left."""
    hw, hh = size[0] / 2, size[1] / 2
    return ((-hw, -hh, hw, -hh), (hw, -hh, hw, hh), (hw, hh, -hw, hh), (-hw, hh, -hw, -hh))


def _walls(ctx: Ctx, v: Any, size: tuple[float, float], boundary: bool = False) -> tuple:
    """The ``walls`` segments; ``boundary``: the world's edges are walls already (``map_server.boundary``)."""
    if v == "boundary":
        v = ["boundary"]
    if not isinstance(v, list):
        raise ctx.fail("walls", f"expected 'boundary' or a list of walls, got {show(v)}")
    segments: list[tuple[float, float, float, float]] = []
    has_boundary = False
    for i, w in enumerate(v):
        key = f"walls[{i}]"
        if isinstance(w, str):
            if w != "boundary":
                raise ctx.fail(key, f"expected 'boundary' or [x1, y1, x2, y2], got {show(w)}")
            if has_boundary:
                raise ctx.fail(key, "'boundary' is listed twice")
            if boundary:
                raise ctx.fail(key, "map_server.boundary (true by default) makes the world's edges walls already; list 'boundary' once")
            has_boundary = True
            segments += _boundary(size)
            continue
        seg = check_vector(ctx, w, key, 4)
        if seg[0] == seg[2] and seg[1] == seg[3]:
            raise ctx.fail(key, f"wall has zero length: {show(w)}")
        _inside(ctx, key, "an endpoint", [seg[0], seg[2]], [seg[1], seg[3]], size)
        segments.append(seg)
    return tuple(segments)


_STYLE_KEYS = ("height", "color")  # a fixed circle's or box's own camera height and colour


def _style(ctx: Ctx, d: dict, key: str) -> tuple:
    """``(height m or None, (r, g, b) or None)`` from an obstacle's optional ``height`` and ``color``."""
    height = check_number(ctx, d["height"], f"{key}.height", "pos") if "height" in d else None
    color = None
    if "color" in d:
        c = d["color"]
        if not (isinstance(c, list) and is_rgb(c)):
            raise ctx.fail(f"{key}.color", f"expected [r, g, b] with integers in [0, 255], got {show(c)}")
        color = tuple(c)
    return (height, color)


def _split(rows: tuple) -> tuple[tuple, tuple]:
    """``((geometry, style), ...)`` -> ``((geometry, ...), (style, ...))``."""
    return tuple(r[0] for r in rows), tuple(r[1] for r in rows)


def _circles(ctx: Ctx, v: Any, size: tuple[float, float]) -> tuple[tuple, tuple]:
    """The circles ``(cx, cy, r)`` and their camera styles."""
    def circle(key: str, c: Any) -> tuple:
        style = (None, None)
        if isinstance(c, list):  # the compact row form, for maps with hundreds of circles
            cx, cy, r = check_vector(ctx, c, key, 3)
            if r <= 0:
                raise ctx.fail(key, f"expected [cx, cy, r] with a positive radius r, got {show(c)}")
        elif isinstance(c, dict):
            c = check_mapping(ctx, c, key, ("center", "radius"), _STYLE_KEYS)
            cx, cy = check_vector(ctx, c["center"], f"{key}.center", 2)
            r = check_number(ctx, c["radius"], f"{key}.radius", "pos")
            style = _style(ctx, c, key)
        else:
            raise ctx.fail(key, f"expected {{center, radius}} or [cx, cy, r], got {show(c)}")
        _inside(ctx, key, "the circle's edge point", [cx - r, cx + r, cx, cx], [cy, cy, cy - r, cy + r], size)
        return ((cx, cy, r), style)

    return _split(check_list(ctx, v, "circles", "a list of {center, radius} or [cx, cy, r]", circle))


def _boxes(ctx: Ctx, v: Any, size: tuple[float, float]) -> tuple[tuple, tuple]:
    """The boxes ``(cx, cy, half_x, half_y, yaw)`` and their camera styles."""
    def box(key: str, b: Any) -> tuple:
        b = check_mapping(ctx, b, key, ("center", "size"), ("yaw", *_STYLE_KEYS))
        cx, cy = check_vector(ctx, b["center"], f"{key}.center", 2)
        sx, sy = check_vector(ctx, b["size"], f"{key}.size", 2, "pos")
        yaw = check_number(ctx, b.get("yaw", 0.0), f"{key}.yaw")
        c, s = math.cos(yaw), math.sin(yaw)
        corners = [(cx + c * dx - s * dy, cy + s * dx + c * dy) for dx in (-sx / 2, sx / 2) for dy in (-sy / 2, sy / 2)]
        _inside(ctx, key, "a corner of the box", [p[0] for p in corners], [p[1] for p in corners], size)
        return ((cx, cy, sx / 2, sy / 2, yaw), _style(ctx, b, key))

    return _split(check_list(ctx, v, "boxes", "a list of {center, size, yaw}", box))


def _polygons(ctx: Ctx, v: Any, size: tuple[float, float]) -> tuple:
    """Walls along each outline: ``[[x, y], ...]`` (closed) or ``{points, closed}``."""
    if not isinstance(v, list):
        raise ctx.fail("polygons", f"expected a list of outlines [[x, y], ...] or {{points, closed}}, got {show(v)}")
    segments: list[tuple[float, float, float, float]] = []
    for i, p in enumerate(v):
        key, closed = f"polygons[{i}]", True
        if isinstance(p, dict):
            p = check_mapping(ctx, p, key, ("points",), ("closed",))
            closed = check_bool(ctx, p.get("closed", True), f"{key}.closed")
            key, p = f"{key}.points", p["points"]
        need = 3 if closed else 2
        if not isinstance(p, list) or len(p) < need:
            raise ctx.fail(key, f"expected a list of at least {need} [x, y] vertices, got {show(p)}")
        pts = [check_vector(ctx, q, f"{key}[{j}]", 2) for j, q in enumerate(p)]
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


def _occupancy(ctx: Ctx, v: Any, size: tuple[float, float], base_dir: str | os.PathLike | None) -> tuple:
    """Boxes covering exactly the occupied pixels of the ``occupancy`` image (see :mod:`.occupancy`)."""
    k = "occupancy"
    v = check_mapping(ctx, v, k, ("image", "resolution"), ("origin", "threshold", "invert"))
    path = check_image(ctx, v["image"], f"{k}.image", base_dir)
    res = check_number(ctx, v["resolution"], f"{k}.resolution", "pos")
    thr = check_grey_level(ctx, v.get("threshold", 0.5), f"{k}.threshold")
    invert = check_bool(ctx, v.get("invert", False), f"{k}.invert")
    try:
        # Dark pixels are occupied (black on white, as drawn and as ROS map_server images), light ones with invert.
        mask = read_mask(path, thr, invert=not invert)
    except ImageError as e:
        raise ctx.fail(f"{k}.image", str(e)) from None
    h, w = mask.shape
    origin = check_vector(ctx, v["origin"], f"{k}.origin", 2) if "origin" in v else (-w * res / 2, -h * res / 2)
    if not mask.any():
        side = "above" if invert else "below"
        raise ctx.fail(f"{k}.image", f"{path}: no pixel has a grey level {side} the threshold {thr:g}; check threshold and invert")
    boxes = mask_boxes(mask, res, origin)
    lo, hi = boxes[:, :2] - boxes[:, 2:4], boxes[:, :2] + boxes[:, 2:4]
    _inside(ctx, k, "a corner of an occupied pixel", [*lo[:, 0], *hi[:, 0]], [*lo[:, 1], *hi[:, 1]], size)
    return tuple(tuple(b) for b in boxes.tolist())


def _fits(ctx: Ctx, key: str, extent: float, margin: float, size: tuple[float, float], what: str) -> None:
    # The reset sampler places an object by its circumscribed circle, keeping `margin` from the world's edge: one
    # whose circle and margins span the world never finds a place (it would be left out of every episode); say so now.
    if extent + 2 * margin >= min(size):
        raise ctx.fail(key, f"the largest {what}, {extent:.3g} m across (the circle the reset sampler places it by) plus "
                            f"its margin {margin:g} m on each side, does not fit in a {size[0]:g} x {size[1]:g} m world")


def _random_boxes(ctx: Ctx, v: Any, size: tuple[float, float]) -> RandomBoxes:
    k = "random_boxes"
    v = check_mapping(ctx, v, k, ("count", "size_x", "size_y"), ("yaw", "clearance", "margin"))
    d = RandomBoxes.__dataclass_fields__
    rb = RandomBoxes(
        count=check_count(ctx, v["count"], f"{k}.count", MAX_RANDOM),
        size_x=check_range(ctx, v["size_x"], f"{k}.size_x", "pos"),
        size_y=check_range(ctx, v["size_y"], f"{k}.size_y", "pos"),
        yaw=check_range(ctx, v.get("yaw", list(d["yaw"].default)), f"{k}.yaw"),
        clearance=check_number(ctx, v.get("clearance", d["clearance"].default), f"{k}.clearance", "nonneg"),
        margin=check_number(ctx, v.get("margin", d["margin"].default), f"{k}.margin", "nonneg"),
    )
    _fits(ctx, f"{k}.size_x", math.hypot(rb.size_x[1], rb.size_y[1]), rb.margin, size, "box")
    return rb


def _random_circles(ctx: Ctx, v: Any, size: tuple[float, float]) -> RandomCircles:
    k = "random_circles"
    v = check_mapping(ctx, v, k, ("count", "radius"), ("clearance", "margin"))
    d = RandomCircles.__dataclass_fields__
    rc = RandomCircles(
        count=check_count(ctx, v["count"], f"{k}.count", MAX_RANDOM),
        radius=check_range(ctx, v["radius"], f"{k}.radius", "pos"),
        clearance=check_number(ctx, v.get("clearance", d["clearance"].default), f"{k}.clearance", "nonneg"),
        margin=check_number(ctx, v.get("margin", d["margin"].default), f"{k}.margin", "nonneg"),
    )
    _fits(ctx, f"{k}.radius", 2 * rc.radius[1], rc.margin, size, "circle")
    return rc


def random_movers(ctx: Ctx, v: Any, size: tuple[float, float], k: str = "moving_circles", boxes: bool = False) -> RandomMovers:
    """``v`` validated as :class:`RandomMovers`: moving discs, or moving boxes (``moving_boxes``) with ``boxes``;
    errors name ``k`` (the key: also used for the procedural worlds' ``worlds.movers``,
    ``tasks.config.WorldsConfig``)."""
    shape = ("size_x", "size_y") if boxes else ("radius",)
    v = check_mapping(ctx, v, k, ("count", *shape, "speed"), ("motion", "region", "clearance", "margin", "waypoints") + (("yaw",) if boxes else ()))
    d = RandomMovers.__dataclass_fields__
    extents = {}
    if boxes:
        extents = {"size_x": check_range(ctx, v["size_x"], f"{k}.size_x", "pos"), "size_y": check_range(ctx, v["size_y"], f"{k}.size_y", "pos"),
                   "yaw": check_range(ctx, v.get("yaw", list(d["yaw"].default)), f"{k}.yaw")}
        reach = 0.5 * math.hypot(extents["size_x"][1], extents["size_y"][1])  # the largest box's bounding circle
        extents["radius"] = (reach, reach)
    motion = v.get("motion", d["motion"].default)
    if motion not in MOTIONS:
        raise ctx.fail(f"{k}.motion", f"expected one of {', '.join(MOTIONS)}, got {show(motion)}")
    region = None
    if v.get("region") is not None:
        region = check_vector(ctx, v["region"], f"{k}.region", 4)
        if not (region[0] < region[2] and region[1] < region[3]):
            raise ctx.fail(f"{k}.region", f"expected [xmin, ymin, xmax, ymax] with xmin < xmax and ymin < ymax, got {show(v['region'])}")
        _inside(ctx, f"{k}.region", "a corner", [region[0], region[2]], [region[1], region[3]], size)
    mc = RandomMovers(
        count=check_count(ctx, v["count"], f"{k}.count", MAX_RANDOM),
        radius=extents.pop("radius") if boxes else check_range(ctx, v["radius"], f"{k}.radius", "pos"),
        speed=check_range(ctx, v["speed"], f"{k}.speed", "nonneg"),
        motion=motion, region=region, **extents,
        clearance=check_number(ctx, v.get("clearance", d["clearance"].default), f"{k}.clearance", "nonneg"),
        margin=check_number(ctx, v.get("margin", d["margin"].default), f"{k}.margin", "nonneg"),
        waypoints=check_count(ctx, v.get("waypoints", d["waypoints"].default), f"{k}.waypoints", 64),
    )
    if mc.waypoints < 1:
        raise ctx.fail(f"{k}.waypoints", f"expected an integer in [1, 64], got {show(mc.waypoints)}")
    w, h = (region[2] - region[0], region[3] - region[1]) if region else size
    _fits(ctx, f"{k}.size_x and size_y" if boxes else f"{k}.radius", 2 * mc.radius[1], mc.margin, (w, h), "moving " + ("box" if boxes else "disc"))
    return mc


_TOP_KEYS = ("name", "size", "map_server", "walls", "polygons", "circles", "boxes", "occupancy", "random_boxes", "random_circles", "moving_circles",
             "moving_boxes")
MAP_SERVER_KEYS = ("unknown", "crop", "boundary")  # map_server's options, besides its `yaml`


def _options(ctx: Ctx, key: str, opts: dict) -> tuple[str, bool, bool]:
    """``(unknown, crop, boundary)`` of the map_server options ``opts`` (keys :data:`MAP_SERVER_KEYS`), with
    their defaults; errors name ``key`` of ``ctx``'s file."""
    unknown = opts.get("unknown", "occupied")
    if unknown not in ms.UNKNOWN_AS:
        raise ctx.fail(f"{key}.unknown", f"expected one of {', '.join(ms.UNKNOWN_AS)}, got {show(unknown)}")
    return unknown, check_bool(ctx, opts.get("crop", True), f"{key}.crop"), check_bool(ctx, opts.get("boundary", True), f"{key}.boundary")


def _map_server(ctx: Ctx, grid: ms.Grid, unknown: str, crop: bool) -> ms.Layout:
    """The world of a map_server ``grid`` (:func:`.map_server.layout`) within the loader's limits; errors
    name ``ctx``'s file (the map_server YAML) and its ``image``."""
    lay = ms.layout(ctx, "image", grid, unknown, crop)
    if max(lay.size) > MAX_SIZE:
        raise ctx.fail("image", f"{grid.image}: {lay.size[0]:g} x {lay.size[1]:g} m; at most {MAX_SIZE:g} m per side "
                       "(float32 positions lose centimetres beyond that)")
    if len(lay.boxes) > MAX_FIXED:
        raise ctx.fail("image", f"{grid.image}: the occupied pixels make {len(lay.boxes):,} boxes; a map holds at most {MAX_FIXED:,} "
                       "(clean the image's noise)")
    return lay


def _embedded(ctx: Ctx, v: Any, base_dir: str | os.PathLike | None) -> tuple[ms.Layout, bool]:
    """The torchnav map key ``map_server: {yaml, unknown, crop, boundary}``: the map_server file's world."""
    v = check_mapping(ctx, v, "map_server", ("yaml",), MAP_SERVER_KEYS)
    unknown, crop, boundary = _options(ctx, "map_server", v)
    path = v["yaml"]
    if not isinstance(path, str) or not path:
        raise ctx.fail("map_server.yaml", f"expected the path of a map_server YAML file, got {show(path)}")
    if base_dir is not None and not os.path.isabs(path):
        path = os.path.join(base_dir, path)
    if not path.endswith((".yaml", ".yml")):
        raise ctx.fail("map_server.yaml", f"{path}: expected a .yaml or .yml file")
    try:
        text, source, _, folder = read_named(path, None, "map_server YAML", MapError)
    except MapError as e:
        raise ctx.fail("map_server.yaml", str(e)) from None
    inner = Ctx(f"{ctx.source}: map_server.yaml: {source}", MapError)  # its errors name both files
    data = load_yaml(text, inner.source, MapError)
    if not ms.is_map_server(data):
        raise inner.fail("", "not a map_server map (it needs an `image` key and no `size`)")
    return _map_server(inner, ms.read_grid(inner, data, folder), unknown, crop), boundary


def parse_map(
    data: Any, source: str = "<dict>", default_name: str = "map", base_dir: str | os.PathLike | None = None
) -> MapSpec:
    """Validate an already-parsed map (the dict a YAML file loads to) into a :class:`MapSpec`.

    ``source`` is only used in error messages and :attr:`MapSpec.source`. ``base_dir``
    resolves a relative ``occupancy.image`` or ``map_server.yaml`` path (``load_map`` passes
    the file's folder; None: the current directory). Segments are the world's edges of a
    ``map_server`` with ``boundary``, the ``walls``, then the ``polygons`` edges; boxes are
    the ``boxes``, the ``occupancy`` boxes, then the ``map_server`` image's. A map_server
    document (``image`` and no ``size``) is read as ``map_server: {yaml: <it>}`` with the defaults.
    """
    ctx = Ctx(source, MapError)
    if data is None:
        raise ctx.fail("", "the map file is empty; it needs at least `size: [w, h]`")
    if ms.is_map_server(data):
        unknown, crop, boundary = _options(ctx, "", {})  # the defaults: a map_server file has no torchnav options
        lay = _map_server(ctx, ms.read_grid(ctx, data, base_dir), unknown, crop)
        return MapSpec(name=default_name, source=source, size=lay.size, segments=_boundary(lay.size) if boundary else (),
                       boxes=tuple(tuple(b) for b in lay.boxes.tolist()), frame=lay.frame)
    d = check_mapping(ctx, data, "", (), _TOP_KEYS)
    name = d.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise ctx.fail("name", f"expected a non-empty string, got {show(name)}")
    lay, boundary = None, False
    if "map_server" in d:
        if "size" in d:
            raise ctx.fail("size", "not with map_server: the world's size is that of the map_server image (cropped to its known area by default)")
        lay, boundary = _embedded(ctx, d["map_server"], base_dir)
        size = lay.size
    elif "size" not in d:
        raise ctx.fail("size", "required key is missing (or map_server, whose image gives the size)")
    else:
        size = check_vector(ctx, d["size"], "size", 2, "pos")
    if max(size) > MAX_SIZE:
        raise ctx.fail("size", f"at most {MAX_SIZE:g} m per side (float32 positions lose centimetres beyond that), got {show(d['size'])}")
    for k in ("walls", "polygons", "circles", "boxes"):
        if isinstance(d.get(k), list) and len(d[k]) > MAX_FIXED:
            raise ctx.fail(k, f"{len(d[k]):,} entries; a map holds at most {MAX_FIXED:,} of a kind")
    counts = [d[k].get("count") for k in ("random_boxes", "random_circles") if isinstance(d.get(k), dict)]
    if len(counts) == 2 and all(isinstance(c, int) and not isinstance(c, bool) for c in counts) and sum(counts) > MAX_RANDOM:
        # Both kinds are placed in one sequence, so the bound is on their sum.
        raise ctx.fail("random_circles.count", f"random_boxes.count + random_circles.count = {sum(counts)}; a map re-places at most {MAX_RANDOM} "
                       "random objects per reset")
    circles, circle_styles = _circles(ctx, d["circles"], size) if "circles" in d else ((), ())
    boxes, box_styles = _boxes(ctx, d["boxes"], size) if "boxes" in d else ((), ())
    return MapSpec(
        name=name,
        source=source,
        size=size,
        segments=(_boundary(size) if boundary else ())
        + (_walls(ctx, d["walls"], size, boundary) if "walls" in d else ())
        + (_polygons(ctx, d["polygons"], size) if "polygons" in d else ()),
        circles=circles,
        boxes=boxes + (_occupancy(ctx, d["occupancy"], size, base_dir) if "occupancy" in d else ())
        + (tuple(tuple(b) for b in lay.boxes.tolist()) if lay is not None else ()),
        styles=ObstacleStyles(circles=circle_styles, boxes=box_styles),
        random_boxes=_random_boxes(ctx, d["random_boxes"], size) if "random_boxes" in d else None,
        random_circles=_random_circles(ctx, d["random_circles"], size) if "random_circles" in d else None,
        movers=_movers(ctx, d, size),
        frame=lay.frame if lay is not None else ms.IDENTITY,
    )


def _movers(ctx: Ctx, d: dict, size: tuple[float, float]) -> RandomMovers | None:
    """The map's ``moving_circles`` or ``moving_boxes`` (one kind of mover per map), or None."""
    if "moving_circles" in d and "moving_boxes" in d:
        raise ctx.fail("moving_boxes", "a map declares moving_circles or moving_boxes, not both")
    if "moving_boxes" in d:
        return random_movers(ctx, d["moving_boxes"], size, "moving_boxes", boxes=True)
    return random_movers(ctx, d["moving_circles"], size) if "moving_circles" in d else None


def available_maps() -> list[str]:
    """Names of the maps shipped with torchnav (the stems of ``torchnav/maps/data/*.yaml``)."""
    return shipped_names(shipped_folder(__package__))


def load_map(name_or_path: str | os.PathLike) -> MapSpec:
    """Load a shipped map by name (``"arena"``) or a map file by path (``"my_maps/lab.yaml"``).

    A string counts as a path when it contains a path separator or ends in
    ``.yaml``/``.yml``; anything else is looked up among :func:`available_maps`.
    """
    return load_named(name_or_path, __package__, "map", MapError, parse_map)
