"""The report's figures of localizer estimates (paper Fig. 10 and our additions): estimates
over the map, errors along a trajectory, covariance ellipses, ranked hypotheses; same
conventions as figures.py (own Agg canvas, deterministic PNG bytes)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

from scanloc.estimates import table_poses
from scanloc.pose import wrap_angle
from scanloc.report.render.figures import (
    ESTIMATE_COLOR,
    TRUTH_COLOR,
    colors_for,
    draw_map,
    map_extent,
    new_figure,
    save_png,
)
from scanloc.world.occupancy_grid import OccupancyGrid


def _panel_grid(fig: Figure, count: int):
    cols = min(count, 3)
    rows = -(-count // cols)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False).ravel())
    for ax in axes[count:]:
        ax.set_visible(False)
    return axes[:count]


def plot_trajectories(
    grid: OccupancyGrid, truth: np.ndarray, tables: Mapping[str, pd.DataFrame], path: Path
) -> Path:
    """Paper Fig. 10: each localizer's position estimates (red) over the map against the true
    path (blue), one panel per localizer."""
    count = len(tables)
    if count == 0:
        raise ValueError("no estimate tables to plot")
    cols = min(count, 3)
    fig = new_figure(4.6 * cols, 4.6 * -(-count // cols) + 0.3)
    left, right, bottom, top = map_extent(grid)
    for ax, (name, table) in zip(_panel_grid(fig, count), tables.items(), strict=True):
        draw_map(ax, grid)
        ax.plot(truth[:, 0], truth[:, 1], "o-", color=TRUTH_COLOR, ms=2.5, lw=0.6, label="truth")
        ax.plot(
            table["x"], table["y"], "o", color=ESTIMATE_COLOR, ms=1.8, alpha=0.6, label="estimate"
        )
        ax.set_xlim(left, right)
        ax.set_ylim(bottom, top)
        ax.set_title(name)
        ax.legend(loc="upper right", fontsize=7, markerscale=2)
    return save_png(fig, path)


def step_errors(truth: np.ndarray, table: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Per-step position error [m] and absolute wrapped heading error [°] (NaN if missing)."""
    est = table_poses(table)
    pos = np.hypot(est[:, 0] - truth[:, 0], est[:, 1] - truth[:, 1])
    heading = np.degrees(np.abs(wrap_angle(est[:, 2] - truth[:, 2])))
    return pos, heading


def plot_errors_over_time(
    truth: np.ndarray,
    tables: Mapping[str, pd.DataFrame],
    path: Path,
    kidnap_times: tuple[float, ...] = (),
    title: str = "",
) -> Path:
    """Position and heading error of every localizer along the trajectory; kidnaps (times in
    seconds) as dashed vertical lines."""
    colours = colors_for(list(tables))
    fig = new_figure(10.0, 5.6)
    ax_pos, ax_head = fig.subplots(2, 1, sharex=True)
    for ax in (ax_pos, ax_head):
        for when in kidnap_times:
            ax.axvline(when, color="black", ls="--", lw=0.9)
    if kidnap_times:
        ax_pos.text(kidnap_times[0], 1.05, " kidnap", transform=ax_pos.get_xaxis_transform())
    if title:
        ax_pos.set_title(title, fontsize=10)
    for name, table in tables.items():
        pos, heading = step_errors(truth, table)
        t = table["t"].to_numpy(dtype=np.float64) if "t" in table else np.arange(len(table))
        ax_pos.plot(t, np.maximum(pos, 1e-3), color=colours[name], lw=0.9, label=name)
        ax_head.plot(t, np.maximum(heading, 1e-2), color=colours[name], lw=0.9, label=name)
    ax_pos.set_yscale("log")
    ax_head.set_yscale("log")
    ax_pos.set_ylabel("position error [m]")
    ax_head.set_ylabel("heading error [°]")
    ax_head.set_xlabel("time [s]")
    for ax in (ax_pos, ax_head):
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax_pos.legend(fontsize=8, ncols=min(len(tables), 4) or 1)
    return save_png(fig, path)


