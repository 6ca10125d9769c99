"""Laser ray casting on an occupancy grid: an exact caster, its plain reference, and STDR's.

Every caster takes poses (x, y, θ) in the map frame and beam angles in the sensor frame, and
casts all beams of all poses in compiled code, in parallel over poses.

`cast_exact` returns per beam the distance from the pose to the boundary of the first blocked
cell the ray enters (0 when the pose's own cell is blocked), or +inf when the ray leaves the
grid or passes range_max first. Two exact methods give it the same answers (to rounding,
~1e-13 m) as the plain cell-by-cell traversal `cast_reference` (Amanatides & Woo 1987):

* "boxes": the blocked cells are split once into axis-aligned rectangles (rows of equal runs);
  per pose, each rectangle within range is projected to the interval of beams that can see it
  (its silhouette angles) and only those beams are intersected with it analytically (slab
  test), keeping the nearest entry. Work per pose ~ rectangles in range + beams x overlapping
  rectangles, with no memory-latency chain per ray: fast on maps drawn from walls and boxes.
* "march": sphere tracing over a distance transform, as range_libc's ray marching: from any
  point of a free cell a ray may advance by (distance between cell centres to the nearest
  blocked cell - sqrt(2)) without touching a blocked cell; near obstacles it walks cell by
  cell with exact boundary crossings. Its speed does not depend on how blocked cells are
  shaped, so "auto" falls back to it for maps that split into too many rectangles.

`cast_stdr` reproduces STDR 0.3.2's laser (stdr_robot/src/sensors/laser.cpp) statement by
statement: samples at whole multiples of the resolution along the beam, float32 arithmetic
where STDR has it, readings that are multiples of the resolution, +inf / -inf for no hit /
too close, and STDR's own handling of beams that leave the map.

Poses must lie inside the grid. Unknown cells stop a beam only when `unknown_blocks` is set
(STDR lets them through: its test is `value > 70`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy.ndimage import distance_transform_edt

from scanloc.sensor.laser import LaserSpec
from scanloc.world.occupancy_grid import OccupancyGrid

METHODS = ("auto", "boxes", "march")
# "auto" uses boxes up to this many rectangles: per pose each one in range costs two atan2
# and two index look-ups, so boxes lose to marching somewhere past 2000-4000 rectangles on
# a 667-beam scan (measured on the paper's map with extra 3 x 3 blocks).
MAX_AUTO_BOXES = 2000
# A jump shorter than this many cells is not worth its floor() and lookup: walk instead.
_MIN_JUMP_CELLS = 1.0
# Kept off every obstacle after a jump (cells): far more than any rounding in the jump.
_JUMP_MARGIN_CELLS = 1e-3
# Silhouette intervals are widened by this (radians) so rounding never drops a beam; the
# exact slab test then decides hit or miss.
_ANGLE_SLACK = 1e-9
_TWO_PI = 2.0 * math.pi


def blocked_mask(grid: OccupancyGrid, unknown_blocks: bool = False) -> np.ndarray:
    """Cells that stop a beam: occupied ones, plus unknown ones when `unknown_blocks`."""
    return grid.occupied | grid.unknown if unknown_blocks else grid.occupied


@numba.njit(cache=True)
def _blocked_boxes(blocked: np.ndarray) -> np.ndarray:
    """Rectangles (x0, y0, x1, y1), in cells, whose union is exactly the blocked cells.

    Each row is cut into runs of blocked cells; a run identical to one in the row below
    extends that rectangle upwards, any other run opens a new one.
    """
    height, width = blocked.shape
    boxes = []
    open_x0 = np.empty(width, np.int64)
    open_x1 = np.empty(width, np.int64)
    open_y0 = np.empty(width, np.int64)
    n_open = 0
    run_x0 = np.empty(width, np.int64)
    run_x1 = np.empty(width, np.int64)
    next_x0 = np.empty(width, np.int64)
    next_x1 = np.empty(width, np.int64)
    next_y0 = np.empty(width, np.int64)
    for y in range(height + 1):
        n_runs = 0
        if y < height:
            x = 0
            while x < width:
                if blocked[y, x]:
                    start = x
                    while x < width and blocked[y, x]:
                        x += 1
                    run_x0[n_runs] = start
                    run_x1[n_runs] = x
                    n_runs += 1
                else:
                    x += 1
        a = 0
        b = 0
        n_next = 0
        while a < n_open or b < n_runs:
            if b == n_runs or (a < n_open and open_x0[a] < run_x0[b]):
                boxes.append((open_x0[a], open_y0[a], open_x1[a], y))
                a += 1
                continue
            y0 = y
            if a < n_open and open_x0[a] == run_x0[b]:
                if open_x1[a] == run_x1[b]:
                    y0 = open_y0[a]
                else:
                    boxes.append((open_x0[a], open_y0[a], open_x1[a], y))
                a += 1
            next_x0[n_next] = run_x0[b]
            next_x1[n_next] = run_x1[b]
            next_y0[n_next] = y0
            n_next += 1
            b += 1
        open_x0[:n_next] = next_x0[:n_next]
        open_x1[:n_next] = next_x1[:n_next]
        open_y0[:n_next] = next_y0[:n_next]
        n_open = n_next
    out = np.empty((len(boxes), 4), np.float64)
    for k in range(len(boxes)):
        for c in range(4):
            out[k, c] = boxes[k][c]
    return out


def blocked_boxes(blocked: np.ndarray) -> np.ndarray:
    """float64 (R, 4) rectangles x0, y0, x1, y1 (cell units, half-open) covering `blocked`."""
    return _blocked_boxes(np.ascontiguousarray(blocked, dtype=np.bool_))


def _march_safe(blocked: np.ndarray) -> np.ndarray:
    """Per free cell the distance (cells) a ray may advance from any of its points; -1 blocked.

    A point p of cell c lies within sqrt(2)/2 of c's centre and every point q of a blocked
    cell b within sqrt(2)/2 of b's centre, so |p - q| >= |c - b| - sqrt(2).
    """
    if blocked.any():
        centre_dist = distance_transform_edt(~blocked)
    else:  # nothing to hit: rays end at the grid's edge or at range_max
        centre_dist = np.full(blocked.shape, float(sum(blocked.shape)))
    safe = np.maximum(centre_dist - math.sqrt(2.0) - _JUMP_MARGIN_CELLS, 0.0).astype(np.float32)
    # float32 rounding must not lengthen a jump (nextafter(0, 0) stays 0)
    safe = np.nextafter(safe, np.float32(0))
    return np.ascontiguousarray(np.where(blocked, np.float32(-1.0), safe))


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
            safe = _march_safe(blocked)
        return cls(
            method=method,
            blocked=blocked,
            boxes=boxes,
            safe=safe,
            resolution=float(grid.resolution),
            origin_xy=(float(grid.origin[0]), float(grid.origin[1])),
        )


def _check_inputs(
    grid_shape: tuple[int, ...],
    resolution: float,
    origin_xy: tuple[float, float],
    poses: np.ndarray,
    angles: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    angles = np.ascontiguousarray(angles, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must have shape (N, 3), got {poses.shape}")
    if angles.ndim != 1 or angles.size == 0:
        raise ValueError(f"beam angles must have shape (B,) with B >= 1, got {angles.shape}")
    if not (np.all(np.diff(angles) >= 0) and angles[0] >= -math.pi and angles[-1] <= math.pi):
        raise ValueError("beam angles must be ascending and within [-pi, pi]")
    if not np.isfinite(poses).all():
        raise ValueError("poses must be finite")
    height, width = grid_shape
    col = (poses[:, 0] - origin_xy[0]) / resolution
    row = (poses[:, 1] - origin_xy[1]) / resolution
    outside = (col < 0) | (col >= width) | (row < 0) | (row >= height)
    if outside.any():
        first = int(np.flatnonzero(outside)[0])
        raise ValueError(
            f"{int(outside.sum())} pose(s) lie outside the grid, first: index {first} at "
            f"({poses[first, 0]:.4f}, {poses[first, 1]:.4f})"
        )
    return poses, angles


@numba.njit(inline="always")
def _beam_direction(cos_t: float, sin_t: float, cos_a: float, sin_a: float) -> tuple[float, float]:
    """Unit direction of beam angle a on heading t, shared by all exact casters.

    A zero component becomes 1e-300, so that no caster needs a division-by-zero branch: the
    boundary crossings along that axis move to ~1e300 cells, i.e. never.
    """
    dx = cos_t * cos_a - sin_t * sin_a
    dy = sin_t * cos_a + cos_t * sin_a
    if dx == 0.0:
        dx = 1e-300
    if dy == 0.0:
        dy = 1e-300
    return dx, dy


@numba.njit(cache=True)
def _silhouette(
    x0: float, y0: float, x1: float, y1: float, ox: float, oy: float
) -> tuple[float, float]:
    """World angle of a box's clockwise-most silhouette corner seen from o (outside), and the
    counter-clockwise extent (< pi) of the box from there."""
    # the two corners that bound the silhouette depend on the region o lies in
    if (oy < y0 and ox < x0) or (oy > y1 and ox > x1):  # below-left / above-right
        ax, ay, bx, by = x1, y0, x0, y1
    elif (oy < y0 and ox > x1) or (oy > y1 and ox < x0):  # below-right / above-left
        ax, ay, bx, by = x0, y0, x1, y1
    elif oy < y0:  # straight below: the bottom edge
        ax, ay, bx, by = x0, y0, x1, y0
    elif oy > y1:
        ax, ay, bx, by = x0, y1, x1, y1
    elif ox < x0:  # level with the box, to its left: the left edge
        ax, ay, bx, by = x0, y0, x0, y1
    else:
        ax, ay, bx, by = x1, y0, x1, y1
    a = math.atan2(ay - oy, ax - ox)
    b = math.atan2(by - oy, bx - ox)
    extent = b - a
    if extent > math.pi:
        extent -= _TWO_PI
    elif extent < -math.pi:
        extent += _TWO_PI
    return (a, extent) if extent >= 0.0 else (b, -extent)


@numba.njit(cache=True)
def _beam_index(angles: np.ndarray, beams_per_rad: float, value: float, after: bool) -> int:
    """Index of the first beam with angle >= value (> value when `after`).

    Guessed from the mean beam spacing, then corrected by walking: O(1) for evenly spaced
    beams, where a binary search would mispredict about log2(B) branches.
    """
    n = angles.shape[0]
    j = min(max(math.ceil((value - angles[0]) * beams_per_rad), 0), n)
    if after:
        while j > 0 and angles[j - 1] > value:
            j -= 1
        while j < n and angles[j] <= value:
            j += 1
    else:
        while j > 0 and angles[j - 1] >= value:
            j -= 1
        while j < n and angles[j] < value:
            j += 1
    return j


@numba.njit(cache=True, error_model="numpy")
def _hit_box(
    box: np.ndarray,
    ox: float,
    oy: float,
    angles: np.ndarray,
    beams_per_rad: float,
    inv_dx: np.ndarray,
    inv_dy: np.ndarray,
    lo: float,
    hi: float,
    best: np.ndarray,
) -> None:
    """Slab-test the beams with sensor angle in [lo, hi] against one box; keep nearer entries.

    Branch-free (min/max instead of the direction's signs, a select instead of an `if`), so
    the loop over beams compiles to straight vector code.
    """
    x0, y0, x1, y1 = box[0], box[1], box[2], box[3]
    first = _beam_index(angles, beams_per_rad, lo, False)
    stop = _beam_index(angles, beams_per_rad, hi, True)
    for j in range(first, stop):
        tx0 = (x0 - ox) * inv_dx[j]
        tx1 = (x1 - ox) * inv_dx[j]
        ty0 = (y0 - oy) * inv_dy[j]
        ty1 = (y1 - oy) * inv_dy[j]
        t_in = max(min(tx0, tx1), min(ty0, ty1))
        t_out = min(max(tx0, tx1), max(ty0, ty1))
        t = max(t_in, 0.0)
        nearer = (t_in < t_out) & (t_out > 0.0) & (t < best[j])
        best[j] = t if nearer else best[j]


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _cast_boxes_kernel(
    boxes: np.ndarray,
    blocked: np.ndarray,
    origin_x: float,
    origin_y: float,
    resolution: float,
    poses: np.ndarray,
    angles: np.ndarray,
    range_max: float,
    out: np.ndarray,
) -> None:
    n_beams = angles.shape[0]
    span = angles[-1] - angles[0]
    per_rad = (n_beams - 1) / span if span > 0.0 else 0.0  # mean beams per radian
    cos_a = np.cos(angles)
    sin_a = np.sin(angles)
    t_max = range_max / resolution
    for i in numba.prange(poses.shape[0]):
        ox = (poses[i, 0] - origin_x) / resolution
        oy = (poses[i, 1] - origin_y) / resolution
        heading = poses[i, 2]
        if blocked[math.floor(oy), math.floor(ox)]:
            out[i, :] = 0.0
            continue
        cos_t = math.cos(heading)
        sin_t = math.sin(heading)
        inv_dx = np.empty(n_beams)
        inv_dy = np.empty(n_beams)
        for j in range(n_beams):
            dx, dy = _beam_direction(cos_t, sin_t, cos_a[j], sin_a[j])
            inv_dx[j] = 1.0 / dx
            inv_dy[j] = 1.0 / dy
        best = np.full(n_beams, np.inf)
        for k in range(boxes.shape[0]):
            x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
            gap_x = max(x0 - ox, 0.0, ox - x1)
            gap_y = max(y0 - oy, 0.0, oy - y1)
            near = math.sqrt(gap_x * gap_x + gap_y * gap_y)
            if near > t_max:
                continue
            if near == 0.0:  # o on the box's edge: any beam may enter it
                lo, hi = -math.pi, math.pi
            else:
                start, extent = _silhouette(x0, y0, x1, y1, ox, oy)
                lo = start - heading - _ANGLE_SLACK
                lo -= _TWO_PI * math.floor((lo + math.pi) / _TWO_PI)  # into [-pi, pi)
                hi = lo + extent + 2.0 * _ANGLE_SLACK
            box = boxes[k]
            _hit_box(box, ox, oy, angles, per_rad, inv_dx, inv_dy, lo, hi, best)
            if hi > math.pi:  # the interval wraps past +pi
                _hit_box(
                    box, ox, oy, angles, per_rad, inv_dx, inv_dy, lo - _TWO_PI, hi - _TWO_PI, best
                )
        for j in range(n_beams):
            out[i, j] = best[j] * resolution if best[j] <= t_max else np.inf


@numba.njit(cache=True, error_model="numpy")
def _march(safe: np.ndarray, ox: float, oy: float, dx: float, dy: float, t_max: float) -> float:
    """Entry distance (cells) of the first blocked cell along o + t·d, or inf past t_max/grid."""
    height, width = safe.shape
    ix = math.floor(ox)
    iy = math.floor(oy)
    step_x = 1 if dx > 0 else -1
    step_y = 1 if dy > 0 else -1
    edge_x = 1 if dx > 0 else 0  # which side of the cell the ray leaves through
    edge_y = 1 if dy > 0 else 0
    inv_dx = 1.0 / dx
    inv_dy = 1.0 / dy
    t = 0.0
    while True:
        s = safe[iy, ix]
        if s < 0.0:
            return t
        if s >= _MIN_JUMP_CELLS:
            t += s
            if t > t_max:
                return np.inf
            ix = math.floor(ox + t * dx)
            iy = math.floor(oy + t * dy)
            # the jumped segment is clear and a convex grid is never re-entered
            if ix < 0 or ix >= width or iy < 0 or iy >= height:
                return np.inf
        else:
            # boundary crossings from the origin, not accumulated: exact to rounding; a cell
            # misidentified by floor() after a jump (only ever within rounding of a boundary,
            # and clear by the jump margin) is left again at once with no cell skipped
            tx = (ix + edge_x - ox) * inv_dx
            ty = (iy + edge_y - oy) * inv_dy
            if tx < ty:
                t = tx
                ix += step_x
                if ix < 0 or ix >= width:
                    return np.inf
            else:
                t = ty
                iy += step_y
                if iy < 0 or iy >= height:
                    return np.inf
            if t > t_max:
                return np.inf


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _cast_march_kernel(
    safe: np.ndarray,
    origin_x: float,
    origin_y: float,
    resolution: float,
    poses: np.ndarray,
    angles: np.ndarray,
    range_max: float,
    out: np.ndarray,
) -> None:
    cos_a = np.cos(angles)
    sin_a = np.sin(angles)
    t_max = range_max / resolution
    for i in numba.prange(poses.shape[0]):
        ox = (poses[i, 0] - origin_x) / resolution
        oy = (poses[i, 1] - origin_y) / resolution
        cos_t = math.cos(poses[i, 2])
        sin_t = math.sin(poses[i, 2])
        for j in range(angles.shape[0]):
            dx, dy = _beam_direction(cos_t, sin_t, cos_a[j], sin_a[j])
            out[i, j] = _march(safe, ox, oy, dx, dy, t_max) * resolution


def cast_exact(
    cast_map: CastMap, poses: np.ndarray, angles: np.ndarray, range_max: float
) -> np.ndarray:
    """Exact beam ranges, float64 (N, B) metres; +inf where nothing is hit within range_max.

    `angles` must be ascending within [-pi, pi] (as LaserSpec.beam_angles()).
    """
    poses, angles = _check_inputs(
        cast_map.blocked.shape, cast_map.resolution, cast_map.origin_xy, poses, angles
    )
    out = np.empty((poses.shape[0], angles.shape[0]), dtype=np.float64)
    args = (*cast_map.origin_xy, cast_map.resolution, poses, angles, float(range_max), out)
    if cast_map.method == "boxes":
        _cast_boxes_kernel(cast_map.boxes, cast_map.blocked, *args)
    else:
        _cast_march_kernel(cast_map.safe, *args)
    return out


@numba.njit(cache=True, error_model="numpy")
def _traverse(
    blocked: np.ndarray, ox: float, oy: float, dx: float, dy: float, t_max: float
) -> float:
    """Amanatides & Woo's traversal, cell by cell: the textbook method, no shortcuts."""
    height, width = blocked.shape
    ix = math.floor(ox)
    iy = math.floor(oy)
    if blocked[iy, ix]:
        return 0.0
    step_x = 1 if dx > 0 else -1
    step_y = 1 if dy > 0 else -1
    delta_x = abs(1.0 / dx)
    delta_y = abs(1.0 / dy)
    next_x = (ix + (1 if dx > 0 else 0) - ox) / dx
    next_y = (iy + (1 if dy > 0 else 0) - oy) / dy
    while True:
        if next_x < next_y:
            t = next_x
            next_x += delta_x
            ix += step_x
        else:
            t = next_y
            next_y += delta_y
            iy += step_y
        if t > t_max or ix < 0 or ix >= width or iy < 0 or iy >= height:
            return np.inf
        if blocked[iy, ix]:
            return t


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _cast_reference_kernel(
    blocked: np.ndarray,
    origin_x: float,
    origin_y: float,
    resolution: float,
    poses: np.ndarray,
    angles: np.ndarray,
    range_max: float,
    out: np.ndarray,
) -> None:
    cos_a = np.cos(angles)
    sin_a = np.sin(angles)
    t_max = range_max / resolution
    for i in numba.prange(poses.shape[0]):
        ox = (poses[i, 0] - origin_x) / resolution
        oy = (poses[i, 1] - origin_y) / resolution
        cos_t = math.cos(poses[i, 2])
        sin_t = math.sin(poses[i, 2])
        for j in range(angles.shape[0]):
            dx, dy = _beam_direction(cos_t, sin_t, cos_a[j], sin_a[j])
            out[i, j] = _traverse(blocked, ox, oy, dx, dy, t_max) * resolution


def cast_reference(
    grid: OccupancyGrid,
    poses: np.ndarray,
    angles: np.ndarray,
    range_max: float,
    unknown_blocks: bool = False,
) -> np.ndarray:
    """The plain cell-by-cell traversal; same contract and results as `cast_exact`."""
    origin_xy = (float(grid.origin[0]), float(grid.origin[1]))
    poses, angles = _check_inputs(grid.cells.shape, grid.resolution, origin_xy, poses, angles)
    blocked = np.ascontiguousarray(blocked_mask(grid, unknown_blocks))
    out = np.empty((poses.shape[0], angles.shape[0]), dtype=np.float64)
    _cast_reference_kernel(
        blocked, *origin_xy, float(grid.resolution), poses, angles, float(range_max), out
    )
    return out


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
    poses, _ = _check_inputs(
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
