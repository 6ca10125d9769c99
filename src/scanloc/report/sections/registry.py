"""The report's sections, listed once, in the order the report shows them."""

from __future__ import annotations

from scanloc.report.context import SectionSpec
from scanloc.report.sections import (
    bags,
    claims,
    curves,
    global_localization,
    learned,
    localization,
    maps,
    per_map,
    provenance,
    real_data,
    real_learned,
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
    real_data.SECTION,
    real_learned.SECTION,
    per_map.SECTION,  # one per map of params.yaml `maps`
    bags.SECTION,  # one block per params.yaml `bags` entry
    provenance.SECTION,
)
