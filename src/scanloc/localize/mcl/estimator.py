"""Estimators as parts, chosen by the `filter` section's `estimator`: amcl's
`heaviest_cluster`, the heaviest cluster's weighted mean and covariance (kernels in
localize/clustering.py) over amcl's 0.5 m × 0.5 m × 10° bins of the map plus a margin; and
`weighted_mean`, the mean of all particles (right when the cloud is one mode, wrong between
modes, where amcl's answer is the heaviest one)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import numpy as np

from scanloc.localize.clustering import bin_dims, cluster_labels, heaviest_cluster
from scanloc.pose import wrap_angle
from scanloc.world.occupancy_grid import OccupancyGrid


def map_bins(grid: OccupancyGrid) -> np.ndarray:
    """The bin histogram (lo_x, lo_y, nx, ny, n_theta) over `grid` that the estimator and the
    KLD resampler share."""
    width_m, height_m = grid.size_m
    return bin_dims(
        grid.origin[0], grid.origin[1], grid.origin[0] + width_m, grid.origin[1] + height_m
    )


class Estimator(Protocol):
    """A pose estimate (mean (3,), covariance (3, 3)) of a weighted particle set."""

    def estimate(self, poses: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


class ClusterEstimator:
    """amcl's pf_cluster_stats: the heaviest cluster of touching occupied bins."""

    def __init__(self, dims: np.ndarray) -> None:
        self.dims = dims
        self._bin_labels = np.full(int(np.prod(dims[2:])), -1, dtype=np.int64)

    def estimate(self, poses: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        labels = cluster_labels(poses, self.dims, self._bin_labels)
        return heaviest_cluster(poses, weights, labels)


class WeightedMeanEstimator:
    """The weighted mean of every particle (the heading's circular mean) and their weighted
    covariance (heading differences wrapped)."""

    def estimate(self, poses: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = weights / weights.sum()
        heading = math.atan2(float(w @ np.sin(poses[:, 2])), float(w @ np.cos(poses[:, 2])))
        mean = np.array([float(w @ poses[:, 0]), float(w @ poses[:, 1]), heading])
        diff = poses - mean
        diff[:, 2] = wrap_angle(diff[:, 2])
        return mean, (diff * w[:, None]).T @ diff


# name -> estimator over the bins (lo_x, lo_y, nx, ny, n_theta) of map_bins
ESTIMATORS: dict[str, Callable[[np.ndarray], Estimator]] = {
    "heaviest_cluster": ClusterEstimator,
    "weighted_mean": lambda dims: WeightedMeanEstimator(),
}
