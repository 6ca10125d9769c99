"""STDR 0.3.2's laser (stdr_robot/src/sensors/laser.cpp), statement by statement: samples at
whole multiples of the resolution along the beam, float32 arithmetic where STDR has it, readings
that are multiples of the resolution, +inf / -inf for no hit / too close, and STDR's own
handling of beams that leave the map. Unknown cells stop a beam only when `unknown_blocks` is
set (STDR lets them through: its test is `value > 70`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.ray_grid import blocked_mask, check_cast_inputs
from scanloc.world.occupancy_grid import OccupancyGrid


@numba.njit(cache=True, parallel=True)
def _cast_stdr_kernel(
    blocked: np.ndarray,
    width: int,
    resolution32: np.float32,
    origin_x: float,
    origin_y: float,
    poses: np.ndarray,
    min_angle32: np.float32,
    angle_offsets32: np.ndarray,
    range_min32: np.float32,
    range_max32: np.float32,
    out: np.ndarray,
) -> None:
    """STDR's loop, statement by statement (comments quote laser.cpp's expressions)."""
    n_cells = blocked.shape[0]
    resolution = np.float64(resolution32)  # nav_msgs/MapMetaData.resolution is float32
    max_steps32 = range_max32 / resolution32  # maxRange / resolution: float / float
    for i in numba.prange(poses.shape[0]):
        x_cells = (poses[i, 0] - origin_x) / resolution  # origin.x() / resolution: double
        y_cells = (poses[i, 1] - origin_y) / resolution
        for j in range(angle_offsets32.shape[0]):
            # float angle = yaw + minAngle + iter * (maxAngle - minAngle) / divisions;
            # the last term is float32 arithmetic, the sum double, stored as float
            angle = np.float32(poses[i, 2] + np.float64(min_angle32) + angle_offsets32[j])
            cos_a = math.cos(np.float64(angle))
            sin_a = math.sin(np.float64(angle))
            distance = 1
            while np.float32(distance) <= max_steps32:
                x_map = int(x_cells + cos_a * distance)  # int conversion truncates toward 0
                y_map = int(y_cells + sin_a * distance)
                index = y_map * width + x_map
                if index > n_cells or index < 0:
                    # leaving the map: distance = maxRange / resolution - 1 (a finite reading)
                    distance = int(max_steps32 - np.float32(1.0))
                    break
                # index == n_cells reads past the map in STDR (undefined): taken as free
                if index < n_cells and blocked[index]:
                    break
                distance += 1
            reading = np.float32(distance) * resolution32  # distance * resolution: float
            if reading > range_max32:
                out[i, j] = np.inf
            elif reading < range_min32:
                out[i, j] = -np.inf
            else:
                out[i, j] = reading


def stdr_angle_offsets(spec: LaserSpec) -> np.ndarray:
    """float32 `iter * (maxAngle - minAngle) / divisions` as STDR computes it (divisions = B-1)."""
    span = np.float32(spec.angle_max) - np.float32(spec.angle_min)
    steps = np.arange(spec.num_beams, dtype=np.float32)
    return (steps * span) / np.float32(spec.num_beams - 1)


def cast_stdr(
    grid: OccupancyGrid, poses: np.ndarray, spec: LaserSpec, unknown_blocks: bool = False
) -> np.ndarray:
    """STDR's readings, float32 (N, B): multiples of the resolution, +inf no hit, -inf too close.

    A beam that leaves the map reads (range_max / resolution - 1) cells, as in STDR. Where this
    differs from STDR (nil on STDR's maps): the map origin is subtracted (STDR assumes it is
    zero), cos/sin of the float32 beam angle are taken in double precision, and the one cell
    past the map's end that STDR's bounds test lets it read counts as free.
    """
    origin_xy = (float(grid.origin[0]), float(grid.origin[1]))
    resolution32 = np.float32(grid.resolution)
    poses, _ = check_cast_inputs(
        grid.cells.shape, float(resolution32), origin_xy, poses, spec.beam_angles()
    )
    blocked = np.ascontiguousarray(blocked_mask(grid, unknown_blocks)).ravel()
    out = np.empty((poses.shape[0], spec.num_beams), dtype=np.float32)
    _cast_stdr_kernel(
        blocked,
        grid.width,
        resolution32,
        *origin_xy,
        poses,
        np.float32(spec.angle_min),
        stdr_angle_offsets(spec),
        np.float32(spec.range_min),
        np.float32(spec.range_max),
        out,
    )
    return out
