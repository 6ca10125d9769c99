"""Section "Global localization and kidnapping": on every map, the localizers of the catalog's
global table (`global_table: true`) on the drive and the kidnap trajectory."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from scanloc.evaluate.table2 import GLOBAL_NOTE
from scanloc.report.artifacts import TRAJECTORIES, estimate_tables
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.render import localization_figures as figures
from scanloc.report.render.document import Para, Section, Table
from scanloc.report.render.tables import converge_text, fixed, recovery_text
from scanloc.trajectory.format import load_trajectory

HEADER = [
    "map",
    "localizer",
    "steps to converge (drive)",
    "steps to converge (kidnap)",
    "recovery steps (max)",
    "recovery steps (mean)",
    "kidnaps recovered",
    "tracking error mean (drive) [m]",
    "tracking heading mean (drive) [°]",
    "lost > 1 m (kidnap)",
]


def _rows(name: str, methods: list[str], localization: Mapping[str, Any]) -> list[list[str]]:
    drive = localization.get(f"{name}_drive", {})
    kidnap = localization.get(f"{name}_kidnap", {})
    rows = []
    for method in methods:
        d, k = drive.get(method), kidnap.get(method)
        if d is None and k is None:
            continue
        d, k = d or {}, k or {}
        rows.append(
            [
                name,
                method,
                converge_text(d),
                converge_text(k),
                recovery_text(k, "recovery_steps_max") if k.get("kidnaps") else "–",
                recovery_text(k, "recovery_steps_mean", 1) if k.get("kidnaps") else "–",
                f"{k.get('recovered', 0):.0f} / {k.get('kidnaps', 0):.0f}" if k else "–",
                fixed(d.get("tracking_pos_err_mean_m")),
                fixed(d.get("tracking_heading_err_mean_deg"), 2),
                fixed(k.get("frac_lost"), percent=True),
            ]
        )
    return rows


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    b, methods = ctx.builder, ctx.localizers.global_table()
    section = spec.section()
    section.blocks.append(
        Para(
            "Beyond the paper. Each map has a drive trajectory and a kidnap trajectory (the same "
            "route generator; at fixed fractions of the run the robot is carried to a random "
            "free pose while its odometry sees nothing). amcl tracks from the true first pose; "
            "amcl_global and amcl_recovery start without a pose (recovery off / on); "
            "scanlocnet_track and hybrid start from the learned localizer's first scan. "
            f"{GLOBAL_NOTE}"
        )
    )
    rows = [row for name in ctx.maps for row in _rows(name, methods, ctx.artifacts.localization)]
    section.blocks.append(Table(HEADER, rows))
    for name in ctx.maps:
        run = f"{name}_kidnap"
        traj_dir = b.root / TRAJECTORIES / run
        tables = estimate_tables(b.root, run, methods)
        if not tables or not (traj_dir / "truth.npy").is_file():
            section.blocks.append(Para(f"{run}: no trajectory or localizer tables."))
            continue
        traj, _ = load_trajectory(traj_dir)
        kidnap_times = tuple(float(traj.times[k]) for k in traj.kidnap_steps)
        section.blocks.append(
            b.figure(
                f"kidnap_errors_{name}.png",
                f"{run}: position and heading error over time; dashed lines: kidnaps.",
                lambda p, traj=traj, tables=tables, kt=kidnap_times, run=run: (
                    figures.plot_errors_over_time(traj.truth, tables, p, kt, run)
                ),
            )
        )
    return [section]


SECTION = SectionSpec("global-localization", "Global localization and kidnapping", build)
