"""Section "Table 2": the paper's error table of the localizers on the map-1 drive, and the
modern metrics beside it."""

from __future__ import annotations

from scanloc.evaluate.table2 import (
    MODERN_COLUMNS,
    TABLE2_COLUMNS,
    TABLE2_NOTE,
    TIME_COLUMN,
    format_rows,
)
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.render.document import Para, Section, Table


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    metrics = ctx.artifacts.paper_metrics
    section = spec.section()
    section.blocks.append(
        Para(f"Paper Table 2 (its numbers were lost; layout as described). {TABLE2_NOTE}")
    )
    section.blocks.append(Table(*format_rows(metrics, TABLE2_COLUMNS)))
    section.blocks.append(
        Para(
            "Modern metrics: position error = Euclidean distance; heading error wrapped to "
            "±180° (unlike the sine difference it tells θ from 180° − θ); shares of steps "
            "within 0.1 / 0.25 / 0.5 m and gross failures beyond 1 m; calibration = share of "
            "steps whose true position lies inside the 1σ / 2σ ellipse of the estimate's "
            "position covariance (a calibrated Gaussian: 39.3 % / 86.5 %; the single CNN has "
            "no covariance). Time per scan is measured on the machine that ran the localize stage "
            "(reports/localize_timing/, outside the hashed metrics)."
        )
    )
    section.blocks.append(Table(*format_rows(metrics, (*MODERN_COLUMNS, TIME_COLUMN))))
    return [section]


SECTION = SectionSpec("table-2", "Table 2", build)
