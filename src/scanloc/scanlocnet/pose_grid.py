"""The discrete pose space of scanloc's learned localizer: cells over a map's free space and
heading bins, with continuous offsets inside them.

A pose (x, y, θ) is encoded as (cell, in-cell offset, heading bin, in-bin offset): cells are
squares of `cell_size` metres on the map's grid (a whole number of map cells, aligned to the
map's origin), and only those that hold some free position with the robot's clearance exist,
so the grid follows the map's size and free space. Headings are `heading_bins` equal bins
starting at -π. Offsets are in units of a cell / a bin, in [-0.5, 0.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from scanloc.world.free_space import centre_clearance
from scanloc.world.occupancy_grid import OccupancyGrid

# Scans whose hypotheses over the whole pose grid are decoded together (scanlocnet.top_k):
# their logits, scans x cells x heading bins, are what decoding holds at once.
DECODE_BATCH = 256


@dataclass(frozen=True)
class PoseGrid:
    """Cells over a map's free space and heading bins.

    Attributes:
        origin: world (x, y) of the corner of grid cell (0, 0) (the map's origin).
        cell_size: cell edge in metres.
        shape: (rows, cols) of the full cell grid over the map.
        cells: (C, 2) int64 (row, col) of the cells that exist, in row-major order.
        heading_bins: number of heading bins over (-π, π].
    """

    origin: tuple[float, float]
    cell_size: float
    shape: tuple[int, int]
    cells: np.ndarray
    heading_bins: int

    @classmethod
    def from_map(
        cls,
        grid: OccupancyGrid,
        cell_size: float,
        heading_bins: int,
        clearance: float,
        max_cells: int = 100_000,
    ) -> PoseGrid:
        """The cells of `grid` (cell_size rounded to whole map cells) that hold a map cell whose
        centre keeps `clearance` metres from every non-free cell. Raises ValueError naming the
        numbers when there is none, or more than `max_cells` (the classifier would not fit)."""
        if not (cell_size > 0 and heading_bins >= 2 and clearance >= 0):
            raise ValueError(
                f"need cell_size > 0, heading_bins >= 2, clearance >= 0, got {cell_size}, "
                f"{heading_bins}, {clearance}"
            )
        step = max(1, round(cell_size / grid.resolution))
        size = step * grid.resolution
        clear = centre_clearance(grid) * grid.resolution
        # A map cell whose centre is within half a cell diagonal of the clearance may still
        # hold valid positions: keep it (an extra cell is harmless, a missing one is not).
        valid = grid.free & (clear >= clearance - grid.resolution / math.sqrt(2.0))
        rows, cols = np.nonzero(valid)
        shape = (math.ceil(grid.height / step), math.ceil(grid.width / step))
        occupied = np.zeros(shape, dtype=bool)
        occupied[rows // step, cols // step] = True
        cells = np.argwhere(occupied)
        if len(cells) == 0:
            raise ValueError(f"no free space with clearance {clearance} m for the pose grid")
        if len(cells) > max_cells:
            raise ValueError(
                f"the pose grid has {len(cells)} cells of {size:.2f} m (limit {max_cells}): "
                "raise cell_size for a map this large"
            )
        return cls(
            origin=(float(grid.origin[0]), float(grid.origin[1])),
            cell_size=float(size),
            shape=(int(shape[0]), int(shape[1])),
            cells=cells.astype(np.int64),
            heading_bins=int(heading_bins),
        )

    @property
    def num_cells(self) -> int:
        return len(self.cells)

    @property
    def bin_width(self) -> float:
        return 2.0 * math.pi / self.heading_bins

    def cell_index(self) -> np.ndarray:
        """(rows, cols) int64: each grid cell's index into `cells`, -1 where there is none."""
        index = np.full(self.shape, -1, dtype=np.int64)
        index[self.cells[:, 0], self.cells[:, 1]] = np.arange(self.num_cells)
        return index

    def cell_centres(self) -> np.ndarray:
        """(C, 2) world (x, y) of the cells' centres."""
        x = self.origin[0] + (self.cells[:, 1] + 0.5) * self.cell_size
        y = self.origin[1] + (self.cells[:, 0] + 0.5) * self.cell_size
        return np.column_stack([x, y])

    def encode(self, poses: np.ndarray) -> dict[str, np.ndarray]:
        """cell (N,) int64 (-1: outside every cell), offset (N, 2) float, bin (N,) int64 and
        bin_offset (N,) float of poses (N, 3)."""
        poses = np.asarray(poses, dtype=np.float64)
        gx = (poses[:, 0] - self.origin[0]) / self.cell_size
        gy = (poses[:, 1] - self.origin[1]) / self.cell_size
        col, row = np.floor(gx).astype(np.int64), np.floor(gy).astype(np.int64)
        inside = (row >= 0) & (row < self.shape[0]) & (col >= 0) & (col < self.shape[1])
        cell = np.full(len(poses), -1, dtype=np.int64)
        cell[inside] = self.cell_index()[row[inside], col[inside]]
        offset = np.column_stack([gx - col - 0.5, gy - row - 0.5])
        h = (poses[:, 2] + math.pi) / self.bin_width
        heading_bin = np.floor(h).astype(np.int64) % self.heading_bins
        bin_offset = h - np.floor(h) - 0.5
        return {"cell": cell, "offset": offset, "bin": heading_bin, "bin_offset": bin_offset}

    def decode(
        self,
        cell: np.ndarray,
        offset: np.ndarray,
        heading_bin: np.ndarray,
        bin_offset: np.ndarray,
    ) -> np.ndarray:
        """Poses (..., 3) from cells (...), offsets (..., 2), bins (...) and bin offsets (...);
        θ wrapped to (-π, π]."""
        rc = self.cells[np.asarray(cell)]
        x = self.origin[0] + (rc[..., 1] + 0.5 + offset[..., 0]) * self.cell_size
        y = self.origin[1] + (rc[..., 0] + 0.5 + offset[..., 1]) * self.cell_size
        theta = -math.pi + (np.asarray(heading_bin) + 0.5 + bin_offset) * self.bin_width
        theta = math.pi - np.mod(math.pi - theta, 2.0 * math.pi)
        return np.stack([x, y, theta], axis=-1)

    def to_dict(self) -> dict:
        """A JSON-able description (stored with the model)."""
        return {
            "origin": list(self.origin),
            "cell_size": self.cell_size,
            "shape": list(self.shape),
            "cells": self.cells.tolist(),
            "heading_bins": self.heading_bins,
        }

    @classmethod
    def from_dict(cls, d: dict) -> PoseGrid:
        return cls(
            origin=(float(d["origin"][0]), float(d["origin"][1])),
            cell_size=float(d["cell_size"]),
            shape=(int(d["shape"][0]), int(d["shape"][1])),
            cells=np.asarray(d["cells"], dtype=np.int64).reshape(-1, 2),
            heading_bins=int(d["heading_bins"]),
        )
