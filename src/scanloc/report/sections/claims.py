"""Section "Paper claims": each finding of the paper, its numbers, ours, the verdict and the
rule that gave it (scanloc.report.claims), after the legend of the verdicts."""

from __future__ import annotations

from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.render.document import Para, Section, Table
from scanloc.report.verdicts import VERDICT_CLASSES


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    section = spec.section()
    section.blocks.append(
        Para(
            "Each finding of the paper (Section 4), what the paper reports, what we measured, "
            "and the verdict by the rule in the last column (its thresholds: "
            "conf/report.yaml). Our runs are scaled down by the profile (see Table 1), so "
            "numbers measured at a smaller scale are not expected to match the paper's; the "
            "verdict says so rather than excusing it. 'margins and spread' gives each margin "
            "the verdict rests on, its threshold and the band around it that the rows' seed "
            "spread, measured in this run, sets; the last column, the scale at which the "
            "`paper` profile tests the claim. Verdicts:"
        )
    )
    section.blocks.append(
        Table(
            ["verdict", "meaning"],
            [[name, meaning] for name, meaning in ctx.legend.items()],
            [VERDICT_CLASSES[name] for name in ctx.legend],
        )
    )
    header = ["#", "paper's claim", "paper", "ours", "margins and spread", "verdict", "rule"]
    header.append("scale of the paper profile")
    rows = [
        [
            str(v.number),
            v.paper,
            v.paper_figure,
            v.ours,
            "; ".join(c.text() for c in v.comparisons) or "–",
            v.verdict,
            v.rule,
            v.paper_scale,
        ]
        for v in ctx.verdicts
    ]
    classes = [VERDICT_CLASSES[v.verdict] for v in ctx.verdicts]
    section.blocks.append(Table(header, rows, classes))
    return [section]


SECTION = SectionSpec("paper-claims", "Paper claims", build)
