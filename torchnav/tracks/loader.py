"""Track files (YAML ``lines:`` polylines, or an ``image:`` PNG mask) -> :class:`~torchnav.tracks.track.Track`.

The schema is documented key by key in docs/line.md. Parsing is strict, like map files: an
unknown key, a wrong type or an impossible corner radius raises :class:`TrackError` naming the
file and the key path (``course.yaml: lines[1].corner_radius: ...``)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..maps.occupancy import ImageError, read_mask
from ..yamlcheck import (Ctx, check_bool, check_grey_level, check_image, check_list, check_mapping, check_number, check_vector, is_number, load_named, shipped_folder,
                         shipped_names, show)
from .geometry import CurveError, catmull_rom, fillet_polyline, resample
from .png import track_from_mask
from .track import Track, TrackError

DEFAULT_SPACING = 0.02  # m


def _points(ctx: Ctx, v: Any, key: str, min_n: int) -> np.ndarray:
    ok = isinstance(v, list) and len(v) >= min_n and all(
        isinstance(p, list) and len(p) == 2 and all(is_number(x) for x in p) for p in v
    )
    if not ok:
        raise ctx.fail(key, f"expected a list of at least {min_n} [x, y] points in m, got {show(v)}")
    return np.asarray(v, dtype=np.float64)


def _curve(ctx: Ctx, v: dict, key: str, spacing: float, force_closed: bool = False) -> tuple[np.ndarray, bool]:
    """A resampled polyline from a line entry's ``points``, ``closed``, ``corner_radius``, ``smooth``."""
    closed = True if force_closed else check_bool(ctx, v.get("closed", False), f"{key}.closed")
    pts = _points(ctx, v["points"], f"{key}.points", 3 if closed else 2)
    smooth = check_bool(ctx, v.get("smooth", False), f"{key}.smooth")
    cr = v.get("corner_radius", 0.0)
    if smooth and "corner_radius" in v:
        raise ctx.fail(f"{key}.corner_radius", "give either corner_radius or smooth: true, not both")
    if isinstance(cr, list):
        radii = np.asarray(check_vector(ctx, cr, f"{key}.corner_radius", len(pts), "nonneg"))
    else:
        radii = np.full(len(pts), check_number(ctx, cr, f"{key}.corner_radius", "nonneg"))
    try:
        dense = catmull_rom(pts, closed) if smooth else fillet_polyline(pts, radii, closed)
        return resample(dense, spacing, closed), closed
    except CurveError as e:
        msg = str(e)
        raise ctx.fail("spacing" if "spacing" in msg else f"{key}.corner_radius" if "radi" in msg else f"{key}.points", msg) from None


def _walls(ctx: Ctx, v: Any) -> np.ndarray:
    walls = check_list(ctx, v, "walls", "a list of [x1, y1, x2, y2] segments in m", lambda key, w: check_vector(ctx, w, key, 4))
    return np.asarray(walls, dtype=np.float64).reshape(-1, 4)


def _segments(line: np.ndarray) -> np.ndarray:
    return np.concatenate((line[:-1], line[1:]), axis=1)


LINE_KEYS = ("points", "closed", "corner_radius", "smooth", "lap")
COMMON_KEYS = ("name", "description", "spacing", "walls")
IMAGE_KEYS = ("image", "resolution", "origin", "threshold", "invert", "width", "lap")


