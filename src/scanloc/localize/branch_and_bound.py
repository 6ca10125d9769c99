"""Branch and bound over the whole map: the best poses for one scan, exact at the search's
resolution (Hess et al., "Real-Time Loop Closure in 2D LIDAR SLAM", ICRA 2016; Cartographer's
FastCorrelativeScanMatcher2D).

The score of a pose is the mean, over the scan's end points, of a map's match grid at the cell
each point falls in: exp(-d² / 2σ²), d the distance from the cell to the nearest obstacle
(a likelihood field). Poses are searched on the map's cells (the robot's cell centre) and on
headings a step apart that moves the farthest point at most one cell. Rotating the scan once per
heading turns every translation into integer cell offsets, so a pose's score is a sum of grid
lookups. For a block of 2^h × 2^h translations, the same sum over a grid max-pooled over
2^h × 2^h windows bounds every pose in the block from above; a depth-first search that expands
the best child first and drops every block whose bound cannot beat the best pose found finds the
best pose of the whole grid without scoring most of it. Poses must lie in free space.

`search` returns the best pose; `search_top_k` the k best whose positions or headings differ
by more than a separation, each found by a search that excludes the ones before (still exact).
A learned model may guide the search: its poses are scored first, the best of them is the
score every block must beat from the start, and their blocks are expanded first, so that most
blocks are pruned; the answer is the same.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from scipy.ndimage import distance_transform_edt

from scanloc.world.occupancy_grid import OccupancyGrid


@dataclass(frozen=True)
class SearchParams:
    """The search's resolution and score: the `search` section of conf/localizer/bnb.yaml."""

    sigma: float = 0.1  # m, the match grid's width around an obstacle
    depth: int = 6  # the coarsest blocks: 2^depth cells a side
    max_points: int = 120  # end points kept of the scan, evenly spread over its beams
    range_cap: float = 15.0  # m: farther end points are not matched (they drive the angle step)
    min_score: float = 0.0  # a pose must beat this to be returned


@dataclass(frozen=True)
class TopKParams:
    """How many poses a scan gets and how far apart they must be: the `top_k` section."""

    k: int = 5
    separation_m: float = 0.5
    separation_deg: float = 10.0

    def __post_init__(self) -> None:
        if self.k < 1 or self.separation_m < 0 or self.separation_deg < 0:
            raise ValueError(f"need k >= 1 and separations >= 0, got {self}")


@dataclass(frozen=True)
class Match:
    """A pose and its score, with how much of the search it took."""

    pose: np.ndarray  # (x, y, theta) in the map frame
    score: float
    nodes: int  # blocks and poses scored by the search so far (the roots' bounds included)


class MatchGrids:
    """The map's match grid and its max-pooled stack, computed once per map."""

    def __init__(self, grid: OccupancyGrid, params: SearchParams) -> None:
        occupied = grid.occupied
        if occupied.any():
            distance = distance_transform_edt(~occupied) * grid.resolution
        else:
            distance = np.full(occupied.shape, np.inf)
        base = np.exp(-0.5 * (distance / params.sigma) ** 2)
        # x = column, y = row (row 0 the bottom): stored [x, y] for the search's loops
        self.score = np.ascontiguousarray(base.T)
        self.free = np.ascontiguousarray(grid.free.T.astype(np.uint8))
        self.resolution = float(grid.resolution)
        self.origin = (float(grid.origin[0]), float(grid.origin[1]))
        self.depth = int(params.depth)
        self.stack = _pooled_stack(self.score, self.depth)
        self.free_stack = _pooled_stack(self.free.astype(np.float64), self.depth)


def _pooled_stack(values: np.ndarray, depth: int) -> np.ndarray:
    """(depth + 1, nx + W, ny + W), W = 2^depth: level h at [W - 1 + i, W - 1 + j] holds the
    max of `values` over columns i .. i + 2^h - 1 and rows j .. j + 2^h - 1 (cells outside the
    map count 0), for i, j from -(2^h - 1): every block that touches the map."""
    width = 1 << depth
    nx, ny = values.shape
    stack = np.zeros((depth + 1, nx + 2 * width, ny + 2 * width))
    stack[0, width - 1 : width - 1 + nx, width - 1 : width - 1 + ny] = values
    for h in range(1, depth + 1):
        half = 1 << (h - 1)
        prev = stack[h - 1]
        shifted = np.zeros_like(prev)
        shifted[:-half] = prev[half:]
        level = np.maximum(prev, shifted)  # columns i .. i + 2^h - 1
        shifted = np.zeros_like(level)
        shifted[:, :-half] = level[:, half:]
        stack[h] = np.maximum(level, shifted)  # and rows j .. j + 2^h - 1
    return stack


