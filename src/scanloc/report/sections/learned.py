"""Section "Beyond the paper: a learned localizer that localizes": scanloc's learned localizer
per map, beside the paper's networks on the map-1 drive, and the hypotheses of an ambiguous
scan of map 2."""

from __future__ import annotations

import math

import numpy as np

from scanloc.io import read_json
from scanloc.report.artifacts import LOCALIZE_DIRS, TRAJECTORIES, map_yaml, scanlocnet_run
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.paper import AMBIGUOUS_MAP, PAPER_DRIVE
from scanloc.report.render import figures, localization_figures
from scanloc.report.render.document import Block, Builder, Para, Section, Table
from scanloc.report.render.tables import fixed
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.trajectory.format import load_trajectory
from scanloc.world.map_server import load_map

TRAINING_HEADER = [
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
]
DRIVE_HEADER = [
    "localizer",
    "what it is",
    "position mean [m]",
    "median [m]",
    "> 1 m",
    "heading median [°]",
    "top-5 recall",
    "time per scan [ms]",
]


def _training_row(name: str, metrics: dict | None) -> list[str]:
    if metrics is None:
        return [name] + ["not trained"] + ["–"] * 9
    return [
        name,
        str(metrics.get("cells", "–")),
        fixed(metrics.get("train_s"), 0),
        f"{metrics.get('samples_seen', 0):,}",
        fixed(metrics.get("val_pos_err_median_m")),
        fixed(metrics.get("val_heading_err_median_deg"), 2),
        fixed(metrics.get("val_frac_gross_over_1m"), percent=True),
        fixed(metrics.get("val_top1_recall"), percent=True),
        fixed(metrics.get("val_top5_recall"), percent=True),
        fixed(metrics.get("val_top20_recall"), percent=True),
        str(metrics.get("precision", "–")),
    ]


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    b, maps = ctx.builder, ctx.maps
    section = spec.section()
    section.blocks.append(
        Para(
            "Beyond the paper. The paper's networks regress one pose per scan and, at this "
            "profile's scale, stay metres off (Table 2). scanloc's own learned localizer "
            "(scanloc.scanlocnet.model) classifies instead: cells of about 1 m over the map's "
            "free space and heading bins, p(cell, bin | scan) = p(cell | scan) · p(bin | cell, "
            "scan), each hypothesis refined by in-cell and in-bin offsets with predicted standard "
            "deviations. It trains on scans simulated afresh every epoch (same sensor and noise "
            "as the datasets) and returns ranked hypotheses; the k best, after suppressing "
            "near-duplicates, are its output. Validation: the map's own validation scans "
            "(data/scans/<map>_val, drawn as Table 1's validation splits). Top-K recall: the "
            "truth within 0.5 m and 10° of one of the K best hypotheses."
        )
    )
    trained = {name: scanlocnet_run(b.root, name) for name in maps}
    rows = [_training_row(name, metrics) for name, (metrics, _) in trained.items()]
    section.blocks.append(Table(TRAINING_HEADER, rows))
    histories = {n: h for n, (_, h) in trained.items() if h is not None}
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
    paper = ctx.artifacts.localization.get(PAPER_DRIVE, {})
    shown = [m for m in ctx.localizers.learned() if m in paper]
    if shown:
        section.blocks.append(
            Para(
                "On the paper's map-1 drive, side by side with the paper's networks (the same "
                "trajectory and scans; the learned ones are beyond the paper):"
            )
        )
        rows = [
            [
                m,
                ctx.localizers.note(m),
                fixed(paper[m].get("pos_err_mean_m")),
                fixed(paper[m].get("pos_err_median_m")),
                fixed(paper[m].get("frac_gross_over_1m"), percent=True),
                fixed(paper[m].get("heading_err_median_deg"), 2),
                fixed(paper[m].get("top5_recall"), percent=True),
                fixed(1000 * (paper[m].get("time_per_scan_s") or math.nan), 2),
            ]
            for m in shown
        ]
        section.blocks.append(Table(DRIVE_HEADER, rows))
    section.blocks += _ambiguous_scan(b, maps)
    return [section]


def _ambiguous_scan(b: Builder, maps: list[str]) -> list[Block]:
    """The hypotheses of an ambiguous scan of map 2's drive: the best hypothesis wrong, the
    truth among the others (else the scan whose two best are closest in weight)."""
    name = AMBIGUOUS_MAP if AMBIGUOUS_MAP in maps else (maps[-1] if maps else None)
    if name is None:
        return []
    run = f"{name}_drive"
    hyp_path = b.root / LOCALIZE_DIRS[0] / run / "scanlocnet_hypotheses.npz"
    traj_dir = b.root / TRAJECTORIES / run
    grid_yaml = map_yaml(b.root, name)
    if not (hyp_path.is_file() and (traj_dir / "truth.npy").is_file() and grid_yaml.is_file()):
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
    spec = laser_spec_from_config(read_json(traj_dir / "meta.json")["sensor"])
    grid = load_map(grid_yaml)
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
            lambda p: localization_figures.plot_hypotheses(
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


SECTION = SectionSpec(
    "learned-localizer", "Beyond the paper: a learned localizer that localizes", build
)
