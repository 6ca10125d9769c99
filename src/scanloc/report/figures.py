"""The report's figures (paper Fig. 1, 3, 5, 6, 7, 8, 9, 10 and our additions), as PNG files.

Every function takes arrays or DataFrames and an output path, draws on its own `Figure` (no
pyplot state, Agg canvas) and writes a PNG whose bytes depend only on the inputs: the
"Software" metadata that would name the matplotlib version is left out.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse

from scanloc.estimates import table_poses
from scanloc.io import atomic_path
from scanloc.pose import wrap_angle
from scanloc.world.occupancy_grid import FREE, OCCUPIED, OccupancyGrid

DPI = 100
TRUTH_COLOR = "#1f5fbf"
ESTIMATE_COLOR = "#d62728"
PALETTE = ("#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf", "#7f7f7f")
_MAP_RGB = {FREE: (255, 255, 255), OCCUPIED: (0, 0, 0)}
_UNKNOWN_RGB = (200, 200, 200)


def new_figure(width_in: float, height_in: float) -> Figure:
    """A figure on its own Agg canvas (thread-safe, no global pyplot state)."""
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_png(fig: Figure, path: Path) -> Path:
    """Write the figure as a PNG with deterministic bytes, atomically."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI, metadata={"Software": None})
    return Path(path)


def colors_for(names: list[str]) -> dict[str, str]:
    """A fixed colour per name, in order."""
    return {name: PALETTE[i % len(PALETTE)] for i, name in enumerate(names)}


def map_rgb(grid: OccupancyGrid) -> np.ndarray:
    """RGB image of the grid (row 0 = bottom, for imshow with origin="lower")."""
    rgb = np.empty((*grid.cells.shape, 3), dtype=np.uint8)
    rgb[:] = _UNKNOWN_RGB
    for value, colour in _MAP_RGB.items():
        rgb[grid.cells == value] = colour
    return rgb


def map_extent(grid: OccupancyGrid) -> tuple[float, float, float, float]:
    """(left, right, bottom, top) of the map in world metres."""
    x0, y0 = grid.origin[0], grid.origin[1]
    width, height = grid.size_m
    return x0, x0 + width, y0, y0 + height


def draw_map(ax, grid: OccupancyGrid) -> None:
    """Draw the occupancy grid in world coordinates (white free, black occupied, grey unknown)."""
    ax.imshow(map_rgb(grid), origin="lower", extent=map_extent(grid), interpolation="nearest")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def _draw_robot(ax, pose: np.ndarray, radius: float = 0.2) -> None:
    x, y, theta = pose
    ax.add_patch(Ellipse((x, y), 2 * radius, 2 * radius, fc="#f2c14e", ec="k", lw=0.8, zorder=4))
    ax.plot(
        [x, x + radius * np.cos(theta)], [y, y + radius * np.sin(theta)], "k-", lw=1.2, zorder=5
    )


def plot_map_scan(
    grid: OccupancyGrid,
    pose: np.ndarray,
    ranges: np.ndarray,
    angles: np.ndarray,
    path: Path,
    title: str,
    range_max: float,
    beam_step: int = 4,
) -> Path:
    """Paper Fig. 6 / 8: the map with the robot and its laser beams (red; beams without a
    return drawn to the maximum range, lighter)."""
    pose = np.asarray(pose, dtype=np.float64)
    r = np.asarray(ranges, dtype=np.float64)[::beam_step]
    a = np.asarray(angles, dtype=np.float64)[::beam_step] + pose[2]
    hit = r <= range_max
    length = np.where(hit, r, range_max)
    ends = pose[:2] + length[:, None] * np.stack([np.cos(a), np.sin(a)], axis=1)
    segments = np.stack([np.broadcast_to(pose[:2], ends.shape), ends], axis=1)
    fig = new_figure(6.4, 6.0)
    ax = fig.add_subplot()
    draw_map(ax, grid)
    ax.add_collection(LineCollection(segments[hit], colors=ESTIMATE_COLOR, linewidths=0.6))
    ax.add_collection(LineCollection(segments[~hit], colors="#f4a6a6", linewidths=0.4))
    _draw_robot(ax, pose)
    left, right, bottom, top = map_extent(grid)
    ax.set_xlim(left, right)
    ax.set_ylim(bottom, top)
    ax.set_title(title)
    return save_png(fig, path)


