"""The report's sections beyond the paper: scanloc's learned localizer next to the paper's
networks, global localization and kidnapping, and one section per map of params.yaml `maps`.

Everything is read from the artifact tree (layout in build.py and below); artifacts of a map
that are missing are named in its section rather than failing the report.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from scanloc.evaluate.table2 import (
    GLOBAL_COLUMNS,
    GLOBAL_NOTE,
    MODERN_COLUMNS,
    TABLE2_COLUMNS,
    format_rows,
)
from scanloc.io import read_json
from scanloc.report import figures
from scanloc.report.build import LOCALIZE_DIRS, METHOD_NOTES, METRICS_DIR, SECTIONS, TRAJECTORIES
from scanloc.report.document import Builder, Para, Section, Table
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.trajectory.format import load_trajectory
from scanloc.world.map_server import load_map

LEARNED = ("scanlocnet", "scanlocnet_track")
PAPER_CNNS = ("cnn_single", "cnn_ensemble", "cnn_ekf")
GLOBAL_METHODS = ("amcl", "amcl_global", "amcl_recovery", "scanlocnet_track", "hybrid")
RUNS = ("drive", "kidnap")
AMBIGUOUS_MAP = "simple_rooms"  # paper map 2, the symmetric one


def fmt_value(value: Any, digits: int = 3, percent: bool = False) -> str:
    if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return "–"
    if not math.isfinite(value):
        return "–"
    return f"{100 * value:.1f} %" if percent else f"{value:.{digits}f}"


def _scanlocnet_run(root: Path, map_name: str) -> tuple[dict | None, pd.DataFrame | None]:
    metrics_path = root / METRICS_DIR / f"scanlocnet_{map_name}.json"
    history_path = root / "models" / "scanlocnet" / map_name / "history.csv"
    metrics = read_json(metrics_path) if metrics_path.is_file() else None
    history = pd.read_csv(history_path) if history_path.is_file() else None
    return metrics, history


def learned_section(b: Builder, maps: list[str], all_metrics: Mapping[str, Any]) -> Section:
    section = Section(*SECTIONS[6])
    section.blocks.append(
        Para(
            "Beyond the paper. The paper's networks regress one pose per scan and, at this "
            "profile's scale, stay metres off (Table 2). scanloc's own learned localizer "
            "(scanloc.models.scanlocnet) classifies instead: cells of about 1 m over the map's "
            "free space and heading bins, p(cell, bin | scan) = p(cell | scan) · p(bin | cell, "
            "scan), each hypothesis refined by in-cell and in-bin offsets with predicted standard "
            "deviations. It trains on scans simulated afresh every epoch (same sensor and noise "
            "as the datasets) and returns ranked hypotheses; the k best, after suppressing "
            "near-duplicates, are its output. Validation: the map's own validation scans "
            "(data/scans/<map>_val, drawn as Table 1's validation splits). Top-K recall: the "
            "truth within 0.5 m and 10° of one of the K best hypotheses."
        )
    )
    rows = []
    for name in maps:
        metrics, _ = _scanlocnet_run(b.root, name)
        if metrics is None:
            rows.append([name] + ["not trained"] + ["–"] * 9)
            continue
        rows.append(
            [
                name,
                str(metrics.get("cells", "–")),
                fmt_value(metrics.get("train_s"), 0),
                f"{metrics.get('samples_seen', 0):,}",
                fmt_value(metrics.get("val_pos_err_median_m")),
                fmt_value(metrics.get("val_heading_err_median_deg"), 2),
                fmt_value(metrics.get("val_frac_gross_over_1m"), percent=True),
                fmt_value(metrics.get("val_top1_recall"), percent=True),
                fmt_value(metrics.get("val_top5_recall"), percent=True),
                fmt_value(metrics.get("val_top20_recall"), percent=True),
                str(metrics.get("precision", "–")),
            ]
        )
    section.blocks.append(
        Table(
            [
                "map",
                "cells",
                "training [s]",
                "scans seen",
                "val. position median [m]",
                "heading median [°]",
                "> 1 m",
                "top-1 recall",
                "top-5 recall",
                "top-20 recall",
                "precision",
            ],
            rows,
        )
    )
    histories = {n: h for n in maps if (h := _scanlocnet_run(b.root, n)[1]) is not None}
    if histories:
        section.blocks.append(
            b.figure(
                "scanlocnet_history.png",
                "Training of the learned localizer per map: validation position error (median "
                "of the best hypothesis) and top-5 recall per epoch.",
                lambda p: figures.plot_columns(
                    histories,
                    {
                        "val_pos_err_median_m": "val. median position error [m]",
                        "val_top5_recall": "val. top-5 recall",
                    },
                    p,
                ),
            )
        )
    paper = all_metrics.get("sparse_obstacles_drive", {})
    shown = [m for m in (*PAPER_CNNS, *LEARNED) if m in paper]
    if shown:
        section.blocks.append(
            Para(
                "On the paper's map-1 drive, side by side with the paper's networks (the same "
                "trajectory and scans; the learned ones are beyond the paper):"
            )
        )
        section.blocks.append(
            Table(
                [
                    "localizer",
                    "what it is",
                    "position mean [m]",
                    "median [m]",
                    "> 1 m",
                    "heading median [°]",
                    "top-5 recall",
                    "time per scan [ms]",
                ],
                [
                    [
                        m,
                        METHOD_NOTES.get(m, "–"),
                        fmt_value(paper[m].get("pos_err_mean_m")),
                        fmt_value(paper[m].get("pos_err_median_m")),
                        fmt_value(paper[m].get("frac_gross_over_1m"), percent=True),
                        fmt_value(paper[m].get("heading_err_median_deg"), 2),
                        fmt_value(paper[m].get("top5_recall"), percent=True),
                        fmt_value(1000 * (paper[m].get("time_per_scan_s") or math.nan), 2),
                    ]
                    for m in shown
                ],
            )
        )
    section.blocks += _ambiguous_scan(b, maps)
    return section


def _ambiguous_scan(b: Builder, maps: list[str]) -> list:
    """The hypotheses of an ambiguous scan of map 2's drive: the best hypothesis wrong, the
    truth among the others (else the scan whose two best are closest in weight)."""
    name = AMBIGUOUS_MAP if AMBIGUOUS_MAP in maps else (maps[-1] if maps else None)
    if name is None:
        return []
    run = f"{name}_drive"
    hyp_path = b.root / LOCALIZE_DIRS[0] / run / "scanlocnet_hypotheses.npz"
    traj_dir = b.root / TRAJECTORIES / run
    map_yaml = b.root / "data" / "maps" / name / "map.yaml"
    if not (hyp_path.is_file() and (traj_dir / "truth.npy").is_file() and map_yaml.is_file()):
        return [Para(f"Hypotheses of an ambiguous scan: not available ({run}).")]
    with np.load(hyp_path) as data:
        poses, weights = data["poses"], data["weights"]
    traj, ranges = load_trajectory(traj_dir)
    truth = traj.truth
    pos = np.hypot(*(poses[:, :, :2] - truth[:, None, :2]).transpose(2, 0, 1))
    ang = np.degrees(np.abs(np.angle(np.exp(1j * (poses[:, :, 2] - truth[:, None, 2])))))
    near = (pos <= 0.5) & (ang <= 10.0)
    ambiguous = np.flatnonzero(~near[:, 0] & near[:, 1:5].any(axis=1))
    if len(ambiguous):
        step = int(ambiguous[0])
        why = "its best hypothesis is elsewhere, the truth is among the next four"
    else:
        ratio = weights[:, 1] / np.maximum(weights[:, 0], 1e-300)
        step = int(np.argmax(ratio))
        why = "its two best hypotheses are the closest in weight"
    meta = read_json(traj_dir / "meta.json")
    spec = laser_spec_from_config(meta["sensor"])
    grid = load_map(map_yaml)
    caption = (
        f"The learned localizer's ranked hypotheses (red arrows, longer = heavier, numbered by "
        f"rank) for step {step} of the {run} trajectory, a scan chosen because {why}; blue: "
        "the true pose, pink: the scan drawn from it. The map's symmetry makes several poses "
        "explain the same scan."
    )
    return [
        b.figure(
            "ambiguous_scan_hypotheses.png",
            caption,
            lambda p: figures.plot_hypotheses(
                grid,
                truth[step],
                ranges[step].astype(np.float64),
                spec.beam_angles(),
                spec.range_max,
                poses[step, :5],
                weights[step, :5],
                p,
                f"{name}: step {step}, 5 best hypotheses",
            ),
        )
    ]


def converge_text(metrics: Mapping[str, Any]) -> str:
    """Steps to converge, or 'never (N steps)' for a censored count."""
    steps = metrics.get("steps_to_converge")
    if steps is None:
        return "–"
    return f"{steps:.0f}" if metrics.get("converged", 1) else f"never ({steps:.0f} steps)"


def recovery_text(metrics: Mapping[str, Any], key: str, digits: int = 0) -> str:
    """A recovery figure, marked '≥' when some kidnap never recovered (censored counts)."""
    value = metrics.get(key)
    if value is None:
        return "–"
    censored = metrics.get("recovered", 0) < metrics.get("kidnaps", 0)
    return ("≥ " if censored else "") + f"{value:.{digits}f}"


def _global_rows(name: str, all_metrics: Mapping[str, Any]) -> list[list[str]]:
    drive = all_metrics.get(f"{name}_drive", {})
    kidnap = all_metrics.get(f"{name}_kidnap", {})
    rows = []
    for method in GLOBAL_METHODS:
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
                fmt_value(d.get("tracking_pos_err_mean_m")),
                fmt_value(d.get("tracking_heading_err_mean_deg"), 2),
                fmt_value(k.get("frac_lost"), percent=True),
            ]
        )
    return rows


def global_section(b: Builder, maps: list[str], all_metrics: Mapping[str, Any]) -> Section:
    section = Section(*SECTIONS[7])
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
    rows = [row for name in maps for row in _global_rows(name, all_metrics)]
    section.blocks.append(
        Table(
            [
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
            ],
            rows,
        )
    )
    for name in maps:
        run = f"{name}_kidnap"
        traj_dir = b.root / TRAJECTORIES / run
        tables = estimate_tables(b.root, run, GLOBAL_METHODS)
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
    return section


def estimate_tables(root: Path, run: str, methods: tuple[str, ...]) -> dict[str, pd.DataFrame]:
    found = {}
    for method in methods:
        for folder in LOCALIZE_DIRS:
            path = root / folder / run / f"{method}.csv"
            if path.is_file():
                found[method] = pd.read_csv(path)
    return found


def map_section(b: Builder, name: str, all_metrics: Mapping[str, Any]) -> Section:
    section = Section(f"map-{name}", f"Map {name}")
    map_yaml = b.root / "data" / "maps" / name / "map.yaml"
    if map_yaml.is_file():
        grid = load_map(map_yaml)
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
        tables = estimate_tables(b.root, f"{name}_drive", ("amcl", "scanlocnet", "hybrid"))
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
        metrics = all_metrics.get(f"{name}_{run}")
        if not metrics:
            section.blocks.append(Para(f"{name}_{run}: not evaluated."))
            continue
        section.blocks.append(Para(f"Trajectory {name}_{run}: Table 2 and the modern metrics."))
        section.blocks.append(Table(*format_rows(metrics, TABLE2_COLUMNS)))
        section.blocks.append(Table(*format_rows(metrics, MODERN_COLUMNS)))
        section.blocks.append(Table(*format_rows(metrics, GLOBAL_COLUMNS)))
    return section
