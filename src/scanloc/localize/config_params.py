"""Localizer parameter dataclasses from config mappings, with errors that name the key."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import fields
from typing import Any, TypeVar

T = TypeVar("T")


def params_from_config(
    cls: type[T], config: Mapping[str, object], what: str, skip: Iterable[str] = ()
) -> T:
    """An instance of the frozen dataclass `cls` from `config`, keys in `skip` ignored.

    Every field needs a default; each value must have its default's type (an int is accepted
    for a float). Raises ValueError for an unknown key (listing the known ones) or a wrong type,
    naming the `what` parameter.
    """
    known = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    skipped = set(skip)
    values: dict[str, Any] = {}
    for key, value in config.items():
        if key in skipped:
            continue
        if key not in known:
            raise ValueError(
                f"unknown {what} parameter {key!r}; known parameters: {', '.join(sorted(known))}"
            )
        values[key] = _coerce(what, key, value, getattr(cls, key))
    return cls(**values)


def _coerce(what: str, key: str, value: object, default: object) -> object:
    """`value` as the type of the parameter's default, or a ValueError naming the parameter."""
    kind = type(default)
    ok = (
        isinstance(value, bool)
        if kind is bool
        else isinstance(value, str)
        if kind is str
        else isinstance(value, (int, float)) and not isinstance(value, bool)
    )
    if ok and kind is int and int(value) != value:  # type: ignore[call-overload]
        ok = False
    if not ok:
        raise ValueError(f"{what} parameter {key!r} must be of type {kind.__name__}, got {value!r}")
    return kind(value)
