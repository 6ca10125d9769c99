"""`key=value` command lines for the bag tools that are not pipeline stages (export_bag,
score_estimates): the stages' syntax, without Hydra, whose config groups `run` and `map`
(conf/run/, conf/map/) would claim the keys `run=` and `map=`."""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence


def parse_key_values(
    prog: str, description: str, argv: Sequence[str] | None, defaults: Mapping[str, str | None]
) -> dict[str, str | None]:
    """{key: value} of `key=value` arguments; keys must be those of `defaults`, and a default
    of "???" marks a required one."""
    parser = argparse.ArgumentParser(
        prog=prog,
        description=description,
        epilog="settings (key=value): "
        + ", ".join(f"{k}={'<required>' if v == '???' else v}" for k, v in defaults.items()),
    )
    parser.add_argument("settings", nargs="*", metavar="key=value")
    args = parser.parse_args(argv)
    values = dict(defaults)
    for item in args.settings:
        key, sep, value = item.partition("=")
        if not sep or key not in defaults:
            parser.error(f"{item!r}: expected key=value with a key of {sorted(defaults)}")
        values[key] = value
    missing = [k for k, v in values.items() if v == "???"]
    if missing:
        parser.error(f"missing required setting(s): {', '.join(f'{k}=...' for k in missing)}")
    return values
