"""amcl's estimator: the particles' clusters and the weighted mean of the heaviest one.

Particles are binned into amcl's pf_kdtree cells, 0.5 m × 0.5 m × 10° (`BIN_XY`, `BIN_THETA`);
occupied bins that touch (26-neighbourhood) form a cluster (amcl's pf_cluster_stats). The
estimate is the heaviest cluster's weighted mean, heading as the circular mean, and its 3 × 3
covariance: the x/y block and θθ = -2·ln(R̄) as amcl computes them, plus the x-θ and y-θ terms
(θ deviations wrapped) that amcl leaves at 0.

Where scanloc departs from amcl: heading bins wrap at ±π (amcl bins the unwrapped heading, so a
cluster straddling ±π splits in two), and the bin histogram covers the map plus a 2 m margin
(particles beyond it share the edge bins). The same bins serve KLD sampling
(`kld_resampling.py`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from scanloc.pose import wrap_pi

BIN_XY: float = 0.5  # metres, amcl's pf_kdtree cell size in x and y
BIN_THETA: float = math.radians(10.0)  # amcl's pf_kdtree cell size in heading
BIN_MARGIN: float = 2.0  # metres of histogram around the map


def bin_dims(x_min: float, y_min: float, x_max: float, y_max: float) -> np.ndarray:
    """(lo_x, lo_y, nx, ny, n_theta) of a histogram with amcl's bins covering a box + margin."""
    lo_x = math.floor((x_min - BIN_MARGIN) / BIN_XY)
    lo_y = math.floor((y_min - BIN_MARGIN) / BIN_XY)
    nx = math.floor((x_max + BIN_MARGIN) / BIN_XY) - lo_x + 1
    ny = math.floor((y_max + BIN_MARGIN) / BIN_XY) - lo_y + 1
    nt = round(2.0 * math.pi / BIN_THETA)
    return np.array([lo_x, lo_y, nx, ny, nt], dtype=np.int64)


@numba.njit(cache=True, inline="always")
def bin_of(x: float, y: float, th: float, lo_x: int, lo_y: int, nx: int, ny: int, nt: int) -> int:
    kx = min(max(math.floor(x / BIN_XY) - lo_x, 0), nx - 1)
    ky = min(max(math.floor(y / BIN_XY) - lo_y, 0), ny - 1)
    kt = math.floor((th + math.pi) / BIN_THETA) % nt
    return (kx * ny + ky) * nt + kt


@numba.njit(cache=True, parallel=True)
def particle_bins(poses: np.ndarray, dims: np.ndarray) -> np.ndarray:
    """Each particle's bin index in the histogram `dims` describes."""
    lo_x, lo_y, nx, ny, nt = dims[0], dims[1], dims[2], dims[3], dims[4]
    bins = np.empty(poses.shape[0], dtype=np.int64)
    for i in numba.prange(poses.shape[0]):
        bins[i] = bin_of(poses[i, 0], poses[i, 1], poses[i, 2], lo_x, lo_y, nx, ny, nt)
    return bins


