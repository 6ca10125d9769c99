"""Which localizers the report's tables list, and what it says of each: read from the one list
of localizers (conf/localizer/*.yaml, scanloc.localize.catalog), never from a copy.

Every selection is in the report's one order (scanloc.evaluate.table2.ordered_methods: the
paper's three first, the others by name), the order of Table 2.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from scanloc.evaluate.table2 import ordered_methods
from scanloc.localize.catalog import CONF_DIR, LocalizerInfo, load_catalog

MISSING_NOTE = "–"


@dataclass(frozen=True)
class Localizers:
    """The catalog of localizer configs, by name, and the report's selections of it."""

    catalog: Mapping[str, LocalizerInfo]

    @classmethod
    def load(cls, conf_dir: Path = CONF_DIR) -> Localizers:
        return cls(load_catalog(conf_dir))

    def note(self, name: str) -> str:
        """The config's one line for the report ('–' for an estimate table without a config)."""
        info = self.catalog.get(name)
        return info.note if info else MISSING_NOTE

    def global_table(self) -> list[str]:
        """The localizers the global-localization table lists (`global_table: true`)."""
        return ordered_methods([n for n, info in self.catalog.items() if info.global_table])

    def of_stage(self, stage: str) -> list[str]:
        """The localizers a pipeline stage runs (`localize` also runs on every real log)."""
        return ordered_methods([n for n, info in self.catalog.items() if stage in info.stages])

    def learned(self) -> list[str]:
        """The learned localizers that a pipeline stage runs (group `learned`)."""
        return ordered_methods(
            [n for n, info in self.catalog.items() if info.group == "learned" and info.stages]
        )
