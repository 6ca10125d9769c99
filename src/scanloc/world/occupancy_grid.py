"""The occupancy grid every other part of scanloc works on.

Cells are stored with row 0 at the BOTTOM of the map (world y grows with the row index), the
ROS convention for `nav_msgs/OccupancyGrid`: cell (row 0, col 0) is the bottom-left corner,
placed at `origin`. Image files store row 0 at the top; `map_server` flips on read and write.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FREE: int = 0
OCCUPIED: int = 100
UNKNOWN: int = -1


@dataclass(frozen=True)
class OccupancyGrid:
    """A 2D grid of FREE / OCCUPIED / UNKNOWN cells with its metric placement.

    Attributes:
        cells: int8 array (height, width); row 0 is the bottom row (smallest world y).
        resolution: cell edge length in metres.
        origin: (x, y, yaw) of the bottom-left corner of cell (0, 0) in the world frame.
            scanloc only supports yaw == 0 (as does most of ROS).
    """

    cells: np.ndarray
    resolution: float
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.cells.ndim != 2:
            raise ValueError(f"cells must be 2D, got shape {self.cells.shape}")
        if self.cells.dtype != np.int8:
            object.__setattr__(self, "cells", self.cells.astype(np.int8))
        if not self.resolution > 0:
            raise ValueError(f"resolution must be > 0, got {self.resolution}")
        if abs(float(self.origin[2])) > 1e-12:
            raise ValueError(f"origin yaw must be 0, got {self.origin[2]}")

    @property
    def height(self) -> int:
        """Number of rows (cells along y)."""
        return int(self.cells.shape[0])

    @property
    def width(self) -> int:
        """Number of columns (cells along x)."""
        return int(self.cells.shape[1])

    @property
    def size_m(self) -> tuple[float, float]:
        """Metric (width, height) of the map."""
        return self.width * self.resolution, self.height * self.resolution

    @property
    def occupied(self) -> np.ndarray:
        """Boolean mask of occupied cells."""
        return self.cells == OCCUPIED

    @property
    def free(self) -> np.ndarray:
        """Boolean mask of free cells."""
        return self.cells == FREE

    @property
    def unknown(self) -> np.ndarray:
        """Boolean mask of unknown cells."""
        return self.cells == UNKNOWN

    def world_to_cell(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(col, row) integer indices of the cells containing world points (may be out of range)."""
        col = np.floor((np.asarray(x) - self.origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((np.asarray(y) - self.origin[1]) / self.resolution).astype(np.int64)
        return col, row

    def cell_center(self, col: np.ndarray, row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World coordinates of cell centres."""
        x = self.origin[0] + (np.asarray(col) + 0.5) * self.resolution
        y = self.origin[1] + (np.asarray(row) + 0.5) * self.resolution
        return x, y

    def counts(self) -> dict[str, int]:
        """Number of occupied, free and unknown cells."""
        return {
            "occupied": int(self.occupied.sum()),
            "free": int(self.free.sum()),
            "unknown": int(self.unknown.sum()),
        }
