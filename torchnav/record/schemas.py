"""JSON Schemas for the recorded messages.

Foxglove's well-known schemas (``foxglove.LaserScan``, ``foxglove.SceneUpdate``, ...)
are generated here from the protobuf descriptors that ship with the pinned
``foxglove-sdk`` (``foxglove.messages.X.get_schema()``), following Foxglove's own
JSON conventions: times and durations are ``{"sec", "nsec"}`` objects, enums are
integers, bytes are base64 strings. Generating them from the SDK keeps field names
exactly those the Foxglove app expects, without a copy of the schema files here.

torchnav's own messages (actions, rewards, episode events) get hand-written JSON
Schemas with a ``torchnav.`` name.

``validate(instance, schema)`` is a small JSON-Schema checker (type, properties,
items, required, enum-by-``oneOf``/``const``) used by the tests and by
``python -m torchnav.record.replay --check``.
"""

from __future__ import annotations

import functools
import re
from typing import Any, Sequence

# -- a minimal protobuf wire-format reader, just enough for descriptor.proto -------------


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    shift = result = 0
    while True:
        b = buf[i]
        i += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, i
        shift += 7


def _fields(buf: bytes) -> list[tuple[int, Any]]:
    """(field number, value) pairs of one serialised message: ints or raw bytes."""
    out, i = [], 0
    while i < len(buf):
        key, i = _varint(buf, i)
        num, wire = key >> 3, key & 7
        if wire == 0:
            val, i = _varint(buf, i)
        elif wire == 2:
            n, i = _varint(buf, i)
            val, i = buf[i : i + n], i + n
        elif wire == 1:
            val, i = buf[i : i + 8], i + 8
        elif wire == 5:
            val, i = buf[i : i + 4], i + 4
        else:  # groups never occur in descriptors
            raise ValueError(f"unsupported protobuf wire type {wire}")
        out.append((num, val))
    return out


def _parse_descriptor_set(data: bytes) -> tuple[dict[str, list[dict]], dict[str, list[tuple[str, int]]]]:
    """Messages ``{'.pkg.Name': [field dicts]}`` and enums ``{'.pkg.Name.Enum': [(name, number)]}``."""
    messages: dict[str, list[dict]] = {}
    enums: dict[str, list[tuple[str, int]]] = {}

    def enum(buf: bytes, prefix: str) -> None:
        f = _fields(buf)
        name = next(v.decode() for n, v in f if n == 1)
        enums[f"{prefix}.{name}"] = [
            (next(x.decode() for k, x in fv if k == 1), next((x for k, x in fv if k == 2), 0))
            for fv in (_fields(v) for n, v in f if n == 2)
        ]

    def message(buf: bytes, prefix: str) -> None:
        f = _fields(buf)
        full = f"{prefix}.{next(v.decode() for n, v in f if n == 1)}"
        fields = []
        for n, v in f:
            if n == 2:
                fd = dict(_fields(v))
                fields.append({"name": fd[1].decode(), "label": fd.get(4, 1), "type": fd[5], "type_name": fd.get(6, b"").decode()})
            elif n == 3:
                message(v, full)
            elif n == 4:
                enum(v, full)
        messages[full] = fields

    for num, file_buf in _fields(data):
        if num != 1:
            continue
        f = _fields(file_buf)
        package = next((v.decode() for n, v in f if n == 2), "")
        prefix = f".{package}" if package else ""
        for n, v in f:
            if n == 4:
                message(v, prefix)
            elif n == 5:
                enum(v, prefix)
    return messages, enums


_TIME = {
    "type": "object",
    "title": "time",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
}
_DURATION = {
    "type": "object",
    "title": "duration",
    "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
}
# descriptor.proto FieldDescriptorProto.Type -> JSON Schema type
_SCALARS = {1: "number", 2: "number", 3: "integer", 4: "integer", 5: "integer", 6: "integer", 7: "integer", 8: "boolean",
            9: "string", 13: "integer", 15: "integer", 16: "integer", 17: "integer", 18: "integer"}


