"""Public names that changed: the old ones keep working for one release, with a
`DeprecationWarning` that names the new one."""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import Any, ParamSpec, TypeVar

from .checks import user_stacklevel

P = ParamSpec("P")
R = TypeVar("R")


def warn(old: str, new: str) -> None:
    """Say that `old` is deprecated, at the user's line."""
    warnings.warn(
        f"{old} is deprecated and will be removed in the next release: use {new}.",
        DeprecationWarning,
        stacklevel=user_stacklevel(),
    )


def renamed_arguments(**renames: str) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """A decorator: keyword arguments `old=` (the keys of `renames`) still work as their new
    names, with a warning; both at once is a `TypeError`."""

    def wrap(f: Callable[P, R]) -> Callable[P, R]:
        @functools.wraps(f)
        def inner(*args: P.args, **kwargs: P.kwargs) -> R:
            for old, new in renames.items():
                if old in kwargs:
                    name = getattr(f, "__name__", "the function")
                    if new in kwargs:
                        raise TypeError(f"{name}() got `{old}=` and `{new}=`: pass `{new}=`.")
                    warn(f"{name}({old}=...)", f"{name}({new}=...)")
                    kwargs[new] = kwargs.pop(old)
            return f(*args, **kwargs)

        return inner

    return wrap


def alias(f: Callable[P, R], old: str, new: str) -> Callable[P, R]:
    """`f` under its old public name `old`, warning that it is now `new`."""

    @functools.wraps(f)
    def inner(*args: P.args, **kwargs: P.kwargs) -> R:
        warn(old, new)
        return f(*args, **kwargs)

    inner.__name__ = inner.__qualname__ = old
    return inner


def renamed_attribute(old: str, new: str) -> Any:
    """A read-only property for the attribute's old name `old`, warning that it is now `new`."""

    def get(self):
        warn(f"`{type(self).__name__}.{old}`", f"`.{new}`")
        return getattr(self, new)

    return property(get)


def renamed_option(method: Any, old: str, new: str, values: dict, default: Any = "auto") -> Any:
    """The value of `method`'s option `new`, given its deprecated name `old` (a field that
    defaults to `None`; its values renamed by `values`): `old` given warns, both given is a
    `TypeError`. The method's `__post_init__` stores the result as `new`."""
    value = getattr(method, old)
    if value is None:
        return getattr(method, new)
    name = type(method).__name__
    if getattr(method, new) != default:
        raise TypeError(f"{name}() got `{old}=` and `{new}=`: pass `{new}=`.")
    renamed = values.get(value, value) if isinstance(value, str) else value
    warn(f"{name}({old}={value!r})", f"{name}({new}={renamed!r})")
    return renamed
