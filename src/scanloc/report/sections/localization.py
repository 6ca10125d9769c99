"""Section "Localization": every localizer on the paper's drive through map 1 (paper §4.4,
Fig. 10), its estimates over the map, its errors over time and its uncertainty."""

from __future__ import annotations

from scanloc.evaluate.table2 import METHOD_ORDER
from scanloc.report.artifacts import TRAJECTORIES
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.paper import MAP1, PAPER_DRIVE
from scanloc.report.render import localization_figures as figures
from scanloc.report.render.document import Para, Section, Table
from scanloc.report.render.tables import num

COVARIANCE = {"cov_xx", "cov_xy", "cov_yy"}


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    b, truth, tables = ctx.builder, ctx.artifacts.truth, ctx.artifacts.tables
    grid = ctx.artifacts.grid(MAP1)
    section = spec.section()
    absent = [m for m in METHOD_ORDER if m not in tables]
    section.blocks.append(
        Para(
            f"The robot drives {len(truth)} steps through map 1 "
            f"({(TRAJECTORIES / PAPER_DRIVE).as_posix()}). Each localizer estimates every "
            "step's pose: amcl from the scans and odometry, the CNNs from each step's scan alone."
        )
    )
    if absent:
        section.blocks.append(
            Para(f"Not available: {', '.join(absent)} (no reports/localize/<method>.csv).")
        )
    if not tables:
        return [section]
    rows = []
    for name, table in tables.items():
        valid = table[["x", "y", "theta"]].notna().all(axis=1)
        hypotheses = table["n_particles"].median() if "n_particles" in table else None
        rows.append(
            [
                name,
                ctx.localizers.note(name),
                f"{int(valid.sum())} / {len(table)}",
                num(None if hypotheses is None else float(hypotheses), 4),
            ]
        )
    section.blocks.append(
        Table(["method", "what it is", "steps with an estimate", "median hypotheses"], rows)
    )
    section.blocks.append(
        b.figure(
            "fig10_trajectories.png",
            "Paper Fig. 10: position estimates (red) against the true path (blue), one "
            "panel per localizer.",
            lambda p: figures.plot_trajectories(grid, truth, tables, p),
        )
    )
    section.blocks.append(
        b.figure(
            "errors_over_time.png",
            "Position and heading error along the trajectory (log scale).",
            lambda p: figures.plot_errors_over_time(truth, tables, p),
        )
    )
    with_cov = {
        n: t
        for n, t in tables.items()
        if COVARIANCE <= set(t.columns) and t["cov_xx"].notna().any()
    }
    if with_cov:
        section.blocks.append(
            b.figure(
                "uncertainty.png",
                "Uncertainty: 2σ ellipses of the position covariance "
                "(ensemble: spread of the members; amcl: particle cloud) along the path; "
                "a calibrated 2σ ellipse holds the truth 86.5 % of the time.",
                lambda p: figures.plot_uncertainty(grid, truth, with_cov, p),
            )
        )
    return [section]


SECTION = SectionSpec("localization", "Localization", build)
