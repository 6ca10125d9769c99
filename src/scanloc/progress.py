"""Progress a user can see: bars on a terminal, one plain line per step when not (CI, DVC's
logs), so a long stage never sits silent and a log never fills with carriage returns."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator, Mapping, Sized
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")


def interactive() -> bool:
    """True on a terminal: bars there, lines elsewhere."""
    return sys.stderr.isatty()


def duration(seconds: float) -> str:
    """12 s, 3 min 05 s, 1 h 02 min: readable at a glance in a log."""
    seconds = max(0.0, float(seconds))
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes, secs = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


def step_line(
    label: str, done: int, total: int, elapsed_s: float, values: Mapping[str, str] = {}
) -> str:
    """`label done/total: key value, ... (elapsed, ~expected to go)`; the time still to go is
    the mean time per step so far times the steps left."""
    remaining = elapsed_s / done * (total - done) if done else float("nan")
    parts = ", ".join(f"{key} {value}" for key, value in values.items())
    to_go = f", ~{duration(remaining)} to go" if done < total and done else ""
    return (
        f"{label} {done}/{total}"
        + (f": {parts}" if parts else "")
        + (f" ({duration(elapsed_s)} elapsed{to_go})")
    )


def print_line(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def steps(items: Iterable[T], label: str, total: int | None = None) -> Iterator[T]:
    """Iterate with a bar on a terminal, or a line per item when not."""
    if total is None and isinstance(items, Sized):
        total = len(items)
    if interactive():
        yield from tqdm(items, desc=label, total=total, file=sys.stderr)
        return
    for item in items:
        print_line(f"{label}: {item}")
        yield item
