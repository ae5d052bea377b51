"""What a config value allows, and the one validation of every config dataclass of torchnav.

It lives in the simulator package so that ``torchnav.sim`` stays usable (and copyable) on its
own; ``torchnav.config`` builds on it (``Config``, ``from_dict``) for the task and recipe configs.

* a field made with :func:`checked` (or a shorthand: :func:`count`, :func:`positive`,
  :func:`one_of`, ...) declares what it allows next to its default and unit;
* :meth:`Checked.checks` returns the relations between fields, as ``(ok, message)`` pairs;
* on construction every refused field and every failed relation is collected and raised as one
  :class:`ConfigError`, each problem starting with the key it names.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Iterable


class ConfigError(ValueError):
    """A configuration value or key is invalid; the message names it.

    ``problems`` holds each problem found (one line each); a ConfigError made from several lists
    them all under ``invalid config:``."""

    def __init__(self, *problems: str):
        self.problems = list(problems)
        super().__init__(problems[0] if len(problems) == 1 else "invalid config:\n  " + "\n  ".join(problems))


def raise_problems(problems: list[str]) -> None:
    """One ConfigError for every problem found (nothing when there is none)."""
    if problems:
        raise ConfigError(*problems)


# --------------------------------------------------------------------------- what a field allows


def checked(test: Callable[[Any], bool], allowed: str, default: Any = dataclasses.MISSING,
            default_factory: Any = dataclasses.MISSING) -> Any:
    """A dataclass field whose value must pass ``test`` (its type included), required unless given a
    default. A refused value is reported as ``key=value: must be <allowed>``, a refused inf or nan as
    ``key=value: must be finite``."""
    return dataclasses.field(default=default, default_factory=default_factory, metadata={"check": (test, allowed)})


def is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v: Any) -> bool:
    """A finite int or float (not a bool)."""
    return (is_int(v) or isinstance(v, float)) and math.isfinite(v)


def count(lo: int = 0, default: Any = dataclasses.MISSING, hi: int | None = None) -> Any:
    """An integer >= ``lo`` (and <= ``hi``: a size past which a tensor would not fit in memory)."""
    if hi is None:
        return checked(lambda v: is_int(v) and v >= lo, f"an integer >= {lo}", default)
    return checked(lambda v: is_int(v) and lo <= v <= hi, f"an integer in [{lo}, {hi:,}]", default)


def positive(default: Any = dataclasses.MISSING) -> Any:
    return checked(lambda v: is_number(v) and v > 0, "a finite number > 0", default)


def non_negative(default: Any = dataclasses.MISSING) -> Any:
    return checked(lambda v: is_number(v) and v >= 0, "a finite number >= 0", default)


def limit(default: Any = dataclasses.MISSING) -> Any:
    """An upper limit: a number > 0, inf for none."""
    return checked(lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0, "a number > 0 (inf: no limit)", default)


def discount(default: Any = dataclasses.MISSING) -> Any:
    return checked(lambda v: is_number(v) and 0 < v <= 1, "a number in (0, 1]", default)


def probability(default: Any = dataclasses.MISSING) -> Any:
    return checked(lambda v: is_number(v) and 0 <= v <= 1, "a number in [0, 1]", default)


def within(lo: float, hi: float, default: Any = dataclasses.MISSING, closed: str = "[]") -> Any:
    """A finite number between ``lo`` and ``hi``; ``closed`` says which ends are allowed: ``"[]"``, ``"(]"``, ``"[)"``, ``"()"``."""
    low = (lambda v: v >= lo) if closed[0] == "[" else (lambda v: v > lo)
    high = (lambda v: v <= hi) if closed[1] == "]" else (lambda v: v < hi)
    return checked(lambda v: is_number(v) and low(v) and high(v), f"a number in {closed[0]}{lo:g}, {hi:g}{closed[1]}", default)


def real(default: Any = dataclasses.MISSING) -> Any:
    return checked(is_number, "a float", default)


def flag(default: Any = dataclasses.MISSING) -> Any:
    return checked(lambda v: isinstance(v, bool), "true or false", default)


def one_of(*options: str, default: Any = dataclasses.MISSING, hint: str = "") -> Any:
    return checked(lambda v: v in options, " or ".join(options) + hint, default)


def sizes(default: Any = dataclasses.MISSING) -> Any:
    return checked(lambda v: isinstance(v, (list, tuple)) and len(v) > 0 and all(is_int(h) and h >= 1 for h in v),
                   "a non-empty list of integers >= 1", default)


def optional(test: Callable[[Any], bool], allowed: str) -> Any:
    """None (off), or a value that passes ``test``; the default is None."""
    return checked(lambda v: v is None or test(v), f"null or {allowed}", None)


def refusal(key: str, value: Any, rule: tuple[Callable[[Any], bool], str]) -> str:
    """The message for ``key=value`` refused by a field's ``(test, allowed)`` rule."""
    test, allowed = rule
    if isinstance(value, float) and not math.isfinite(value) and not test(math.inf):
        return f"{key}={value!r}: must be finite"
    return f"{key}={value!r}: must be {allowed}"


def raises(fn: Callable[[], Any]) -> tuple[bool, str]:
    """A relation checked by a function that raises a ValueError naming the problem, as ``(ok, message)``."""
    try:
        fn()
    except ValueError as e:
        return False, str(e)
    return True, ""


# --------------------------------------------------------------------------- the base class


class Checked:
    """The base of every config dataclass: construction checks the fields made with :func:`checked`,
    then (when they all pass) the relations of :meth:`checks`; every failure is reported in one
    :class:`ConfigError`, each message starting with the key it names, relative to this config
    (``torchnav.config.from_dict`` puts the section's dotted path in front)."""

    def __post_init__(self) -> None:
        problems = []
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            rule, value = f.metadata.get("check"), getattr(self, f.name)
            if rule is not None and not rule[0](value):
                problems.append(refusal(f.name, value, rule))
        if not problems:  # relations only between valid fields
            problems = [msg for ok, msg in self.checks() if not ok]
        raise_problems(problems)

    def checks(self) -> Iterable[tuple[bool, str]]:
        """The relations between fields as ``(ok, message)`` pairs (none here); each message starts with the key it names."""
        return ()
