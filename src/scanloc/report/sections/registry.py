"""The report's sections, listed once, in the order the report shows them."""

from __future__ import annotations

from scanloc.report.context import SectionSpec
from scanloc.report.sections import (
    claims,
    curves,
    global_localization,
    learned,
    localization,
    maps,
    provenance,
    real_learned,
    sites,
    table1,
    table2,
)

SECTIONS: tuple[SectionSpec, ...] = (
    maps.SECTION,
    table1.SECTION,
    curves.SECTION,
    localization.SECTION,
    table2.SECTION,
    claims.SECTION,
    learned.SECTION,
    global_localization.SECTION,
    real_learned.SECTION,
    sites.SECTION,  # one per site: map, log or bag (params.yaml)
    provenance.SECTION,
)