def plot_scan_ranges(ranges: np.ndarray, angles: np.ndarray, path: Path, range_max: float) -> Path:
    """Paper Fig. 1a / 3: the raw scan, range per beam angle (the 1D CNN's input)."""
    hit = ranges <= range_max
    fig = new_figure(7.0, 3.2)
    ax = fig.add_subplot()
    ax.plot(
        np.degrees(angles[hit]), ranges[hit], ".", ms=2.0, color=ESTIMATE_COLOR, label="returns"
    )
    if (~hit).any():
        ax.plot(
            np.degrees(angles[~hit]),
            ranges[~hit],
            ".",
            ms=1.5,
            color="#f4a6a6",
            label="no return (fill value)",
        )
    ax.axhline(range_max, color="0.5", lw=0.8, ls="--", label=f"max range {range_max:g} m")
    ax.set_xlabel("beam angle [°] (0 = forward, positive = left)")
    ax.set_ylabel("range [m]")
    ax.set_title("Raw scan: range per beam (1D CNN input)")
    ax.legend(loc="upper right", fontsize=8)
    return save_png(fig, path)


def plot_scan_points(ranges: np.ndarray, angles: np.ndarray, path: Path, range_max: float) -> Path:
    """Paper Fig. 1b: the scan's end points around the robot, robot frame (x forward, y left)."""
    hit = ranges <= range_max
    x, y = ranges * np.cos(angles), ranges * np.sin(angles)
    fig = new_figure(4.6, 4.6)
    ax = fig.add_subplot()
    ax.plot(x[hit], y[hit], ".", ms=2.0, color=ESTIMATE_COLOR, label="returns")
    if (~hit).any():
        ax.plot(x[~hit], y[~hit], ".", ms=1.5, color="#f4a6a6", label="no return (fill value)")
    _draw_robot(ax, np.zeros(3), radius=0.2)
    ax.set_aspect("equal")
    ax.set_xlabel("x forward [m]")
    ax.set_ylabel("y left [m]")
    ax.set_title("Scan around the robot")
    ax.legend(loc="lower left", fontsize=8)
    return save_png(fig, path)


def plot_scan_image(image: np.ndarray, path: Path, max_range: float) -> Path:
    """Paper Fig. 5: the rasterised scan image that the 2D CNN sees (one channel, binary)."""
    image = np.asarray(image)
    size = image.shape[-1]
    fig = new_figure(4.6, 4.8)
    ax = fig.add_subplot()
    ax.imshow(
        image.reshape(image.shape[-2:]), cmap="gray_r", interpolation="nearest", vmin=0, vmax=1
    )
    ax.set_title(f"Rasterised scan, {size}×{size} px ({size / (2 * max_range):.2f} px/m)")
    ax.set_xlabel("column [px]")
    ax.set_ylabel("row [px]")
    return save_png(fig, path)


def plot_learning_curves(histories: Mapping[str, pd.DataFrame], path: Path, title: str) -> Path:
    """Paper Fig. 7 / 9: training (a) and validation (b) MAE per epoch, log scale."""
    colours = colors_for(list(histories))
    fig = new_figure(10.0, 4.0)
    axes = fig.subplots(1, 2, sharey=True)
    for ax, column, label in zip(
        axes, ("train_mae", "val_mae"), ("Training", "Validation"), strict=True
    ):
        for name, history in histories.items():
            ax.plot(history["epoch"], history[column], color=colours[name], lw=1.2, label=name)
        ax.set_yscale("log")
        ax.set_xlabel("epoch")
        ax.set_title(f"({'ab'[column == 'val_mae']}) {label} loss (MAE)")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    axes[0].set_ylabel("mean absolute error (x [m], y [m], θ [rad])")
    axes[1].legend(fontsize=8)
    fig.suptitle(title)
    return save_png(fig, path)


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


def rasterize_scan(
    ranges: np.ndarray, angles: np.ndarray, size: int, max_range: float
) -> np.ndarray:
    """The binary (size, size) image the 2D CNN sees for one scan (paper eq. 1–4), made by the
    network's own rasteriser so the figure shows exactly its input."""
    import torch

    from scanloc.data.rasterize import rasterize_scans

    image = rasterize_scans(
        torch.as_tensor(ranges, dtype=torch.float32)[None],
        torch.as_tensor(angles, dtype=torch.float32),
        size=size,
        max_range=max_range,
    )
    return image[0, 0].numpy().astype(np.uint8)


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


def plot_columns(
    histories: Mapping[str, pd.DataFrame], columns: Mapping[str, str], path: Path
) -> Path:
    """One panel per history column (label: y axis), one line per run, against `epoch`."""
    colours = colors_for(list(histories))
    fig = new_figure(5.0 * len(columns), 3.6)
    axes = np.atleast_1d(fig.subplots(1, len(columns)))
    for ax, (column, label) in zip(axes, columns.items(), strict=True):
        for name, history in histories.items():
            if column in history:
                ax.plot(
                    history["epoch"], history[column], "o-", ms=3, color=colours[name], label=name
                )
        ax.set_xlabel("epoch")
        ax.set_ylabel(label)
        ax.grid(True, lw=0.3, alpha=0.5)
    axes[0].legend(fontsize=8)
    return save_png(fig, path)