def parse_track(data: Any, source: str = "<dict>", default_name: str = "track", base_dir: str | os.PathLike | None = None) -> Track:
    """Validate a parsed track file (a dict) and build the :class:`Track`.

    ``base_dir`` resolves a relative ``image:`` path (the YAML file's folder).
    """
    ctx = Ctx(source, TrackError)
    if not isinstance(data, dict):
        raise ctx.fail("", f"a track file must be a mapping with 'lines' or 'image', got {show(data)}")
    if "image" in data:
        d = check_mapping(ctx, data, "", ("image", "resolution"), COMMON_KEYS + IMAGE_KEYS[2:])
    else:
        d = check_mapping(ctx, data, "", ("width", "lines"), COMMON_KEYS)
    name = d.get("name", default_name)
    desc = d.get("description", "")
    for k, val in (("name", name), ("description", desc)):
        if not isinstance(val, str):
            raise ctx.fail(k, f"expected a string, got {show(val)}")
    spacing = check_number(ctx, d.get("spacing", DEFAULT_SPACING), "spacing", "pos")
    walls = _walls(ctx, d.get("walls", []))
    if "image" in d:
        return _track_from_png(ctx, d, name, desc, spacing, walls, base_dir)
    width = _width(ctx, d["width"])
    lines_v = d["lines"]
    if not isinstance(lines_v, list) or not lines_v:
        raise ctx.fail("lines", f"expected a non-empty list of lines, got {show(lines_v)}")
    lines, closed, lap_flags = [], [], []
    for i, lv in enumerate(lines_v):
        key = f"lines[{i}]"
        lv = check_mapping(ctx, lv, key, ("points",), LINE_KEYS[1:])
        line, c = _curve(ctx, lv, key, spacing)
        lines.append(line)
        closed.append(c)
        lap_flags.append(check_bool(ctx, lv.get("lap", False), f"{key}.lap"))
    if sum(lap_flags) > 1:
        raise ctx.fail("lines", "only one line may have lap: true")
    if any(lap_flags):
        lap_i = lap_flags.index(True)
        if not closed[lap_i]:
            raise ctx.fail(f"lines[{lap_i}].lap", "the lap line must be closed (closed: true)")
    elif any(closed):
        lap_i = closed.index(True)
    else:
        raise ctx.fail("lines", "no closed line: mark a closed line with lap: true to define laps")
    return Track(
        name=name, width=width, segments=np.concatenate([_segments(ln) for ln in lines]), lines=tuple(lines),
        lap=lines[lap_i], walls=walls, spacing=spacing, source=source, description=desc,
    )


MAX_WIDTH = 10.0  # m, a line wider than this is no line for floor sensors
MIN_WIDTH = 1e-3  # m, a line narrower than this no floor sensor resolves


def _width(ctx: Any, v: Any) -> float:
    w = check_number(ctx, v, "width", "pos")
    if not MIN_WIDTH <= w <= MAX_WIDTH:
        raise ctx.fail("width", f"expected a line width in [{MIN_WIDTH:g}, {MAX_WIDTH:g}] m, got {show(v)}")
    return w


def _track_from_png(ctx: Any, d: dict, name: str, desc: str, spacing: float, walls: np.ndarray, base_dir: Any) -> Track:
    """The ``image:`` form of a track file (called by the loader with the validated mapping)."""
    path = check_image(ctx, d["image"], "image", base_dir)
    res = check_number(ctx, d["resolution"], "resolution", "pos")
    origin = check_vector(ctx, d["origin"], "origin", 2) if "origin" in d else None
    thr = check_grey_level(ctx, d.get("threshold", 0.5), "threshold")
    invert = check_bool(ctx, d.get("invert", False), "invert")
    width = _width(ctx, d["width"]) if "width" in d else None
    lap = None
    if "lap" in d:
        lv = check_mapping(ctx, d["lap"], "lap", ("points",), ("corner_radius", "smooth"))
        lap, _ = _curve(ctx, lv, "lap", spacing, force_closed=True)
    try:
        mask = read_mask(path, thr, invert)
    except ImageError as e:
        raise ctx.fail("image", str(e)) from None
    return track_from_mask(mask, res, origin, width, lap, spacing, walls, name, ctx.source, desc)


def available_tracks() -> list[str]:
    """Names of the tracks shipped with torchnav (stems of ``torchnav/tracks/data/*.yaml``)."""
    return shipped_names(shipped_folder(__package__))


def load_track(name_or_path: str | os.PathLike) -> Track:
    """Load a shipped track by name (``"course"``) or a track file by path (``"my/track.yaml"``).

    A string counts as a path when it contains a path separator or ends in ``.yaml``/``.yml``.
    """
    return load_named(name_or_path, __package__, "track", TrackError, parse_track)
