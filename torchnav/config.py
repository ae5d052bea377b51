"""The config schema: frozen dataclasses that check themselves, and their strict construction from
plain dicts (YAML, command lines).

Every config dataclass of torchnav is validated the same way (``torchnav.sim.checks``, where the
simulator's parameters use it too): a field made with :func:`checked` (or a shorthand:
:func:`count`, :func:`positive`, :func:`one_of`, ...) declares what it allows next to its default
and unit, ``checks()`` returns the relations between fields as ``(ok, message)`` pairs, and
construction raises one :class:`ConfigError` listing every refused field and failed relation,
each starting with the key it names. The task and recipe configs subclass :class:`Config`.

:func:`from_dict` builds a config from nested dicts and adds what only a dict can get wrong:
unknown keys (named with the closest valid one, after VMAS's ``check_kwargs_consumed``), missing
required keys and wrong types. It reports every problem of every section at once, each under its
dotted key (``task.robot.dt=0: must be a finite number > 0``).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
import typing
from typing import Any, Mapping, TypeVar

# The rules, the error and the validation every config shares; the task and recipe configs import them from here.
from .sim.checks import (  # noqa: F401
    Checked, ConfigError, checked, count, discount, flag, is_int, is_number, limit, non_negative, one_of, optional, positive,
    probability, raise_problems, raises, real, refusal, sizes, within,
)

T = TypeVar("T")
C = TypeVar("C", bound="Config")


class Config(Checked):
    """The base of the task and recipe configs: validated on construction like every config
    (:class:`~torchnav.sim.checks.Checked`), built from dicts with :meth:`from_dict`, and with section
    defaults: a field annotated with a config dataclass whose fields all have defaults, and given no
    default itself (``robot: RobotConfig``), defaults to that class's defaults (a fresh one per config)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        hints = typing.get_type_hints(cls)
        for name in cls.__dict__.get("__annotations__", {}):
            tp = hints[name]
            if dataclasses.is_dataclass(tp) and name not in cls.__dict__ and _all_defaulted(tp):
                setattr(cls, name, dataclasses.field(default_factory=tp))

    @classmethod
    def from_dict(cls: type[C], data: Mapping[str, Any] | None = None, where: str = "env") -> C:
        return from_dict(cls, data, where)


def _all_defaulted(cls: type) -> bool:
    return all(f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
               for f in dataclasses.fields(cls) if f.init)


# --------------------------------------------------------------------------- from_dict, to_dict, merge


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


def _key(where: str, k: Any) -> str:
    return f"{where}.{k}" if where else str(k)


def _build(cls: type[T], data: Any, where: str, problems: list[str]) -> T | None:
    """``cls`` from ``data``, or None after appending every problem found to ``problems``."""
    if not isinstance(data, Mapping):
        problems.append(f"{where}: expected a mapping, got {type(data).__name__} {data!r}")
        return None
    prepare = getattr(cls, "prepare_dict", None)  # a section's own expansion of its data (NavConfig: robot presets)
    if prepare is not None:
        data = prepare(data)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
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
                problems.append(f"{key}: missing (this key has no default)")
            continue
        value = data[name]
        if dataclasses.is_dataclass(tp) and not isinstance(value, tp):
            sub = _build(tp, value, key, problems)
            if sub is not None:
                kwargs[name] = sub
            continue
        rule = f.metadata.get("check")
        try:
            kwargs[name] = _check_type(value, tp, key)
        except ConfigError as e:  # what the field allows says more than its type
            problems.append(refusal(key, value, rule) if rule is not None else str(e))
            continue
        if rule is not None and not rule[0](kwargs[name]):  # here too, so that it is named even when the section cannot be built
            problems.append(refusal(key, value, rule))  # the value as written
    if len(problems) > found:
        return None
    try:
        return cls(**kwargs)
    except ConfigError as e:  # the class's own checks, each naming its key within the class
        problems.extend(_key(where, p) for p in e.problems)
    except (ValueError, TypeError) as e:
        problems.append(f"{where}: {e}" if where else str(e))
    return None


def from_dict(cls: type[T], data: Mapping[str, Any] | None, where: str = "config") -> T:
    """Build dataclass ``cls`` from ``data``, recursively, rejecting unknown keys and wrong types.

    Missing keys take the dataclass defaults (a field without one must be set); every problem of
    every section is reported at once, each naming its dotted key starting at ``where`` (``""``: none).
    """
    problems: list[str] = []
    obj = _build(cls, dict(data or {}), where, problems)
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


def merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict:
    """Recursive dict merge: values in ``override`` win; nested mappings merge."""
    out = dict(base)
    for k, v in override.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = merge(out[k], v)
        else:
            out[k] = v
    return out
