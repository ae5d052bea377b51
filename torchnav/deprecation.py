"""Old names kept working for a while: each use warns with a ``DeprecationWarning`` that names the new one."""

from __future__ import annotations

import functools
import warnings
from typing import Any, Callable


def _warn(old: str, new: str) -> None:
    warnings.warn(f"{old} is deprecated: use {new}", DeprecationWarning, stacklevel=3)


def renamed_function(new: Callable, old: str) -> Callable:
    """``new`` under its old name ``old`` (a dotted path); each call warns."""

    @functools.wraps(new)
    def call(*args: Any, **kwargs: Any) -> Any:
        _warn(old, f"{new.__module__}.{new.__name__}")
        return new(*args, **kwargs)

    call.__name__, call.__doc__ = old.rsplit(".", 1)[-1], f"Deprecated name of :func:`{new.__name__}`."
    return call


def renamed_attribute(old: str, new: str) -> property:
    """A read-only class attribute ``old`` that reads ``new`` and warns."""

    def read(self: Any) -> Any:
        _warn(f"{type(self).__name__}.{old}", new)
        return getattr(self, new)

    return property(read, doc=f"Deprecated name of ``{new}``.")


def renamed_keywords(**old_to_new: str) -> Callable[[Callable], Callable]:
    """A decorator: the function still takes each keyword ``old`` as ``new`` (``gen="generator"``), with a warning."""

    def wrap(fn: Callable) -> Callable:
        @functools.wraps(fn)
        def call(*args: Any, **kwargs: Any) -> Any:
            for old, new in old_to_new.items():
                if old in kwargs:
                    if new in kwargs:
                        raise TypeError(f"{fn.__qualname__}() got both {old}= (its deprecated name) and {new}=")
                    _warn(f"{fn.__qualname__}({old}=...)", f"{new}=")
                    kwargs[new] = kwargs.pop(old)
            return fn(*args, **kwargs)

        return call

    return wrap