def _param_docs(name: str) -> tuple[str, dict[str, str]]:
    """Title line and ``:param x:`` descriptions from the SDK's docstring of ``foxglove.messages.<name>``."""
    import foxglove.messages as fm

    doc = getattr(getattr(fm, name, None), "__doc__", None) or ""
    first = doc.strip().splitlines()[0] if doc.strip() else ""
    params = dict(re.findall(r":param (\w+): ([^\n]*)", doc))
    return first, params


@functools.lru_cache(maxsize=None)
def foxglove_schema(name: str) -> dict:
    """The JSON Schema of Foxglove message ``name`` (e.g. ``"LaserScan"``), from the pinned foxglove-sdk."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import foxglove.messages as fm

    sdk_schema = getattr(fm, name).get_schema()
    messages, enums = _parse_descriptor_set(bytes(sdk_schema.data))

    def convert(full: str) -> dict:
        short = full.rsplit(".", 1)[-1]
        title, params = _param_docs(short)
        props = {}
        for f in messages[full]:
            t, tn = f["type"], f["type_name"]
            if tn == ".google.protobuf.Timestamp":
                p = dict(_TIME)
            elif tn == ".google.protobuf.Duration":
                p = dict(_DURATION)
            elif t == 11:
                p = convert(tn)
            elif t == 14:
                p = {"title": tn.lstrip("."), "oneOf": [{"title": n, "const": v} for n, v in enums[tn]]}
            elif t == 12:
                p = {"type": "string", "contentEncoding": "base64"}
            else:
                p = {"type": _SCALARS[t]}
            if f["name"] in params:
                p["description"] = params[f["name"]]
            if f["label"] == 3:
                desc = p.pop("description", None)
                p = {"type": "array", "items": p, **({"description": desc} if desc else {})}
            props[f["name"]] = p
        out = {"title": full.lstrip("."), "type": "object", "properties": props}
        if title:
            out["description"] = title
        return out

    schema = convert(f".{sdk_schema.name}")
    schema["$comment"] = "Generated by torchnav from the protobuf descriptors of foxglove-sdk"
    return schema


# -- torchnav's own messages ------------------------------------------------------------------

_NUM = {"type": "number"}
_INT = {"type": "integer"}


def _message(title: str, description: str, required: list[str], properties: dict) -> dict:
    """The JSON Schema of one of torchnav's own messages: an object of ``properties``."""
    return {"title": title, "description": description, "type": "object", "properties": properties, "required": required}


_ROBOT = {**_INT, "description": "robot slot in the env (several robots per env only)"}


def action_schema(action_dim: int, robots: bool = False) -> dict:
    """``robots``: the messages of a multi-robot recording, which name their ``robot``."""
    return _with_robot(robots, _message("torchnav.Action", "The policy's action and the twist it commands (recorded at the time of the state it was chosen in)",
                    ["env", "episode", "step", "v", "omega", "action"], {
        "env": {**_INT, "description": "index of the env in the batch"},
        "episode": {**_INT, "description": "episode number of this env in the file, from 0"},
        "step": {**_INT, "description": "step of the episode this action starts, from 0"},
        "v": {**_NUM, "description": "applied linear speed, m/s"},
        "omega": {**_NUM, "description": "applied turn rate, rad/s (CCW positive)"},
        "action": {"type": "array", "items": _NUM, "minItems": action_dim, "maxItems": action_dim,
                   "description": "raw policy output (continuous in [-1, 1], or one-hot)"},
    }))


def _with_robot(robots: bool, schema: dict, **extra: dict) -> dict:
    """``schema`` with the ``robot`` field (required) and ``extra`` properties when ``robots``, else as it is."""
    if robots:
        schema["properties"] = {"robot": _ROBOT, **schema["properties"], **extra}
        schema["required"] = ["robot", *schema["required"]]
    return schema


