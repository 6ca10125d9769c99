"""Routes through a map for a robot to drive: a coarse wall-averse graph of the free space,
waypoints spread over it, the shortest open tour through them, resampled and smoothed
(steps 1-3 of scanloc.trajectory.drive's doc)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.ndimage import uniform_filter1d
from scipy.sparse.csgraph import connected_components, dijkstra

from scanloc.world.occupancy_grid import OccupancyGrid

PLAN_RESOLUTION = 0.1  # metres between planning graph nodes
TRACK_MARGIN = 0.08  # metres of room left for the controller's deviation from the route
MAX_WAYPOINTS = 24
ROUTE_SPACING = 0.05  # metres between resampled route points
SMOOTH_WINDOW = 0.6  # metres of route averaged by the smoother


def pose_clearance(grid: OccupancyGrid, clear: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """A lower bound on the distance from points (N, 2) to every occupied or unknown cell;
    `clear` is centre_clearance(grid) in metres.

    A point p in cell c is within |p - centre(c)| of the centre, and a blocked cell's square
    lies within res/√2 of its centre, so clearance(p) >= clear[c] - |p - c| - res/√2.
    """
    col, row = grid.world_to_cell(xy[:, 0], xy[:, 1])
    inside = (col >= 0) & (col < grid.width) & (row >= 0) & (row < grid.height)
    col_c, row_c = np.clip(col, 0, grid.width - 1), np.clip(row, 0, grid.height - 1)
    cx, cy = grid.cell_center(col_c, row_c)
    bound = clear[row_c, col_c] - np.hypot(xy[:, 0] - cx, xy[:, 1] - cy)
    return np.where(inside, bound - grid.resolution / math.sqrt(2.0), -np.inf)


@dataclass(frozen=True)
class PlanningGraph:
    """The coarse planning graph: node positions, edge costs (wall-averse) and edge lengths."""

    xy: np.ndarray
    cost: sparse.csr_matrix
    length: sparse.csr_matrix


def planning_graph(grid: OccupancyGrid, clear: np.ndarray, clearance: float) -> PlanningGraph:
    step = max(1, round(PLAN_RESOLUTION / grid.resolution))
    rows = np.arange(step // 2, grid.height, step)
    cols = np.arange(step // 2, grid.width, step)
    node_clear = clear[np.ix_(rows, cols)]
    spacing = step * grid.resolution
    # A point within half an edge of a node keeps clearance from every blocked cell square.
    need = clearance + grid.resolution / math.sqrt(2.0) + spacing / math.sqrt(2.0) + TRACK_MARGIN
    allowed = node_clear >= need
    if not allowed.any():
        raise ValueError(
            f"no free space keeps clearance {clearance} m (+ {need - clearance:.3f} m margin) "
            "from obstacles: lower `clearance` or use a roomier map"
        )
    index = np.full(allowed.shape, -1, dtype=np.int64)
    index[allowed] = np.arange(int(allowed.sum()))
    # Cost grows near walls (up to 4x at the limit), so routes keep to the middle of passages.
    penalty = 1.0 + 3.0 * np.clip(1.0 - (node_clear - need) / 0.5, 0.0, 1.0)
    height, width = allowed.shape
    src, dst, length, cost = [], [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        here = (slice(0, height - dr), slice(max(0, -dc), width - max(0, dc)))
        there = (slice(dr, height), slice(max(0, dc), width - max(0, -dc)))
        ok = allowed[here] & allowed[there]
        src.append(index[here][ok])
        dst.append(index[there][ok])
        edge = spacing * math.hypot(dr, dc)
        length.append(np.full(int(ok.sum()), edge))
        cost.append(edge * 0.5 * (penalty[here][ok] + penalty[there][ok]))
    n = int(allowed.sum())
    ij = (np.concatenate(src), np.concatenate(dst))
    rr, cc = np.nonzero(allowed)
    x, y = grid.cell_center(cols[cc], rows[rr])
    return PlanningGraph(
        xy=np.column_stack([x, y]),
        cost=sparse.coo_matrix((np.concatenate(cost), ij), shape=(n, n)).tocsr(),
        length=sparse.coo_matrix((np.concatenate(length), ij), shape=(n, n)).tocsr(),
    )


def spread_points(graph: PlanningGraph, start: int, reachable: np.ndarray) -> list[int]:
    """Farthest-point sampling along the graph (by length): MAX_WAYPOINTS spread-out nodes."""
    points = [start]
    nearest = np.where(reachable, dijkstra(graph.length, directed=False, indices=start), -1.0)
    while len(points) < MAX_WAYPOINTS and nearest.max() > 0.0:
        points.append(int(np.argmax(nearest)))
        dist = dijkstra(graph.length, directed=False, indices=points[-1])
        nearest = np.minimum(nearest, np.where(reachable, dist, -1.0))
    return points


def open_tour(dist: np.ndarray) -> list[int]:
    """A short open path through all points from point 0: nearest neighbour, then 2-opt."""
    order, left = [0], set(range(1, len(dist)))
    while left:
        order.append(min(left, key=lambda j: (dist[order[-1], j], j)))
        left.remove(order[-1])
    improved = True
    while improved:
        improved = False
        for i in range(1, len(order) - 1):
            for j in range(i + 1, len(order)):
                a, b = order[i - 1], order[i]
                c, d = order[j], order[j + 1] if j + 1 < len(order) else None
                old = dist[a, b] + (dist[c, d] if d is not None else 0.0)
                new = dist[a, c] + (dist[b, d] if d is not None else 0.0)
                if new < old - 1e-9:
                    order[i : j + 1] = order[i : j + 1][::-1]
                    improved = True
    return order


def plan_route(
    graph: PlanningGraph, rng: np.random.Generator, sweep_length: float, route_length: float
) -> tuple[np.ndarray, np.ndarray]:
    """The route's node positions (M, 2) and its waypoints (K, 2) in visiting order.

    Waypoints are spread by farthest-point sampling from a random start. The most of them (in
    sampling order) whose shortest open tour is at most `sweep_length` long are visited first:
    a sweep across the map sized to the run. Then tours through the others, and again through
    all, until the route is `route_length` long. Legs follow the cheapest (wall-averse) paths.
    """
    _, comp = connected_components(graph.cost, directed=False)
    reachable = comp == np.bincount(comp).argmax()
    if reachable.sum() < 2:
        raise ValueError("the reachable free space is a single planning node: nowhere to drive")
    candidates = np.flatnonzero(reachable)
    points = spread_points(graph, int(candidates[rng.integers(len(candidates))]), reachable)
    preds = [
        dijkstra(graph.cost, directed=False, indices=p, return_predecessors=True)[1] for p in points
    ]
    legs: dict[tuple[int, int], list[int]] = {}

    def leg(i: int, j: int) -> list[int]:
        """Nodes from waypoint i to waypoint j (both included) along the cheapest path."""
        if (i, j) not in legs:
            nodes = [points[i]]
            while nodes[-1] != points[j]:
                nodes.append(int(preds[j][nodes[-1]]))
            legs[i, j] = nodes
        return legs[i, j]

    n = len(points)
    dist = np.array(
        [
            [np.hypot(*np.diff(graph.xy[leg(i, j)], axis=0).T).sum() for j in range(n)]
            for i in range(n)
        ]
    )

    def tour(subset: list[int]) -> list[int]:
        return [subset[k] for k in open_tour(dist[np.ix_(subset, subset)])]

    def length_of(order: list[int]) -> float:
        return float(sum(dist[i, j] for i, j in itertools.pairwise(order)))

    k = 2
    while k < n and length_of(tour(list(range(k + 1)))) <= sweep_length:
        k += 1
    order = tour(list(range(min(k, n))))
    rest = [i for i in range(n) if i not in order]
    while length_of(order) < route_length:
        here = order[-1]
        order += tour([here, *(rest or [i for i in range(n) if i != here])])[1:]
        rest = []
    path = [points[order[0]]]
    for i, j in itertools.pairwise(order):
        path += leg(i, j)[1:]
    return graph.xy[np.asarray(path)], graph.xy[np.asarray([points[i] for i in order])]


def resample_polyline(polyline: np.ndarray, spacing: float) -> np.ndarray:
    seg = np.hypot(*np.diff(polyline, axis=0).T)
    keep = np.concatenate([[True], seg > 1e-9])
    polyline = polyline[keep]
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(polyline, axis=0).T))])
    t = np.arange(0.0, s[-1], spacing)
    return np.column_stack([np.interp(t, s, polyline[:, 0]), np.interp(t, s, polyline[:, 1])])


def smooth_route(
    route: np.ndarray, grid: OccupancyGrid, clear: np.ndarray, need: float
) -> np.ndarray:
    """Moving-average smoothing, undone wherever it would bring the route closer to a wall."""
    window = max(1, round(SMOOTH_WINDOW / ROUTE_SPACING)) | 1
    smooth = uniform_filter1d(route, size=window, axis=0, mode="nearest")
    unsafe = pose_clearance(grid, clear, smooth) < need
    smooth[unsafe] = route[unsafe]
    return smooth
