"""Exact laser ray casting on an occupancy grid, in compiled code, in parallel over poses.

`cast_exact` takes poses (x, y, θ) in the map frame and beam angles in the sensor frame and
returns per beam the distance from the pose to the boundary of the first blocked cell the ray
enters (0 when the pose's own cell is blocked), or +inf when the ray leaves the grid or passes
range_max first. Two methods give it the same answers (to rounding, ~1e-13 m) as the plain
cell-by-cell traversal (scanloc.sensor.raycast_reference):

* "boxes" (scanloc.sensor.raycast_boxes): rectangles covering the blocked cells, each
  intersected analytically with the beams that can see it; fast on maps drawn from walls and
  boxes;
* "march" (scanloc.sensor.raycast_march): sphere tracing over a distance transform; its speed
  does not depend on how blocked cells are shaped, so "auto" falls back to it for maps that
  split into too many rectangles.

STDR's own caster, reading for reading, is scanloc.sensor.raycast_stdr. Poses must lie inside
the grid. Unknown cells stop a beam only when `unknown_blocks` is set.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanloc.sensor.ray_grid import blocked_mask, check_cast_inputs
from scanloc.sensor.raycast_boxes import blocked_boxes, cast_boxes_kernel
from scanloc.sensor.raycast_march import cast_march_kernel, march_safe
from scanloc.world.occupancy_grid import OccupancyGrid

METHODS = ("auto", "boxes", "march")
# "auto" uses boxes up to this many rectangles: per pose each one in range costs two atan2
# and two index look-ups, so boxes lose to marching somewhere past 2000-4000 rectangles on
# a 667-beam scan (measured on the paper's map with extra 3 x 3 blocks).
MAX_AUTO_BOXES = 2000


@dataclass(frozen=True)
class CastMap:
    """A grid prepared once for many `cast_exact` calls.

    Attributes:
        method: "boxes" or "march" (resolved from "auto").
        blocked: bool (H, W) cells that stop a beam.
        boxes: float64 (R, 4) rectangles covering `blocked` ("boxes"), else shape (0, 4).
        safe: float32 (H, W) jump lengths, -1 on blocked cells ("march"), else shape (0, 0).
        resolution: cell edge length in metres.
        origin_xy: world (x, y) of the grid's bottom-left corner.
    """

    method: str
    blocked: np.ndarray
    boxes: np.ndarray
    safe: np.ndarray
    resolution: float
    origin_xy: tuple[float, float]

    @classmethod
    def from_grid(
        cls, grid: OccupancyGrid, unknown_blocks: bool = False, method: str = "auto"
    ) -> CastMap:
        """Prepare `grid`; "auto" picks boxes unless the map needs over MAX_AUTO_BOXES."""
        if method not in METHODS:
            raise ValueError(f"ray casting method must be one of {METHODS}, got {method!r}")
        blocked = np.ascontiguousarray(blocked_mask(grid, unknown_blocks))
        boxes = np.empty((0, 4))
        safe = np.empty((0, 0), np.float32)
        if method in ("auto", "boxes"):
            boxes = blocked_boxes(blocked)
            if method == "auto":
                method = "boxes" if len(boxes) <= MAX_AUTO_BOXES else "march"
        if method == "march":
            boxes = np.empty((0, 4))
            safe = march_safe(blocked)
        return cls(
            method=method,
            blocked=blocked,
            boxes=boxes,
            safe=safe,
            resolution=float(grid.resolution),
            origin_xy=(float(grid.origin[0]), float(grid.origin[1])),
        )


def cast_exact(
    cast_map: CastMap, poses: np.ndarray, angles: np.ndarray, range_max: float
) -> np.ndarray:
    """Exact beam ranges, float64 (N, B) metres; +inf where nothing is hit within range_max.

    `angles` must be ascending within [-pi, pi] (as LaserSpec.beam_angles()).
    """
    poses, angles = check_cast_inputs(
        cast_map.blocked.shape, cast_map.resolution, cast_map.origin_xy, poses, angles
    )
    out = np.empty((poses.shape[0], angles.shape[0]), dtype=np.float64)
    args = (*cast_map.origin_xy, cast_map.resolution, poses, angles, float(range_max), out)
    if cast_map.method == "boxes":
        cast_boxes_kernel(cast_map.boxes, cast_map.blocked, *args)
    else:
        cast_march_kernel(cast_map.safe, *args)
    return out