def end_points(ranges: np.ndarray, angles: np.ndarray, valid: np.ndarray, params: SearchParams):
    """The scan's end points in the robot frame: at most `max_points`, within `range_cap`."""
    keep = np.flatnonzero(valid & (ranges <= params.range_cap))
    if len(keep) > params.max_points:
        keep = keep[np.linspace(0, len(keep) - 1, params.max_points).round().astype(int)]
    r, a = ranges[keep], angles[keep]
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def heading_step(points: np.ndarray, resolution: float) -> float:
    """The angle that moves the farthest point by one cell (Cartographer's formula)."""
    reach = float(np.max(np.hypot(points[:, 0], points[:, 1]))) if len(points) else 0.0
    if reach < resolution:
        return math.pi / 4
    return math.acos(1.0 - resolution**2 / (2.0 * reach**2))


def point_offsets(points: np.ndarray, headings: np.ndarray, resolution: float) -> np.ndarray:
    """(n_headings, n_points, 2) int: each end point's cell relative to the robot's cell,
    the scan turned to each heading (the robot at its cell's centre)."""
    c, s = np.cos(headings)[:, None], np.sin(headings)[:, None]
    x = c * points[None, :, 0] - s * points[None, :, 1]
    y = s * points[None, :, 0] + c * points[None, :, 1]
    return np.stack([np.floor(0.5 + x / resolution), np.floor(0.5 + y / resolution)], -1).astype(
        np.int64
    )


@numba.njit(cache=True)
def _block_score(stack: np.ndarray, h: int, offsets: np.ndarray, tx: int, ty: int) -> float:
    """Mean of level h over the points of one heading, the block's corner at cell (tx, ty)."""
    width, height = stack.shape[1], stack.shape[2]
    pad = (1 << (stack.shape[0] - 1)) - 1
    total = 0.0
    for k in range(offsets.shape[0]):
        i = tx + offsets[k, 0] + pad
        j = ty + offsets[k, 1] + pad
        if 0 <= i < width and 0 <= j < height:
            total += stack[h, i, j]
    return total / max(offsets.shape[0], 1)


@numba.njit(cache=True)
def _has_free(free_stack: np.ndarray, h: int, tx: int, ty: int) -> bool:
    pad = (1 << (free_stack.shape[0] - 1)) - 1
    return free_stack[h, tx + pad, ty + pad] > 0.0


@numba.njit(cache=True)
def _root_bounds(stack: np.ndarray, free_stack: np.ndarray, offsets, roots) -> np.ndarray:
    """Each root block's bound (-1 where it holds no free cell)."""
    bounds = np.empty(roots.shape[0])
    for r in range(roots.shape[0]):
        a, tx, ty, h = roots[r, 0], roots[r, 1], roots[r, 2], roots[r, 3]
        if _has_free(free_stack, h, tx, ty):
            bounds[r] = _block_score(stack, h, offsets[a], tx, ty)
        else:
            bounds[r] = -1.0
    return bounds


@numba.njit(cache=True)
def _excluded(tx, ty, a, excluded, n_headings, cells_apart, steps_apart) -> bool:
    """Whether leaf (heading a, cell tx, ty) lies within the separation of an excluded one."""
    for e in range(excluded.shape[0]):
        da = abs(a - excluded[e, 0])
        da = min(da, n_headings - da)
        dx, dy = tx - excluded[e, 1], ty - excluded[e, 2]
        if dx * dx + dy * dy <= cells_apart * cells_apart and da <= steps_apart:
            return True
    return False


