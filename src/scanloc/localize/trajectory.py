"""A robot driven through a map at a fixed rate, with ground truth and drifting wheel odometry.

The route (paper §4.4: "a robot steered through map 1"):
1. A coarse (0.1 m) graph of the free cells that keep `clearance` plus safety margins from any
   occupied or unknown cell; edges cost their length, more near walls, so routes keep to the
   middle of passages.
2. Waypoints spread over the reachable space by farthest-point sampling along the graph; the
   most of them (in sampling order) whose shortest open tour (nearest neighbour + 2-opt) the
   robot can drive in `num_steps` are visited first, so a short run still sweeps across the
   map and a long one covers it; further tours follow until the route is long enough.
3. The shortest paths between them (scipy's Dijkstra) are joined, resampled and smoothed.
4. A pure-pursuit controller follows the route as a unicycle with speed, turn-rate and
   acceleration limits, integrated exactly over each 1/rate_hz step.
Every true pose is checked to keep `clearance` from every occupied or unknown cell.

Kidnapping (`kidnap_steps`): at each listed step the robot is carried to a random place and
drives on from there: the run is split into segments, each driven as above from its own random
start (a reachable node of the planning graph, heading along its new route). The wheels do not
turn while the robot is carried, so the odometry sees no motion across a kidnap: it integrates
wheel motion only, and from the first kidnap on it no longer matches the truth.

Odometry: the true motion of each step, split as (rot1, trans, rot2), is reported with
Gaussian noise of standard deviation sqrt(alpha1·rot² + alpha2·trans²) for the rotations and
sqrt(alpha3·trans² + alpha4·(rot1² + rot2²)) for the translation, plus systematic scale errors
(a wrong wheel radius or wheel base), and integrated. The odometry frame starts at the true
start pose (odometry[0] == truth[0]), so odometry - truth is the accumulated drift.
"""

from __future__ import annotations

import io
import itertools
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse
from scipy.ndimage import uniform_filter1d
from scipy.sparse.csgraph import connected_components, dijkstra

from scanloc.io import atomic_path
from scanloc.localize.estimates import wrap_angle
from scanloc.world.free_space import centre_clearance
from scanloc.world.occupancy_grid import OccupancyGrid

PLAN_RESOLUTION = 0.1  # metres between planning graph nodes
TRACK_MARGIN = 0.08  # metres of room left for the controller's deviation from the route
MAX_WAYPOINTS = 24
ROUTE_SPACING = 0.05  # metres between resampled route points
SMOOTH_WINDOW = 0.6  # metres of route averaged by the smoother
FILES = ("truth.npy", "odometry.npy", "times.npy", "ranges.npy", "meta.json", "route.png")


@dataclass(frozen=True)
class OdometryNoise:
    """Wheel odometry errors per step (alpha-style random part plus systematic scale errors).

    alpha1: rotation variance per squared rotation; alpha2: rotation variance per squared
    translation (rad²/m²); alpha3: translation variance per squared translation; alpha4:
    translation variance per squared rotation (m²/rad²). trans_scale / rot_scale: reported
    translation / rotation = (1 + scale) · true. The defaults model a calibrated
    differential drive: about 5 % random error per step, 0.5 % / 0.25 % scale errors.
    """

    alpha1: float = 0.0025
    alpha2: float = 0.0004
    alpha3: float = 0.0025
    alpha4: float = 0.0001
    trans_scale: float = 0.005
    rot_scale: float = 0.0025

    def __post_init__(self) -> None:
        if min(self.alpha1, self.alpha2, self.alpha3, self.alpha4) < 0:
            raise ValueError("odometry noise alphas must be >= 0")


