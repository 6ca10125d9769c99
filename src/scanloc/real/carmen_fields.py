"""One CARMEN log line read field by field, with errors that name file, line and field."""

from __future__ import annotations

import numpy as np


class CarmenFormatError(ValueError):
    """A line that breaks the CARMEN log format; the message names file, line and field."""


class LineFields:
    """The fields of one line, read left to right; errors name file, line number and field."""

    def __init__(self, where: str, tokens: list[str]) -> None:
        self.where = where
        self.tag = tokens[0]
        self.tokens = tokens
        self.pos = 1
        self.last = self.tag

    def error(self, name: str, expected: str, got: object) -> CarmenFormatError:
        return CarmenFormatError(
            f"{self.where}: {self.tag} field '{name}': expected {expected}, got {got!r}"
        )

    def _missing(self, name: str) -> CarmenFormatError:
        return CarmenFormatError(
            f"{self.where}: {self.tag} field '{name}': missing (the line ends after "
            f"{len(self.tokens)} fields)"
        )

    def word(self, name: str) -> str:
        if self.pos >= len(self.tokens):
            raise self._missing(name)
        self.pos += 1
        self.last = name
        return self.tokens[self.pos - 1]

    def number(self, name: str) -> float:
        token = self.word(name)
        try:
            return float(token)
        except ValueError:
            raise self.error(name, "a number", token) from None

    def count(self, name: str) -> int:
        token = self.word(name)
        try:
            value = int(token)
        except ValueError:
            raise self.error(name, "a count (a whole number >= 0)", token) from None
        if value < 0:
            raise self.error(name, "a count (a whole number >= 0)", token)
        return value

    def numbers(self, n: int, prefix: str) -> np.ndarray:
        """n numbers named prefix1 … prefixn."""
        chunk = self.tokens[self.pos : self.pos + n]
        if len(chunk) < n:
            raise self._missing(f"{prefix}{len(chunk) + 1}")
        try:
            values = np.fromiter(map(float, chunk), dtype=np.float64, count=n)
        except ValueError:
            for k, token in enumerate(chunk):
                try:
                    float(token)
                except ValueError:
                    raise self.error(f"{prefix}{k + 1}", "a number", token) from None
            raise
        self.pos += n
        self.last = f"{prefix}{n}" if n else self.last
        return values

    def timestamp(self) -> float:
        """`ipc_hostname [logger_timestamp]` after the ipc timestamp: the time to use."""
        ipc = self.number("ipc_timestamp")
        self.word("ipc_hostname")
        logger = self.number("logger_timestamp") if self.pos < len(self.tokens) else ipc
        if self.pos < len(self.tokens):
            raise CarmenFormatError(
                f"{self.where}: {self.tag}: {len(self.tokens) - self.pos} field(s) after field "
                f"'{self.last}', the last one, starting with {self.tokens[self.pos]!r}"
            )
        return logger