@numba.njit(cache=True)
def _search(
    stack, free_stack, offsets, roots, bounds, min_score, excluded, cells_apart, steps_apart, seeds
):
    """Depth-first branch and bound from `roots` (heading, tx, ty, depth) with their `bounds`,
    tried in order; returns (best score, heading, tx, ty, nodes scored). Children are expanded
    best first. `seeds` (heading, tx, ty): poses scored before the search (a guide's), the best
    of them the bound every block must beat from the start."""
    n_headings = offsets.shape[0]
    best, best_a, best_x, best_y = min_score, -1, -1, -1
    nodes = 0
    for g in range(seeds.shape[0]):
        a, tx, ty = seeds[g, 0], seeds[g, 1], seeds[g, 2]
        if not (0 <= a < n_headings) or not _has_free(free_stack, 0, tx, ty):
            continue
        if _excluded(tx, ty, a, excluded, n_headings, cells_apart, steps_apart):
            continue
        s = _block_score(stack, 0, offsets[a], tx, ty)
        nodes += 1
        if s > best:
            best, best_a, best_x, best_y = s, a, tx, ty
    cap = roots.shape[0] + 64 * (stack.shape[0] + 1) * 4
    st_a = np.empty(cap, np.int64)
    st_x = np.empty(cap, np.int64)
    st_y = np.empty(cap, np.int64)
    st_h = np.empty(cap, np.int64)
    st_s = np.empty(cap, np.float64)
    top = 0
    for r in range(roots.shape[0] - 1, -1, -1):  # the first root on top of the stack
        if bounds[r] <= min_score:
            continue
        st_a[top], st_x[top], st_y[top], st_h[top] = (
            roots[r, 0],
            roots[r, 1],
            roots[r, 2],
            roots[r, 3],
        )
        st_s[top] = bounds[r]
        top += 1
    child_s = np.empty(4, np.float64)
    child_x = np.empty(4, np.int64)
    child_y = np.empty(4, np.int64)
    while top > 0:
        top -= 1
        a, tx, ty, h, s = st_a[top], st_x[top], st_y[top], st_h[top], st_s[top]
        if s <= best:
            continue
        if h == 0:
            if _excluded(tx, ty, a, excluded, n_headings, cells_apart, steps_apart):
                continue
            best, best_a, best_x, best_y = s, a, tx, ty
            continue
        half = 1 << (h - 1)
        n = 0
        for dx in range(2):
            for dy in range(2):
                cx, cy = tx + dx * half, ty + dy * half
                if not _has_free(free_stack, h - 1, cx, cy):
                    continue
                cs = _block_score(stack, h - 1, offsets[a], cx, cy)
                nodes += 1
                if cs > best:
                    child_s[n], child_x[n], child_y[n] = cs, cx, cy
                    n += 1
        # push the worst first, so that the best child is expanded next
        for i in range(n):
            worst = i
            for j in range(i + 1, n):
                if child_s[j] < child_s[worst]:
                    worst = j
            child_s[i], child_s[worst] = child_s[worst], child_s[i]
            child_x[i], child_x[worst] = child_x[worst], child_x[i]
            child_y[i], child_y[worst] = child_y[worst], child_y[i]
            st_a[top], st_x[top], st_y[top], st_h[top], st_s[top] = (
                a,
                child_x[i],
                child_y[i],
                h - 1,
                child_s[i],
            )
            top += 1
    return best, best_a, best_x, best_y, nodes