@dataclass(frozen=True)
class Trajectory:
    """A driven run: times (T,), truth (T, 3) and odometry (T, 3) poses (x, y, θ ∈ (-π, π]).

    `odometry` is the wheel-odometry pose in the odometry frame, which starts at the true start
    pose. `waypoints` (K, 2) are the route's waypoints in visiting order. `kidnap_steps` are the
    steps at which the robot was carried elsewhere (truth[k] is the first pose after it).
    """

    times: np.ndarray
    truth: np.ndarray
    odometry: np.ndarray
    waypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    kidnap_steps: tuple[int, ...] = ()


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
class _Graph:
    """The coarse planning graph: node positions, edge costs (wall-averse) and edge lengths."""

    xy: np.ndarray
    cost: sparse.csr_matrix
    length: sparse.csr_matrix


def _planning_graph(grid: OccupancyGrid, clear: np.ndarray, clearance: float) -> _Graph:
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
    return _Graph(
        xy=np.column_stack([x, y]),
        cost=sparse.coo_matrix((np.concatenate(cost), ij), shape=(n, n)).tocsr(),
        length=sparse.coo_matrix((np.concatenate(length), ij), shape=(n, n)).tocsr(),
    )


def _spread_points(graph: _Graph, start: int, reachable: np.ndarray) -> list[int]:
    """Farthest-point sampling along the graph (by length): MAX_WAYPOINTS spread-out nodes."""
    points = [start]
    nearest = np.where(reachable, dijkstra(graph.length, directed=False, indices=start), -1.0)
    while len(points) < MAX_WAYPOINTS and nearest.max() > 0.0:
        points.append(int(np.argmax(nearest)))
        dist = dijkstra(graph.length, directed=False, indices=points[-1])
        nearest = np.minimum(nearest, np.where(reachable, dist, -1.0))
    return points


def _open_tour(dist: np.ndarray) -> list[int]:
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


def _route(
    graph: _Graph, rng: np.random.Generator, sweep_length: float, route_length: float
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
    points = _spread_points(graph, int(candidates[rng.integers(len(candidates))]), reachable)
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
        return [subset[k] for k in _open_tour(dist[np.ix_(subset, subset)])]

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


def _resample(polyline: np.ndarray, spacing: float) -> np.ndarray:
    seg = np.hypot(*np.diff(polyline, axis=0).T)
    keep = np.concatenate([[True], seg > 1e-9])
    polyline = polyline[keep]
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(polyline, axis=0).T))])
    t = np.arange(0.0, s[-1], spacing)
    return np.column_stack([np.interp(t, s, polyline[:, 0]), np.interp(t, s, polyline[:, 1])])


def _smooth(route: np.ndarray, grid: OccupancyGrid, clear: np.ndarray, need: float) -> np.ndarray:
    """Moving-average smoothing, undone wherever it would bring the route closer to a wall."""
    window = max(1, round(SMOOTH_WINDOW / ROUTE_SPACING)) | 1
    smooth = uniform_filter1d(route, size=window, axis=0, mode="nearest")
    unsafe = pose_clearance(grid, clear, smooth) < need
    smooth[unsafe] = route[unsafe]
    return smooth