@numba.njit(cache=True)
def cluster_labels(poses: np.ndarray, dims: np.ndarray, labels_grid: np.ndarray) -> np.ndarray:
    """Label particles by connected occupied bins (26-neighbourhood, heading wraps at ±π).

    `labels_grid` is a work array of -1 over all bins; it is left as it was found.
    """
    nx, ny, nt = dims[2], dims[3], dims[4]
    n = poses.shape[0]
    bins = particle_bins(poses, dims)
    occupied = np.empty(n, dtype=np.int64)
    n_occ = 0
    for i in range(n):
        b = bins[i]
        if labels_grid[b] == -1:
            labels_grid[b] = -2
            occupied[n_occ] = b
            n_occ += 1
    stack = np.empty(n_occ, dtype=np.int64)
    n_clusters = 0
    for s in range(n_occ):
        if labels_grid[occupied[s]] != -2:
            continue
        labels_grid[occupied[s]] = n_clusters
        top = 0
        stack[top] = occupied[s]
        top += 1
        while top > 0:
            top -= 1
            b = stack[top]
            kt = b % nt
            ky = (b // nt) % ny
            kx = b // (nt * ny)
            for dx in range(-1, 2):
                jx = kx + dx
                if jx < 0 or jx >= nx:
                    continue
                for dy in range(-1, 2):
                    jy = ky + dy
                    if jy < 0 or jy >= ny:
                        continue
                    for dt in range(-1, 2):
                        jt = (kt + dt) % nt
                        nb = (jx * ny + jy) * nt + jt
                        if labels_grid[nb] == -2:
                            labels_grid[nb] = n_clusters
                            stack[top] = nb
                            top += 1
        n_clusters += 1
    labels = np.empty(n, dtype=np.int64)
    for i in range(n):
        labels[i] = labels_grid[bins[i]]
    for s in range(n_occ):
        labels_grid[occupied[s]] = -1
    return labels


@numba.njit(cache=True, parallel=True)
def _headings(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos θ and sin θ of every particle (element by element: the same on any thread count)."""
    cos = np.empty(poses.shape[0])
    sin = np.empty(poses.shape[0])
    for i in numba.prange(poses.shape[0]):
        cos[i] = math.cos(poses[i, 2])
        sin[i] = math.sin(poses[i, 2])
    return cos, sin


@numba.njit(cache=True)
def heaviest_cluster(
    poses: np.ndarray, weights: np.ndarray, labels: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean and 3 × 3 covariance of the heaviest cluster (amcl's pf_cluster_stats).

    The sums run in particle order on one thread, so the estimate does not depend on the
    thread count."""
    cos, sin = _headings(poses)
    n_clusters = labels.max() + 1
    cw = np.zeros(n_clusters)
    for i in range(poses.shape[0]):
        cw[labels[i]] += weights[i]
    best = 0
    for c in range(1, n_clusters):
        if cw[c] > cw[best]:  # the first of equal weights wins, as in amcl
            best = c
    w = 0.0
    sx = 0.0
    sy = 0.0
    sc = 0.0
    ss = 0.0
    sxx = 0.0
    sxy = 0.0
    syy = 0.0
    for i in range(poses.shape[0]):
        if labels[i] != best:
            continue
        wi = weights[i]
        w += wi
        sx += wi * poses[i, 0]
        sy += wi * poses[i, 1]
        sc += wi * cos[i]
        ss += wi * sin[i]
        sxx += wi * poses[i, 0] * poses[i, 0]
        sxy += wi * poses[i, 0] * poses[i, 1]
        syy += wi * poses[i, 1] * poses[i, 1]
    mean = np.empty(3)
    cov = np.zeros((3, 3))
    if w <= 0.0:
        mean[:] = np.nan
        return mean, cov
    mean[0] = sx / w
    mean[1] = sy / w
    mean[2] = math.atan2(ss, sc)
    cov[0, 0] = sxx / w - mean[0] * mean[0]
    cov[0, 1] = sxy / w - mean[0] * mean[1]
    cov[1, 1] = syy / w - mean[1] * mean[1]
    resultant = min(math.sqrt(sc * sc + ss * ss) / w, 1.0)
    cov[2, 2] = -2.0 * math.log(resultant) if resultant > 0.0 else math.inf
    sxt = 0.0
    syt = 0.0
    for i in range(poses.shape[0]):
        if labels[i] != best:
            continue
        dt = wrap_pi(poses[i, 2] - mean[2])
        sxt += weights[i] * (poses[i, 0] - mean[0]) * dt
        syt += weights[i] * (poses[i, 1] - mean[1]) * dt
    cov[0, 2] = sxt / w
    cov[1, 2] = syt / w
    cov[1, 0] = cov[0, 1]
    cov[2, 0] = cov[0, 2]
    cov[2, 1] = cov[1, 2]
    return mean, cov


def cluster_estimate(
    poses: np.ndarray, weights: np.ndarray, dims: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, cov, labels) of the heaviest cluster of a weighted particle set.

    `dims` = (lo_x, lo_y, nx, ny, n_theta) of the bin histogram; by default it spans the
    particles.
    """
    poses = np.ascontiguousarray(poses, dtype=np.float64)
    weights = np.ascontiguousarray(weights, dtype=np.float64)
    if dims is None:
        dims = bin_dims(
            float(poses[:, 0].min()),
            float(poses[:, 1].min()),
            float(poses[:, 0].max()),
            float(poses[:, 1].max()),
        )
    labels_grid = np.full(int(np.prod(dims[2:])), -1, dtype=np.int64)
    labels = cluster_labels(poses, dims, labels_grid)
    mean, cov = heaviest_cluster(poses, weights, labels)
    return mean, cov, labels