class GlobalSearch:
    """Branch and bound for one map: `search` / `search_top_k` per scan."""

    def __init__(self, grid: OccupancyGrid, params: SearchParams) -> None:
        self.params = params
        self.grids = MatchGrids(grid, params)

    def _setup(self, points: np.ndarray):
        g = self.grids
        step = heading_step(points, g.resolution)
        n_headings = max(1, math.ceil(2 * math.pi / step))
        headings = np.arange(n_headings) * (2 * math.pi / n_headings)
        return headings, point_offsets(points, headings, g.resolution)

    def roots(
        self, offsets: np.ndarray, order: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(heading, tx, ty, depth) of every coarsest block and its bound, best bound first
        (Cartographer's order); the blocks holding the guide's (heading index, tx, ty) before
        all others, in the guide's order."""
        g = self.grids
        width = 1 << g.depth
        nx, ny = g.score.shape
        xs, ys = np.arange(0, nx, width), np.arange(0, ny, width)
        a, bx, by = np.meshgrid(np.arange(len(offsets)), xs, ys, indexing="ij")
        roots = np.column_stack([a.ravel(), bx.ravel(), by.ravel(), np.full(a.size, g.depth)])
        roots = np.ascontiguousarray(roots, dtype=np.int64)
        bounds = _root_bounds(g.stack, g.free_stack, offsets, roots)
        rank = np.full(len(roots), len(roots), dtype=np.int64)
        if order is not None and len(order):
            index = {(int(r[0]), int(r[1]), int(r[2])): i for i, r in enumerate(roots)}
            for place, (ai, tx, ty) in enumerate(order):
                key = (int(ai) % len(offsets), int(tx) // width * width, int(ty) // width * width)
                if key in index and rank[index[key]] == len(roots):
                    rank[index[key]] = place
        chosen = np.lexsort((-bounds, rank))
        return roots[chosen], bounds[chosen]

    def search_top_k(
        self,
        points: np.ndarray,
        k: int,
        separation_m: float = 0.5,
        separation_rad: float = math.radians(10.0),
        guide: np.ndarray | None = None,
    ) -> list[Match]:
        """The k best poses (end points in the robot frame), each more than the separation
        from the ones before in position or in heading. `guide`: (n, 3) poses (x, y, theta)
        to try first, e.g. a learned model's hypotheses."""
        g = self.grids
        headings, offsets = self._setup(points)
        order = None
        if guide is not None and len(guide):
            step = 2 * math.pi / len(headings)
            order = np.column_stack(
                [
                    np.round(np.mod(guide[:, 2], 2 * math.pi) / step).astype(np.int64)
                    % len(headings),
                    np.floor((guide[:, 0] - g.origin[0]) / g.resolution).astype(np.int64),
                    np.floor((guide[:, 1] - g.origin[1]) / g.resolution).astype(np.int64),
                ]
            )
        roots, bounds = self.roots(offsets, order)
        cells_apart = separation_m / g.resolution
        steps_apart = separation_rad / (2 * math.pi / len(headings))
        seeds = np.empty((0, 3), np.int64) if order is None else order
        seeds = seeds[(seeds[:, 1] >= 0) & (seeds[:, 1] < g.score.shape[0])]
        seeds = np.ascontiguousarray(seeds[(seeds[:, 2] >= 0) & (seeds[:, 2] < g.score.shape[1])])
        excluded = np.empty((0, 3), np.int64)
        found: list[Match] = []
        scored = len(roots)  # every root's bound, once per scan
        for _ in range(k):
            score, a, tx, ty, nodes = _search(
                g.stack, g.free_stack, offsets, roots, bounds, self.params.min_score, excluded,
                cells_apart, steps_apart, seeds,
            )  # fmt: skip
            if a < 0:
                break
            x = g.origin[0] + (tx + 0.5) * g.resolution
            y = g.origin[1] + (ty + 0.5) * g.resolution
            scored += int(nodes)
            found.append(Match(np.array([x, y, headings[a]]), float(score), scored))
            excluded = np.vstack([excluded, [[a, tx, ty]]])
        return found

    def search(self, points: np.ndarray, guide: np.ndarray | None = None) -> Match | None:
        """The best pose for the end points (robot frame), or None below `min_score`."""
        found = self.search_top_k(points, 1, guide=guide)
        return found[0] if found else None


@numba.njit(cache=True)
def _brute_force(level: np.ndarray, free: np.ndarray, offsets: np.ndarray, pad: int):
    best, best_a, best_x, best_y = -1.0, -1, -1, -1
    nx, ny = free.shape
    for a in range(offsets.shape[0]):
        for tx in range(nx):
            for ty in range(ny):
                if free[tx, ty] == 0:
                    continue
                total = 0.0
                for k in range(offsets.shape[1]):
                    i, j = tx + offsets[a, k, 0] + pad, ty + offsets[a, k, 1] + pad
                    if 0 <= i < level.shape[0] and 0 <= j < level.shape[1]:
                        total += level[i, j]
                score = total / max(offsets.shape[1], 1)
                if score > best:
                    best, best_a, best_x, best_y = score, a, tx, ty
    return best, best_a, best_x, best_y


def brute_force(grids: MatchGrids, offsets: np.ndarray) -> tuple[float, int, int, int]:
    """The plain reference: every heading at every free cell scored, the first best kept;
    (score, heading index, tx, ty)."""
    pad = (1 << grids.depth) - 1
    return _brute_force(grids.stack[0], grids.free, offsets, pad)
