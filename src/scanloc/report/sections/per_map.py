"""Sections "Map <name>", one per map of params.yaml `maps`: the map, its drive's estimates
over it, and Table 2, the modern and the global metrics of its drive and kidnap runs."""

from __future__ import annotations

from scanloc.evaluate.table2 import GLOBAL_COLUMNS, MODERN_COLUMNS, TABLE2_COLUMNS, format_rows
from scanloc.report.artifacts import TRAJECTORIES, estimate_tables, map_yaml
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.render import localization_figures as figures
from scanloc.report.render.document import Para, Section, Table
from scanloc.trajectory.format import load_trajectory
from scanloc.world.map_server import load_map

RUNS = ("drive", "kidnap")


def map_section(ctx: ReportContext, spec: SectionSpec, name: str) -> Section:
    b = ctx.builder
    section = spec.section(name=name)
    grid_yaml = map_yaml(b.root, name)
    if grid_yaml.is_file():
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
        drive_dir = b.root / TRAJECTORIES / f"{name}_drive"
        tables = estimate_tables(b.root, f"{name}_drive", ctx.figure_localizers)
        if tables and (drive_dir / "truth.npy").is_file():
            traj, _ = load_trajectory(drive_dir)
            section.blocks.append(
                b.figure(
                    f"trajectories_{name}.png",
                    f"{name}_drive: position estimates (red) against the true path (blue).",
                    lambda p, grid=grid, traj=traj, tables=tables: figures.plot_trajectories(
                        grid, traj.truth, tables, p
                    ),
                )
            )
    else:
        section.blocks.append(Para(f"{name}: map not available (data/maps/{name}/map.yaml)."))
    for run in RUNS:
        metrics = ctx.artifacts.localization.get(f"{name}_{run}")
        if not metrics:
            section.blocks.append(Para(f"{name}_{run}: not evaluated."))
            continue
        section.blocks.append(Para(f"Trajectory {name}_{run}: Table 2 and the modern metrics."))
        section.blocks.append(Table(*format_rows(metrics, TABLE2_COLUMNS)))
        section.blocks.append(Table(*format_rows(metrics, MODERN_COLUMNS)))
        section.blocks.append(Table(*format_rows(metrics, GLOBAL_COLUMNS)))
    return section


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    return [map_section(ctx, spec, name) for name in ctx.maps]


SECTION = SectionSpec("map-{name}", "Map {name}", build)
