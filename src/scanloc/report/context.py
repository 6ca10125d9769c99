"""What every section of the report is built from, and what a section is to the registry."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from scanloc.report.artifacts import Artifacts
from scanloc.report.claims import Verdict
from scanloc.report.localizers import Localizers
from scanloc.report.paper import MAP1
from scanloc.report.render.document import Builder, Section


@dataclass(frozen=True)
class ReportContext:
    """The figure writer, the loaded artifacts, the localizer catalog, the claims' verdicts
    and their legend, and the run's context: {"profile", "params" (the run's knobs),
    "git_commit", "sites" ({site: kind}, in order)}."""

    builder: Builder
    artifacts: Artifacts
    localizers: Localizers
    verdicts: list[Verdict]
    legend: Mapping[str, str]
    run: Mapping[str, Any]
    figure_localizers: list[str]  # the localizers drawn over a map (conf/report.yaml)
    # {kind: the runs a site section tabulates, its first drawn over the map} (conf/report.yaml)
    site_runs: Mapping[str, list[str]] = field(default_factory=dict)

    @property
    def sites(self) -> dict[str, str]:
        """{site: kind} in the run's order (the paper's map 1 alone when the run names none)."""
        return dict(self.run.get("sites") or {MAP1: "map"})

    def of_kind(self, kind: str) -> list[str]:
        return [site for site, of in self.sites.items() if of == kind]

    @property
    def maps(self) -> list[str]:
        return self.of_kind("map")

    @property
    def real_logs(self) -> list[str]:
        return self.of_kind("log")

    @property
    def profile(self) -> str:
        return str(self.run.get("profile", "?"))


@dataclass(frozen=True)
class SectionSpec:
    """One entry of the report's registry: its id and title (a per-map section's with a
    `{name}` placeholder) and what builds it (one section, or one per map)."""

    id: str
    title: str
    build: Callable[[ReportContext, SectionSpec], list[Section]]

    def section(self, **names: str) -> Section:
        """An empty section with this entry's id and title (placeholders filled in)."""
        return Section(self.id.format(**names), self.title.format(**names))