def reward_schema(term_names: Sequence[str], robots: bool = False) -> dict:
    terms = {k: {**_NUM, "description": f"weighted reward term '{k}' of this step"} for k in term_names}
    return _with_robot(robots, _message("torchnav.Reward", "Reward of one step, split into its terms (recorded at the time of the state it led to)",
                    ["env", "episode", "step", "reward", "return", "v", "omega", "terms", "curriculum_radius"], {
        "env": _INT, "episode": _INT,
        "step": {**_INT, "description": "steps done in this episode, from 1"},
        "reward": {**_NUM, "description": "total reward of the step (sum of the terms)"},
        "return": {**_NUM, "description": "return of the episode so far"},
        "v": {**_NUM, "description": "linear speed after the step, m/s"},
        "omega": {**_NUM, "description": "turn rate after the step, rad/s"},
        "terms": {"type": "object", "properties": terms, "required": list(term_names)},
        "curriculum_radius": {**_NUM, "description": "goal-distance curriculum radius, m"},
        "goal_distance": {**_NUM, "description": "distance from the robot centre to the goal, m"},
        "success": {"type": "boolean"}, "collision": {"type": "boolean"},
    }), robot_collision={"type": "boolean", "description": "the step's collision was with another robot"})


def imu_schema() -> dict:
    return _message("torchnav.Imu", "The robot's planar IMU reading after a step, in the robot frame (x forward, y left)",
                    ["timestamp", "frame_id", "linear_acceleration", "angular_velocity"], {
        "timestamp": {"type": "object", "properties": {"sec": _INT, "nsec": _INT}},
        "frame_id": {"type": "string", "description": "the robot's base frame"},
        "linear_acceleration": {"type": "object", "description": "m/s^2, bias and noise included (z is 0: no gravity)",
                                "properties": {"x": _NUM, "y": _NUM, "z": _NUM}},
        "angular_velocity": {"type": "object", "description": "rad/s, bias and noise included (only z, the yaw rate)",
                             "properties": {"x": _NUM, "y": _NUM, "z": _NUM}},
    })


def movers_schema() -> dict:
    return _message("torchnav.Movers", "The moving obstacles of one env after a step",
                    ["env", "episode", "discs"], {
        "env": _INT, "episode": _INT,
        "discs": {"type": "array", "items": _NUM, "description": "existing moving discs [x m, y m, vx m/s, vy m/s, radius m], 5 numbers each, one after the other"},
        "boxes": {"type": "array", "items": _NUM, "description": "existing moving boxes [x m, y m, vx m/s, vy m/s, half_x m, half_y m, yaw rad], "
                  "7 numbers each, one after the other; only in batches with moving boxes"},
    })


EVENT_KINDS = ("start", "success", "collision", "timeout", "terminated")


ROBOT_OUTCOMES = ("success", "collision", "timeout", "ended")  # a robot's end in a multi-robot episode ("ended": another's collision ended the team's)


