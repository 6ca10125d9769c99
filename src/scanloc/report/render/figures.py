"""The report's figures of maps, scans and training (paper Fig. 1, 3, 5, 6, 7, 8, 9), as PNG files;
the figures of localizer estimates are in localization_figures.py.

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

from scanloc.io import atomic_path
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