def _ellipse(mean: np.ndarray, cov: np.ndarray, sigmas: float, colour: str) -> Ellipse:
    values, vectors = np.linalg.eigh(cov)
    values = np.maximum(values, 0.0)
    angle = np.degrees(np.arctan2(vectors[1, 1], vectors[0, 1]))
    width, height = 2 * sigmas * np.sqrt(values[1]), 2 * sigmas * np.sqrt(values[0])
    return Ellipse(tuple(mean), width, height, angle=angle, fill=False, ec=colour, lw=0.8)


def plot_uncertainty(
    grid: OccupancyGrid,
    truth: np.ndarray,
    tables: Mapping[str, pd.DataFrame],
    path: Path,
    max_ellipses: int = 80,
) -> Path:
    """2σ ellipses of each localizer's position covariance along the path (zoomed on the path),
    for the localizers that report a covariance (the ensemble's is the members' spread)."""
    count = len(tables)
    if count == 0:
        raise ValueError("no estimate tables to plot")
    cols = min(count, 3)
    fig = new_figure(4.6 * cols, 4.6 * -(-count // cols) + 0.3)
    lo, hi = np.nanmin(truth[:, :2], axis=0) - 1.0, np.nanmax(truth[:, :2], axis=0) + 1.0
    for ax, (name, table) in zip(_panel_grid(fig, count), tables.items(), strict=True):
        draw_map(ax, grid)
        ax.plot(truth[:, 0], truth[:, 1], "-", color=TRUTH_COLOR, lw=0.8, label="truth")
        every = max(1, -(-len(table) // max_ellipses))
        for _, row in table.iloc[::every].iterrows():
            cov = np.array([[row.cov_xx, row.cov_xy], [row.cov_xy, row.cov_yy]], dtype=np.float64)
            centre = np.array([row.x, row.y], dtype=np.float64)
            if np.isfinite(cov).all() and np.isfinite(centre).all():
                ax.add_patch(_ellipse(centre, cov, 2.0, ESTIMATE_COLOR))
        ax.plot(table["x"].iloc[::every], table["y"].iloc[::every], ".", color=ESTIMATE_COLOR, ms=2)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_title(f"{name}: 2σ position ellipses")
        ax.legend(loc="upper right", fontsize=7)
    return save_png(fig, path)


def plot_hypotheses(
    grid: OccupancyGrid,
    truth: np.ndarray,
    scan_ranges: np.ndarray,
    angles: np.ndarray,
    range_max: float,
    poses: np.ndarray,
    weights: np.ndarray,
    path: Path,
    title: str,
) -> Path:
    """One scan (drawn from the true pose), the true pose and the learned localizer's ranked
    hypotheses as arrows whose length grows with their weight, numbered by rank."""
    fig = new_figure(8.0, 6.4)
    ax = fig.subplots()
    draw_map(ax, grid)
    hit = scan_ranges <= range_max
    world = truth[2] + angles[hit]
    ax.plot(
        truth[0] + scan_ranges[hit] * np.cos(world),
        truth[1] + scan_ranges[hit] * np.sin(world),
        ".",
        color="#ff9896",
        ms=2,
        label="scan (from the true pose)",
    )
    top = max(float(weights.max()), 1e-12)
    for rank, (pose, weight) in enumerate(zip(poses, weights, strict=True), start=1):
        if weight <= 0:
            continue
        length = 0.3 + 0.9 * weight / top
        ax.arrow(
            pose[0],
            pose[1],
            length * np.cos(pose[2]),
            length * np.sin(pose[2]),
            width=0.05,
            color=ESTIMATE_COLOR,
            alpha=0.8,
            length_includes_head=True,
        )
        ax.text(pose[0], pose[1], f" {rank}", fontsize=7, color=ESTIMATE_COLOR)
    ax.arrow(
        truth[0],
        truth[1],
        0.9 * np.cos(truth[2]),
        0.9 * np.sin(truth[2]),
        width=0.07,
        color=TRUTH_COLOR,
        length_includes_head=True,
        label="truth",
    )
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_aspect("equal")
    return save_png(fig, path)
