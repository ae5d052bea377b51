"""Strict construction of frozen config dataclasses from plain dicts (YAML, CLI).

Unknown keys are an error that names the key and lists the valid ones (after
VMAS's ``check_kwargs_consumed``); wrong types are an error that names the key; a
field without a default must be set; a field made with :func:`checked` declares what
it allows, and a value outside it is an error naming the key, the value and what is
allowed. ``from_dict`` reports every problem of a config in one ConfigError.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from typing import Any, Callable, Mapping, TypeVar

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration value or key is invalid; the message names it."""


def _check_type(value: Any, tp: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        for arg in typing.get_args(tp):
            if arg is type(None):
                if value is None:
                    return None
                continue
            try:
                return _check_type(value, arg, where)
            except ConfigError:
                pass  # try the next type of the union
        raise ConfigError(f"{where}: {value!r} does not match {tp}")
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__} {value!r}")
        return from_dict(tp, value, where)
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_check_type(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}: {value!r}")
        return tuple(_check_type(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if origin is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        kt, vt = typing.get_args(tp)
        return {_check_type(k, kt, where): _check_type(v, vt, f"{where}.{k}") for k, v in value.items()}
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            if isinstance(value, str) and value.strip().lower() in ("inf", "+inf", "infinity"):
                return math.inf
            raise ConfigError(f"{where}: expected a number, got {type(value).__name__} {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {type(value).__name__} {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {type(value).__name__} {value!r}")
        return value
    return value


def checked(test: Callable[[Any], bool], allowed: str, default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field whose value must pass ``test`` (its type included), required unless given a
    ``default``: ``from_dict`` reports a failure as ``key=value: must be <allowed>``, and any
    non-finite number as ``must be finite``."""
    return dataclasses.field(default=default, metadata={"check": (test, allowed)})


def is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v: Any) -> bool:
    return (is_int(v) or isinstance(v, float)) and math.isfinite(v)


def raise_problems(problems: list[str]) -> None:
    """One ConfigError for every problem found (nothing when there is none)."""
    if problems:
        raise ConfigError(problems[0] if len(problems) == 1 else "invalid config:\n  " + "\n  ".join(problems))


def _key(where: str, k: Any) -> str:
    return f"{where}.{k}" if where else str(k)


def _build(cls: type[T], data: Any, where: str, problems: list[str], top: bool) -> T | None:
    """``cls`` from ``data``, or None after appending every problem found to ``problems``."""
    if not isinstance(data, Mapping):
        problems.append(f"{where}: expected a mapping, got {type(data).__name__} {data!r}")
        return None
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    found = len(problems)
    for k in data:
        if k not in fields:
            close = difflib.get_close_matches(str(k), list(fields), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            problems.append(f"{where + ': ' if where else ''}unknown key '{k}'{hint}; valid keys: {', '.join(fields)}")
    kwargs = {}
    for name, f in fields.items():
        key, tp = _key(where, name), hints[name]
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                problems.append(f"{key}: missing (no default: every file of this config sets it)")
            continue
        value, rule = data[name], f.metadata.get("check")
        if rule is not None:
            if isinstance(value, float) and not math.isfinite(value):
                problems.append(f"{key}={value!r}: must be finite")
                continue
            if not rule[0](value):
                problems.append(f"{key}={value!r}: must be {rule[1]}")
                continue
        if dataclasses.is_dataclass(tp) and not isinstance(value, tp):
            sub = _build(tp, value, key, problems, top=False)
            if sub is not None:
                kwargs[name] = sub
            continue
        try:
            kwargs[name] = _check_type(value, tp, key)
        except ConfigError as e:
            problems.append(str(e))
    if len(problems) > found:
        return None
    try:
        return cls(**kwargs)
    except ConfigError as e:  # the class's own checks (__post_init__) name their keys
        problems.append(str(e) if top or str(e).startswith(where) else f"{where}: {e}")
    except (ValueError, TypeError) as e:
        problems.append(f"{where}: {e}")
    return None


def from_dict(cls: type[T], data: Mapping[str, Any] | None, where: str = "config") -> T:
    """Build dataclass ``cls`` from ``data``, recursively, rejecting unknown keys and wrong types.

    Missing keys take the dataclass defaults (a field without one must be set); a field made with
    :func:`checked` must pass its test. Every problem is reported at once, each naming its dotted
    key starting at ``where`` (``""``: none).
    """
    problems: list[str] = []
    obj = _build(cls, dict(data or {}), where, problems, top=True)
    raise_problems(problems)
    return obj  # type: ignore[return-value]


def to_dict(obj: Any) -> Any:
    """A dataclass (nested) as plain dicts, lists and scalars, for YAML/JSON."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_dict(v) for k, v in obj.items()}
    return obj


def fields_as(cls: type[T], obj: Any, **values: Any) -> T:
    """Dataclass ``cls`` from the fields of dataclass ``obj`` that ``cls`` has too, and ``values`` (a config
    section as the simulator's parameters: ``fields_as(ImuParams, cfg.imu)``)."""
    names = {f.name for f in dataclasses.fields(cls)} - set(values)
    return cls(**{f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.name in names}, **values)


def merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict:
    """Recursive dict merge: values in ``override`` win; nested mappings merge."""
    out = dict(base)
    for k, v in override.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = merge(out[k], v)
        else:
            out[k] = v
    return out


C = TypeVar("C", bound="TaskConfig")


class TaskConfig:
    """The base of the task configs (``NavConfig``, ``LineConfig``): strict construction from a
    dict, the checks of their ``__post_init__``, and section defaults: a field annotated with a
    config dataclass and given no default (``robot: RobotConfig``) defaults to that dataclass's
    defaults."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        hints = typing.get_type_hints(cls)
        for name in cls.__dict__.get("__annotations__", {}):
            if dataclasses.is_dataclass(hints[name]) and name not in cls.__dict__:
                setattr(cls, name, dataclasses.field(default_factory=hints[name]))

    @classmethod
    def from_dict(cls: type[C], data: Mapping[str, Any] | None = None, where: str = "env") -> C:
        return from_dict(cls, data, where)

    @staticmethod
    def require(checks: list[tuple[bool, str]]) -> None:
        """Raise a ConfigError with the message of the first failed ``(ok, message)`` check."""
        for ok, msg in checks:
            if not ok:
                raise ConfigError(msg)

