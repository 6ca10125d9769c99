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

import itertools
import math

import numpy as np

from scanloc.pose import wrap_angle
from scanloc.trajectory.format import Trajectory
from scanloc.trajectory.odometry import OdometryNoise, integrate_odometry
from scanloc.trajectory.planning import (
    ROUTE_SPACING,
    TRACK_MARGIN,
    plan_route,
    planning_graph,
    pose_clearance,
    resample_polyline,
    smooth_route,
)
from scanloc.world.free_space import centre_clearance
from scanloc.world.occupancy_grid import OccupancyGrid


def pure_pursuit(
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
    graph = planning_graph(grid, clear, clearance)
    truths, increments, waypoints = [], [], []
    for start, stop in itertools.pairwise(bounds):
        steps_here = stop - start
        reach = steps_here * dt * max_speed  # no segment drives farther than this
        polyline, points = plan_route(graph, plan_rng, reach, 1.1 * reach + 4.0 * lookahead + 1.0)
        route = smooth_route(
            resample_polyline(polyline, ROUTE_SPACING), grid, clear, clearance + TRACK_MARGIN
        )
        truth, steps = pure_pursuit(
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
