"""Verified hypotheses: each of the learned localizer's top-K poses checked against the map.

The network ranks (cell, heading-bin) hypotheses from the scan alone; it never looks at the map
it was trained in, so its top-1 is often a near miss or a look-alike place while the truth
waits lower in its list. The map can tell them apart. For every hypothesis:

1. **Refine** — a few Gauss-Newton steps of scan-to-map matching: the beam end points are moved
   down the gradient of the distance to the nearest obstacle surface (a signed distance field,
   bilinearly interpolated, capped at `max_distance` so that far beams pull nothing), each beam
   weighted by Huber's rule so that people and glass do not drag the pose (Hector SLAM's and
   Cartographer's ceres matcher do the same on a smoothed occupancy grid).
2. **Score** — at the refined pose: the share of beams whose end point lies within
   `inlier_distance` of the map (`inlier_fraction`), their mean capped distance, the
   network's own probability, and how much more of the scan it explains than the best other
   hypothesis of the same scan (`inlier_margin`: a hypothesis that explains the scan no
   better than a look-alike elsewhere is not the answer, however well it fits).
3. **Re-rank** by the share of the scan explained; a hypothesis that refined onto a better
   one's pose is merged.
4. **Calibrate** — a logistic regression of the four features onto "this hypothesis is within
   0.5 m and 10° of the truth" (`ScoreCalibration`), fitted on the best hypothesis of each of
   a set of scans that are never scored (the map's validation scans), turns them into a
   probability. Fitted on the best ones because the best is what a user acts on: fitted on
   all K, the many wrong hypotheses below dominate the fit and the best one's score came out
   under-confident (tune runs: calibration error 0.13–0.17 against 0.04 on the real logs).

The verifier works in the frame the hypotheses are in (the laser's pose, as the learned
localizers' outputs). Readings at or beyond range_max (no return) and below range_min do not
take part. The same object serves the learned localizer, the hypothesis tracker and the hybrid
(scanloc.localize.kinds: a localizer config's `verifier` section, used where its `learned`
section says `verified`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numba
import numpy as np
from scipy.ndimage import distance_transform_edt

from scanloc.localize.score_calibration import ScoreCalibration
from scanloc.sensor.laser import LaserSpec
from scanloc.world.occupancy_grid import OccupancyGrid

if TYPE_CHECKING:  # the model module imports torch, which verification does not need
    from scanloc.scanlocnet.model import Hypotheses

FEATURES = ("inlier_fraction", "mean_distance", "log_network_probability", "inlier_margin")


@dataclass(frozen=True)
class VerifierParams:
    """How hypotheses are refined and scored: the `verifier` section of a localizer config.

    iterations: Gauss-Newton steps per hypothesis; match_beams: evenly spaced beams used to
    refine (all valid beams score); max_distance: cap of the distance field (m), beyond which
    a beam pulls nothing; huber: the distance (m) beyond which a beam's weight falls as 1/d;
    inlier_distance: a beam end point this close to the map (m) counts as explained;
    max_step: the largest move per step (m; the rotation's is max_step / 2 rad);
    merge_distance / merge_angle_deg: refined hypotheses this close to a better one are merged.
    """

    iterations: int = 10
    match_beams: int = 120
    max_distance: float = 1.0
    huber: float = 0.1
    inlier_distance: float = 0.1
    max_step: float = 0.25
    merge_distance: float = 0.25
    merge_angle_deg: float = 5.0

    def __post_init__(self) -> None:
        if self.iterations < 0 or self.match_beams < 3:
            raise ValueError(f"need iterations >= 0 and match_beams >= 3, got {self}")
        if min(self.max_distance, self.huber, self.inlier_distance, self.max_step) <= 0:
            raise ValueError(f"distances must be > 0, got {self}")


@dataclass(frozen=True)
class DistanceField:
    """Signed distance (m) from each cell centre to the nearest obstacle surface, capped at
    ±cap: positive in free space, negative inside obstacles, zero on their boundary (half a
    cell from the boundary cells' centres), so that a beam's end point on a wall reads 0."""

    distance: np.ndarray  # (H, W) float64, row 0 the bottom row
    origin_x: float
    origin_y: float
    resolution: float
    cap: float

    @classmethod
    def of_map(cls, grid: OccupancyGrid, cap: float) -> DistanceField:
        occupied, half = grid.occupied, 0.5 * grid.resolution
        if occupied.any():
            outside = distance_transform_edt(~occupied) * grid.resolution - half
            inside = distance_transform_edt(occupied) * grid.resolution - half
            distance = np.clip(np.where(occupied, -inside, outside), -cap, cap)
        else:
            distance = np.full(occupied.shape, float(cap))
        origin_x, origin_y = float(grid.origin[0]), float(grid.origin[1])
        return cls(np.ascontiguousarray(distance), origin_x, origin_y, grid.resolution, cap)


@numba.njit(cache=True)
def _lookup(field: np.ndarray, ox: float, oy: float, res: float, cap: float, x: float, y: float):
    """Bilinear distance at (x, y) and its gradient; off the map: the cap, no gradient."""
    gx = (x - ox) / res - 0.5  # cell i's centre is at origin + (i + 0.5)·res
    gy = (y - oy) / res - 0.5
    col, row = math.floor(gx), math.floor(gy)
    height, width = field.shape
    if col < 0 or row < 0 or col + 1 >= width or row + 1 >= height:
        return cap, 0.0, 0.0
    fx, fy = gx - col, gy - row
    d00, d10 = field[row, col], field[row, col + 1]
    d01, d11 = field[row + 1, col], field[row + 1, col + 1]
    d = (1 - fy) * ((1 - fx) * d00 + fx * d10) + fy * ((1 - fx) * d01 + fx * d11)
    ddx = ((1 - fy) * (d10 - d00) + fy * (d11 - d01)) / res
    ddy = ((1 - fx) * (d01 - d00) + fx * (d11 - d10)) / res
    return d, ddx, ddy


@numba.njit(cache=True)
def _refine_and_score(
    poses: np.ndarray,
    match_x: np.ndarray,
    match_y: np.ndarray,
    score_x: np.ndarray,
    score_y: np.ndarray,
    field: np.ndarray,
    ox: float,
    oy: float,
    res: float,
    cap: float,
    iterations: int,
    huber: float,
    inlier: float,
    max_step: float,
    out_poses: np.ndarray,
    out_features: np.ndarray,
) -> None:
    for h in range(poses.shape[0]):
        x, y, t = poses[h, 0], poses[h, 1], poses[h, 2]
        for _ in range(iterations):
            c, s = math.cos(t), math.sin(t)
            hess = np.zeros((3, 3))
            grad = np.zeros(3)
            for j in range(match_x.shape[0]):
                rx = c * match_x[j] - s * match_y[j]
                ry = s * match_x[j] + c * match_y[j]
                d, ddx, ddy = _lookup(field, ox, oy, res, cap, x + rx, y + ry)
                if abs(d) >= cap:
                    continue
                w = 1.0 if abs(d) <= huber else huber / abs(d)
                jac = (ddx, ddy, -ry * ddx + rx * ddy)
                for a in range(3):
                    grad[a] += w * jac[a] * d
                    for b in range(3):
                        hess[a, b] += w * jac[a] * jac[b]
            trace = hess[0, 0] + hess[1, 1] + hess[2, 2]
            if trace <= 0.0:
                break
            for a in range(3):  # Levenberg damping keeps a flat direction from exploding
                hess[a, a] += 1e-3 * trace + 1e-9
            step = -np.linalg.solve(hess, grad)
            move = math.hypot(step[0], step[1])
            if move > max_step:
                step *= max_step / move
            if abs(step[2]) > 0.5 * max_step:
                step *= 0.5 * max_step / abs(step[2])
            x, y, t = x + step[0], y + step[1], t + step[2]
            if move < 1e-4 and abs(step[2]) < 1e-4:
                break
        out_poses[h, 0], out_poses[h, 1] = x, y
        out_poses[h, 2] = math.atan2(math.sin(t), math.cos(t))
        c, s = math.cos(t), math.sin(t)
        hits, total = 0, 0.0
        for j in range(score_x.shape[0]):
            rx = c * score_x[j] - s * score_y[j]
            ry = s * score_x[j] + c * score_y[j]
            d = abs(_lookup(field, ox, oy, res, cap, x + rx, y + ry)[0])
            total += d
            if d < inlier:
                hits += 1
        n = max(score_x.shape[0], 1)
        out_features[h, 0] = hits / n
        out_features[h, 1] = total / n / cap


class HypothesisVerifier:
    """Refines, scores, calibrates and re-ranks one scan's hypotheses (module docstring)."""

    def __init__(
        self,
        grid: OccupancyGrid,
        laser: LaserSpec,
        params: VerifierParams,
        calibration: ScoreCalibration | None = None,
    ) -> None:
        self.params, self.laser, self.calibration = params, laser, calibration
        self.field = DistanceField.of_map(grid, params.max_distance)
        self._angles = laser.beam_angles()

    def _end_points(self, scan: np.ndarray) -> tuple[np.ndarray, ...]:
        scan = np.asarray(scan, dtype=np.float64)
        valid = np.isfinite(scan) & (scan > self.laser.range_min) & (scan < self.laser.range_max)
        ranges, angles = scan[valid], self._angles[valid]
        x, y = ranges * np.cos(angles), ranges * np.sin(angles)
        if len(ranges) == 0:
            return x, y, x, y
        pick = np.unique(np.linspace(0, len(ranges) - 1, self.params.match_beams).astype(int))
        return x[pick], y[pick], x, y

    def features(self, scan: np.ndarray, poses: np.ndarray, probabilities: np.ndarray):
        """(refined poses (K, 3), features (K, 4) in FEATURES order) of one scan's hypotheses."""
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        match_x, match_y, score_x, score_y = self._end_points(scan)
        refined = np.empty_like(poses)
        features = np.empty((len(poses), len(FEATURES)))
        f = self.field
        _refine_and_score(
            poses,
            match_x,
            match_y,
            score_x,
            score_y,
            f.distance,
            f.origin_x,
            f.origin_y,
            f.resolution,
            f.cap,
            self.params.iterations,
            self.params.huber,
            self.params.inlier_distance,
            self.params.max_step,
            refined,
            features,
        )
        if len(score_x) == 0:  # a scan without one valid reading explains nothing
            features[:, 0], features[:, 1] = 0.0, 1.0
        features[:, 2] = np.log(np.maximum(np.asarray(probabilities, dtype=np.float64), 1e-12))
        features[:, 3] = inlier_margins(features[:, 0], refined, self.params)
        return refined, features

    def verify(self, scan: np.ndarray, hyp: Hypotheses) -> Hypotheses:
        """One scan's hypotheses (a Hypotheses of one row) refined, scored and re-ranked by the
        share of the scan they explain (inlier fraction); the result's `scores` are calibrated
        probabilities (the inlier fraction when the verifier has no calibration). Padding rows
        (weight 0) stay last with score 0."""
        if hyp.poses.shape[0] != 1:
            raise ValueError(f"verify takes one scan's hypotheses, got {hyp.poses.shape[0]}")
        poses, weights, stds = hyp.poses[0], hyp.weights[0], hyp.stds[0]
        real = weights > 0
        refined, features = self.features(scan, poses[real], weights[real])
        scores = (
            features[:, 0].copy()
            if self.calibration is None
            else self.calibration.probability(features)
        )
        keep = merge_duplicates(
            refined,
            features[:, 0],
            self.params.merge_distance,
            math.radians(self.params.merge_angle_deg),
        )
        k = poses.shape[0]
        out_poses, out_weights = np.zeros((1, k, 3)), np.zeros((1, k))
        out_stds, out_scores = np.zeros((1, k, 3)), np.zeros((1, k))
        n = len(keep)
        out_poses[0, :n], out_scores[0, :n] = refined[keep], scores[keep]
        out_weights[0, :n], out_stds[0, :n] = weights[real][keep], stds[real][keep]
        return replace(hyp, poses=out_poses, weights=out_weights, stds=out_stds, scores=out_scores)


def inlier_margins(inliers: np.ndarray, poses: np.ndarray, params: VerifierParams) -> np.ndarray:
    """Each hypothesis' inlier fraction minus the best among the scan's other hypotheses that
    refined to a different pose (beyond the merge distance or angle); its own inlier fraction
    when there is none (a margin over nothing)."""
    margins = np.empty(len(inliers))
    angle = math.radians(params.merge_angle_deg)
    for i in range(len(inliers)):
        distance = np.hypot(poses[:, 0] - poses[i, 0], poses[:, 1] - poses[i, 1])
        turn = np.abs(np.remainder(poses[:, 2] - poses[i, 2] + math.pi, math.tau) - math.pi)
        other = (distance > params.merge_distance) | (turn > angle)
        margins[i] = inliers[i] - inliers[other].max() if other.any() else inliers[i]
    return margins


def merge_duplicates(poses: np.ndarray, scores: np.ndarray, distance: float, angle: float):
    """Indices of the hypotheses kept, best score first: one within `distance` m and `angle`
    rad of a better-scored kept one is dropped (ties keep the network's order)."""
    order = np.argsort(-scores, kind="stable")
    kept: list[int] = []
    for i in order:
        close = False
        for j in kept:
            dpos = math.hypot(poses[i, 0] - poses[j, 0], poses[i, 1] - poses[j, 1])
            dang = abs(math.remainder(poses[i, 2] - poses[j, 2], math.tau))
            if dpos <= distance and dang <= angle:
                close = True
                break
        if not close:
            kept.append(int(i))
    return np.asarray(kept, dtype=np.int64)
