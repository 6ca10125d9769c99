"""The one error a bad bag raises: it names the bag, the topic and what was expected."""

from __future__ import annotations

from pathlib import Path


class BagError(ValueError):
    """A bag that cannot become a scanloc run (or an estimate stream)."""

    def __init__(self, bag: str | Path, topic: str, problem: str) -> None:
        self.bag, self.topic = str(bag), topic
        super().__init__(f"{bag}: topic {topic}: {problem}")
