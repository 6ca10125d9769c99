"""Sections "Site <name> (<kind>)", one per site of the run (the report stage's `sites`, in
params.yaml's order): what every site shows, and what its kind adds.

Every site: its map (size and cells), the estimates of its first run over the map against the
truth, and Table 2, the modern and the global metrics of each run its kind tabulates
(conf/report.yaml `site_runs`). A log adds its split, its real run against its simulated twin
and its runs over filter seeds (real_data.py); a bag adds where its map came from and, without
truth, its localizers' agreement and speed in place of the tables (bags.py).
"""

from __future__ import annotations

from collections.abc import Callable

from scanloc.evaluate.table2 import (
    GLOBAL_COLUMNS,
    MODERN_COLUMNS,
    TABLE2_COLUMNS,
    TIME_COLUMN,
    format_rows,
)
from scanloc.report.artifacts import TRAJECTORIES, estimate_tables, map_yaml
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.render import localization_figures as figures
from scanloc.report.render.document import Para, Section, Table
from scanloc.report.sections.bags import bag_blocks
from scanloc.report.sections.real_data import log_blocks
from scanloc.trajectory.format import load_trajectory
from scanloc.world.map_server import load_map

# What a kind adds before the run tables; False: its runs cannot be scored (no truth).
KIND_BLOCKS: dict[str, Callable[[ReportContext, Section, str], bool]] = {
    "log": log_blocks,
    "bag": bag_blocks,
}


def _map_blocks(ctx: ReportContext, section: Section, name: str, first_run: str) -> None:
    b = ctx.builder
    grid_yaml = map_yaml(b.root, name)
    if not grid_yaml.is_file():
        section.blocks.append(Para(f"{name}: map not available (data/maps/{name}/map.yaml)."))
        return
    grid = load_map(grid_yaml)
    width, height = grid.size_m
    counts = grid.counts()
    section.blocks.append(
        Para(
            f"{name}: {width:.2f} × {height:.2f} m at {grid.resolution:g} m "
            f"({grid.width} × {grid.height} cells; free {counts['free']:,}, occupied "
            f"{counts['occupied']:,}, unknown {counts['unknown']:,})."
        )
    )
    run_dir = b.root / TRAJECTORIES / first_run
    tables = estimate_tables(b.root, first_run, ctx.figure_localizers)
    if tables and (run_dir / "truth.npy").is_file():
        traj, _ = load_trajectory(run_dir)
        section.blocks.append(
            b.figure(
                f"site_{name}.png",
                f"{first_run}: position estimates (red) against the true path (blue).",
                lambda p, grid=grid, traj=traj, tables=tables: figures.plot_trajectories(
                    grid, traj.truth, tables, p
                ),
            )
        )


def site_section(ctx: ReportContext, spec: SectionSpec, name: str, kind: str) -> Section:
    section = spec.section(name=name, kind=kind)
    runs = [f"{name}_{run}" for run in ctx.site_runs[kind]]
    _map_blocks(ctx, section, name, runs[0])
    kind_blocks = KIND_BLOCKS.get(kind)
    if kind_blocks is not None and not kind_blocks(ctx, section, name):
        return section
    for run in runs:
        metrics = ctx.artifacts.localization.get(run)
        if not metrics:
            section.blocks.append(Para(f"{run}: not evaluated."))
            continue
        section.blocks.append(
            Para(f"Run {run}: Table 2, the modern metrics with the time per scan, the global ones.")
        )
        section.blocks.append(Table(*format_rows(metrics, TABLE2_COLUMNS)))
        section.blocks.append(Table(*format_rows(metrics, (*MODERN_COLUMNS, TIME_COLUMN))))
        section.blocks.append(Table(*format_rows(metrics, GLOBAL_COLUMNS)))
    return section


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    return [site_section(ctx, spec, name, kind) for name, kind in ctx.sites.items()]


SECTION = SectionSpec("site-{name}", "Site {name} ({kind})", build)