def _pure_pursuit(
    route: np.ndarray,
    num_steps: int,
    dt: float,
    max_speed: float,
    max_turn_rate: float,
    max_accel: float,
    max_turn_accel: float,
    lookahead: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Drive the route: true poses (T, 3) and per-step (rot1, trans, rot2) increments (T-1, 3)."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(route, axis=0).T))])
    ahead = math.ceil(2.0 * max(lookahead, max_speed * dt * 4) / ROUTE_SPACING) + 2
    first = min(int(np.searchsorted(s, lookahead)), len(route) - 1)
    x, y = route[0]
    theta = math.atan2(route[first, 1] - y, route[first, 0] - x)
    v = omega = 0.0
    idx = 0
    poses = np.empty((num_steps, 3))
    steps = np.zeros((max(num_steps - 1, 0), 3))
    poses[0] = (x, y, theta)
    for t in range(1, num_steps):
        window = route[idx : idx + ahead]
        idx += int(np.argmin(np.hypot(window[:, 0] - x, window[:, 1] - y)))
        target = int(np.searchsorted(s, s[idx] + lookahead))
        if target >= len(route):
            raise RuntimeError("the route ran out before num_steps; this is a bug in the planner")
        dx, dy = route[target, 0] - x, route[target, 1] - y
        alpha = math.atan2(dy, dx) - theta
        alpha = float(wrap_angle(alpha))
        if abs(alpha) > math.pi / 3:  # target far off the heading: stop and turn towards it
            v_cmd, omega_cmd = 0.0, math.copysign(min(max_turn_rate, 2.0 * abs(alpha)), alpha)
        else:
            curvature = 2.0 * math.sin(alpha) / max(math.hypot(dx, dy), 1e-9)
            v_cmd = max_speed * math.cos(alpha)
            if abs(curvature) > 1e-9:
                v_cmd = min(v_cmd, 0.8 * max_turn_rate / abs(curvature))
            v_cmd = min(max(v_cmd, v - max_accel * dt), v + max_accel * dt)
            omega_cmd = curvature * v_cmd
        v = min(max(v_cmd, v - max_accel * dt, 0.0), v + max_accel * dt, max_speed)
        omega = min(max(omega_cmd, omega - max_turn_accel * dt), omega + max_turn_accel * dt)
        omega = min(max(omega, -max_turn_rate), max_turn_rate)
        dtheta = omega * dt
        chord = v * dt if abs(dtheta) < 1e-12 else 2.0 * v / omega * math.sin(dtheta / 2.0)
        x += chord * math.cos(theta + dtheta / 2.0)
        y += chord * math.sin(theta + dtheta / 2.0)
        theta = float(wrap_angle(theta + dtheta))
        poses[t] = (x, y, theta)
        steps[t - 1] = (dtheta / 2.0, chord, dtheta / 2.0)
    return poses, steps


def integrate_odometry(
    start: np.ndarray, steps: np.ndarray, noise: OdometryNoise, rng: np.random.Generator
) -> np.ndarray:
    """Odometry poses (T, 3) from true per-step (rot1, trans, rot2) increments and the noise."""
    rot1, trans, rot2 = steps.T
    sd_rot1 = np.sqrt(noise.alpha1 * rot1**2 + noise.alpha2 * trans**2)
    sd_trans = np.sqrt(noise.alpha3 * trans**2 + noise.alpha4 * (rot1**2 + rot2**2))
    sd_rot2 = np.sqrt(noise.alpha1 * rot2**2 + noise.alpha2 * trans**2)
    z = rng.standard_normal((len(steps), 3))
    r1 = (1.0 + noise.rot_scale) * rot1 + sd_rot1 * z[:, 0]
    tr = (1.0 + noise.trans_scale) * trans + sd_trans * z[:, 1]
    r2 = (1.0 + noise.rot_scale) * rot2 + sd_rot2 * z[:, 2]
    heading_before = start[2] + np.concatenate([[0.0], np.cumsum(r1 + r2)[:-1]])
    heading_mid = heading_before + r1
    out = np.empty((len(steps) + 1, 3))
    out[0] = start
    out[1:, 0] = start[0] + np.cumsum(tr * np.cos(heading_mid))
    out[1:, 1] = start[1] + np.cumsum(tr * np.sin(heading_mid))
    out[1:, 2] = wrap_angle(heading_mid + r2)
    return out


def drive_trajectory(
    grid: OccupancyGrid,
    num_steps: int,
    rate_hz: float = 10.0,
    seed: int = 0,
    clearance: float = 0.3,
    max_speed: float = 0.5,
    max_turn_rate: float = 1.0,
    odometry_noise: OdometryNoise | None = None,
    max_accel: float = 0.5,
    max_turn_accel: float = 2.0,
    lookahead: float = 0.35,
    kidnap_steps: tuple[int, ...] = (),
) -> Trajectory:
    """Drive a robot through `grid` for `num_steps` steps at `rate_hz`, carried to a random
    place at each of `kidnap_steps` (see the module doc)."""
    if num_steps < 1:
        raise ValueError(f"num_steps must be >= 1, got {num_steps}")
    if not (rate_hz > 0 and max_speed > 0 and max_turn_rate > 0 and clearance >= 0):
        raise ValueError("rate_hz, max_speed and max_turn_rate must be > 0, clearance >= 0")
    kidnaps = tuple(int(k) for k in kidnap_steps)
    bounds = (0, *kidnaps, num_steps)
    if any(b - a < 2 for a, b in itertools.pairwise(bounds)):
        raise ValueError(
            f"kidnap_steps must increase within 2..{num_steps - 2}, at least 2 steps apart, "
            f"got {list(kidnaps)}"
        )
    noise = odometry_noise or OdometryNoise()
    plan_rng, odom_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    dt = 1.0 / rate_hz
    clear = centre_clearance(grid) * grid.resolution  # metres
    graph = _planning_graph(grid, clear, clearance)
    truths, increments, waypoints = [], [], []
    for start, stop in itertools.pairwise(bounds):
        steps_here = stop - start
        reach = steps_here * dt * max_speed  # no segment drives farther than this
        polyline, points = _route(graph, plan_rng, reach, 1.1 * reach + 4.0 * lookahead + 1.0)
        route = _smooth(_resample(polyline, ROUTE_SPACING), grid, clear, clearance + TRACK_MARGIN)
        truth, steps = _pure_pursuit(
            route, steps_here, dt, max_speed, max_turn_rate, max_accel, max_turn_accel, lookahead
        )
        if truths:
            increments.append(np.zeros((1, 3)))  # carried: the wheels do not turn
        truths.append(truth)
        increments.append(steps)
        waypoints.append(points)
    truth = np.concatenate(truths)
    worst = float(pose_clearance(grid, clear, truth[:, :2]).min())
    if worst < clearance:
        raise RuntimeError(
            f"the driven path came within {worst:.3f} m of an obstacle (clearance {clearance} m)"
        )
    odometry = integrate_odometry(truth[0], np.concatenate(increments), noise, odom_rng)
    return Trajectory(
        times=np.arange(num_steps) * dt,
        truth=truth,
        odometry=odometry,
        waypoints=np.concatenate(waypoints),
        kidnap_steps=kidnaps,
    )


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def _route_png(traj: Trajectory, grid: OccupancyGrid | None) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6), dpi=100)
    if grid is not None:
        shade = np.full(grid.cells.shape, 0.7)
        shade[grid.free] = 1.0
        shade[grid.occupied] = 0.0
        w, h = grid.size_m
        extent = (grid.origin[0], grid.origin[0] + w, grid.origin[1], grid.origin[1] + h)
        ax.imshow(shade, cmap="gray", vmin=0, vmax=1, origin="lower", extent=extent)
    truth = np.insert(traj.truth[:, :2], list(traj.kidnap_steps), np.nan, axis=0)  # no jumps
    ax.plot(truth[:, 0], truth[:, 1], color="tab:blue", lw=1.2, label="truth")
    for k in traj.kidnap_steps:
        ax.plot(*traj.truth[k, :2], "*", color="tab:purple", ms=10)
    ax.plot(
        traj.odometry[:, 0],
        traj.odometry[:, 1],
        color="tab:orange",
        lw=1.0,
        ls="--",
        label="odometry",
    )
    ax.plot(*traj.truth[0, :2], "o", color="tab:green", label="start")
    if len(traj.waypoints):
        ax.plot(traj.waypoints[:, 0], traj.waypoints[:, 1], "x", color="tab:red", label="waypoints")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    kidnaps = f", kidnapped at steps {list(traj.kidnap_steps)} (stars)" if traj.kidnap_steps else ""
    ax.set_title(f"driven route: {len(traj.times)} steps{kidnaps}", fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def save_trajectory(
    traj: Trajectory,
    out_dir: str | Path,
    ranges: np.ndarray,
    meta: Mapping[str, Any],
    grid: OccupancyGrid | None = None,
) -> None:
    """Write data/trajectories/<name>/: truth, odometry, times, ranges (.npy), meta.json, route.png.

    `meta` is stored with the run's shape added (num_steps, num_beams, rate_hz, waypoints,
    odometry_frame). `grid`, when given, is drawn under the route in route.png.
    """
    out = Path(out_dir)
    ranges = np.asarray(ranges)
    steps = len(traj.times)
    if ranges.ndim != 2 or ranges.shape[0] != steps:
        raise ValueError(f"ranges must have shape (T={steps}, B), got {ranges.shape}")
    if ranges.dtype != np.float32 or np.isnan(ranges).any():
        raise ValueError(f"ranges must be float32 without NaN, got {ranges.dtype}")
    full_meta = dict(meta)
    full_meta.update(
        num_steps=steps,
        num_beams=int(ranges.shape[1]),
        rate_hz=round(float(1.0 / (traj.times[1] - traj.times[0])), 9) if steps > 1 else None,
        odometry_frame="starts at the true start pose",
        waypoints=[[round(float(a), 6) for a in w] for w in traj.waypoints],
    )
    if traj.kidnap_steps:
        full_meta["kidnap_steps"] = list(traj.kidnap_steps)
    payload = {
        "truth.npy": _npy_bytes(np.asarray(traj.truth, dtype=np.float64)),
        "odometry.npy": _npy_bytes(np.asarray(traj.odometry, dtype=np.float64)),
        "times.npy": _npy_bytes(np.asarray(traj.times, dtype=np.float64)),
        "ranges.npy": _npy_bytes(ranges),
        "meta.json": (json.dumps(full_meta, indent=2, sort_keys=True) + "\n").encode(),
        "route.png": _route_png(traj, grid),
    }
    out.mkdir(parents=True, exist_ok=True)
    for name, data in payload.items():
        with atomic_path(out / name) as tmp:
            tmp.write_bytes(data)


def load_trajectory(directory: str | Path) -> tuple[Trajectory, np.ndarray]:
    """Read what `save_trajectory` wrote: (Trajectory, ranges float32 (T, B))."""
    d = Path(directory)
    arrays = {}
    for name in ("truth", "odometry", "times", "ranges"):
        path = d / f"{name}.npy"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: file not found (expected a saved trajectory)")
        arrays[name] = np.load(path, allow_pickle=False)
    steps = arrays["times"].shape
    if len(steps) != 1:
        raise ValueError(f"{d / 'times.npy'}: expected shape (T,), got {steps}")
    for name in ("truth", "odometry"):
        if arrays[name].shape != (steps[0], 3):
            raise ValueError(
                f"{d / name}.npy: expected shape ({steps[0]}, 3), got {arrays[name].shape}"
            )
    if arrays["ranges"].ndim != 2 or arrays["ranges"].shape[0] != steps[0]:
        raise ValueError(
            f"{d / 'ranges.npy'}: expected shape ({steps[0]}, B), got {arrays['ranges'].shape}"
        )
    waypoints = np.zeros((0, 2))
    kidnaps: tuple[int, ...] = ()
    meta_path = d / "meta.json"
    if meta_path.is_file():
        meta = json.loads(meta_path.read_text())
        if meta.get("waypoints"):
            waypoints = np.asarray(meta["waypoints"], dtype=np.float64).reshape(-1, 2)
        kidnaps = tuple(int(k) for k in meta.get("kidnap_steps", ()))
    traj = Trajectory(
        times=arrays["times"],
        truth=arrays["truth"],
        odometry=arrays["odometry"],
        waypoints=waypoints,
        kidnap_steps=kidnaps,
    )
    return traj, arrays["ranges"]
