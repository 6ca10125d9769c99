"""Localizer parameter dataclasses from config mappings, with errors that name the key.

A localizer config (conf/localizer/<name>.yaml) is written in sections, each read by the part
that owns it (`meta` by the catalog, `filter` / `motion` / `sensor` by the particle filter,
`proposal` / `mixing` / `weighting` by the registered part their `type` names, `learned` and
`verifier` by the learned localizer): `parse_section` reads one into its part's dataclass, and
an unknown key is an error naming the file, the section and the key. A part's defaults live
in its dataclass only; a config writes what departs from them.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import MISSING, fields
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
    known = {f.name: f for f in fields(cls)}  # type: ignore[arg-type]
    skipped = set(skip)
    values: dict[str, Any] = {}
    for key, value in config.items():
        if key in skipped:
            continue
        if key not in known:
            raise ValueError(
                f"unknown {what} parameter {key!r}; known parameters: {', '.join(sorted(known))}"
            )
        values[key] = _coerce(what, key, value, _default(known[key]))
    return cls(**values)


def parse_section(cls: type[T], config: Mapping[str, Any], section: str, where: str) -> T:
    """`cls` from `config[section]` (absent: every default). Errors name `where` (the config
    file), the section and the key: an unknown key, a value of the wrong type, or a value
    the part rejects."""
    values = section_values(config, section, where)
    known = sorted(f.name for f in fields(cls))  # type: ignore[arg-type]
    for key in values:
        if key not in known:
            raise ValueError(
                f"{where}: section '{section}': unknown key {key!r}; known: {', '.join(known)}"
            )
    try:
        return params_from_config(cls, values, "the")
    except (ValueError, TypeError) as err:
        raise ValueError(f"{where}: section '{section}': {err}") from None


def section_values(config: Mapping[str, Any], section: str, where: str) -> dict[str, Any]:
    """The mapping `config[section]` ({} when absent), or an error naming the file."""
    values = config.get(section)
    if values is None:
        return {}
    if not isinstance(values, Mapping):
        raise ValueError(f"{where}: section '{section}': expected a mapping, got {values!r}")
    return dict(values)


def check_sections(
    config: Mapping[str, Any], known: Iterable[str], where: str, reader: str
) -> None:
    """Every top-level key of `config` is a section `reader` reads, or an error naming it."""
    allowed = sorted(known)
    for key in config:
        if key not in allowed:
            raise ValueError(
                f"{where}: section '{key}': {reader} does not read it; its sections: "
                f"{', '.join(allowed)}"
            )


def _default(field: Any) -> object:
    if field.default is not MISSING:
        return field.default
    if field.default_factory is not MISSING:
        return field.default_factory()
    raise TypeError(f"field {field.name!r} has no default to take its type from")


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