def event_schema(robots: bool = False) -> dict:
    """``robots``: the events of a multi-robot recording (start: ``robots``, ``starts``, ``goals``; end:
    ``team_success`` and each robot's ``outcomes``)."""
    def rows(width: int, what: str) -> dict:
        return {"type": "array", "items": _NUM, "description": f"{what}, {width} numbers each, one after the other"}

    schema = _message("torchnav.EpisodeEvent", "Start or end of an episode of one env. Start events carry the episode's world.",
                    ["env", "episode", "event"], {
        "env": _INT, "episode": _INT,
        "event": {"type": "string", "enum": list(EVENT_KINDS)},
        "reason": {"type": "string", "description": "why a 'terminated' episode ended (the env's flag, e.g. left_line)"},
        "steps": {**_INT, "description": "steps done in the episode"},
        "return": _NUM, "path_length": {**_NUM, "description": "m driven"},
        "straight_line": {**_NUM, "description": "start-goal distance, m"},
        "start": {"type": "array", "items": _NUM, "description": "start pose [x m, y m, yaw rad]"},
        "goal": {"type": "array", "items": _NUM, "description": "goal [x m, y m]"},
        "world": {
            "type": "object",
            "description": "obstacles of the episode as flat lists (m, rad)",
            "properties": {"segments": rows(4, "walls [x1, y1, x2, y2]"), "circles": rows(3, "circles [cx, cy, r]"),
                           "boxes": rows(5, "boxes [cx, cy, half_x, half_y, yaw]"), "fixed_only": {"type": "boolean"}},
        },
    })
    if robots:
        del schema["properties"]["start"], schema["properties"]["goal"], schema["properties"]["path_length"], schema["properties"]["straight_line"]
        schema["description"] = "Start or end of an episode of one env of several robots. Start events carry the episode's world."
        schema["properties"].update({
            "robots": {"type": "array", "items": _INT, "description": "start: the robot slots present in the episode"},
            "starts": rows(3, "start: the present robots' start poses [x m, y m, yaw rad], in the order of robots"),
            "goals": rows(2, "start: the present robots' goals [x m, y m], in the order of robots"),
            "team_success": {"type": "boolean", "description": "end: every present robot reached its goal"},
            "outcomes": {"type": "array", "description": "end: one per present robot", "items": {
                "type": "object", "required": ["robot", "outcome", "steps", "return"], "properties": {
                    "robot": _INT, "outcome": {"type": "string", "enum": list(ROBOT_OUTCOMES)},
                    "steps": {**_INT, "description": "steps until it parked (at its goal or collided), else the episode's"},
                    "return": _NUM, "path_length": {**_NUM, "description": "m driven"},
                    "straight_line": {**_NUM, "description": "start-goal distance, m"}}}},
        })
        schema["properties"]["return"] = {**_NUM, "description": "end: the sum of the present robots' returns"}
    return schema


# -- a small validator -----------------------------------------------------------------------

_PY = {"object": dict, "array": list, "string": str, "boolean": bool, "integer": int, "number": (int, float)}


def validate(instance: Any, schema: dict, path: str = "$") -> None:
    """Raise ValueError naming the path where ``instance`` breaks ``schema``.

    Checks ``type``, ``properties`` (no unknown keys), ``required``, ``items``,
    ``enum``, ``minItems``/``maxItems`` and ``oneOf`` of ``const`` values; enough
    for the schemas in this module.
    """
    if "oneOf" in schema:
        consts = [s.get("const") for s in schema["oneOf"]]
        if instance not in consts:
            raise ValueError(f"{path}: {instance!r} not one of {consts}")
        return
    t = schema.get("type")
    if t is not None:
        ok = isinstance(instance, _PY[t]) and not (t in ("integer", "number") and isinstance(instance, bool))
        if not ok:
            raise ValueError(f"{path}: expected {t}, got {type(instance).__name__} {instance!r:.60}")
    if "enum" in schema and instance not in schema["enum"]:
        raise ValueError(f"{path}: {instance!r} not in {schema['enum']}")
    if t == "object":
        props = schema.get("properties", {})
        for k, v in instance.items():
            if props and k not in props:
                raise ValueError(f"{path}: unknown key {k!r} (schema {schema.get('title', '')} has {sorted(props)})")
            if k in props:
                validate(v, props[k], f"{path}.{k}")
        for k in schema.get("required", ()):
            if k not in instance:
                raise ValueError(f"{path}: missing required key {k!r}")
    if t == "array":
        if len(instance) < schema.get("minItems", 0) or len(instance) > schema.get("maxItems", 1 << 62):
            raise ValueError(f"{path}: {len(instance)} items outside [{schema.get('minItems')}, {schema.get('maxItems')}]")
        if "items" in schema:
            for i, v in enumerate(instance):
                validate(v, schema["items"], f"{path}[{i}]")
