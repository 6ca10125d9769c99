"""Monte Carlo localization as ROS 1 amcl runs it (navigation, noetic: amcl_node.cpp and pf/*.c).

The filter, step by step, as in amcl's `laserReceived`:
1. The first scan after an initialisation only records the odometry pose and weights the
   particles (no motion update), and an estimate is published.
2. Later scans update the filter only once the odometry has moved more than `update_min_d` along
   the odometry frame's x OR y axis (each on its own, as amcl compares them) or turned more than
   `update_min_a`. An update applies the motion model (`motion_model.py`) from the odometry pose
   of the previous update, then the likelihood-field model (`likelihood_field.py`): weights are
   multiplied by the model's p, normalised, and the recovery averages w_slow / w_fast follow the
   mean weight (alphas `recovery_alpha_slow` / `_fast`).
3. Every `resample_interval`-th update resamples with KLD sampling (Fox 2003): particles are drawn
   one by one (with probability max(0, 1 - w_fast/w_slow) a random free pose instead), each into
   a 0.5 m × 0.5 m × 10° histogram bin, until the count exceeds the KLD bound of the number of
   occupied bins k, n = ⌈(k-1)/(2ε)·(1 - 2/(9(k-1)) + sqrt(2/(9(k-1)))·z)³⌉ clamped to
   [min_particles, max_particles] (k = 1 gives max_particles). amcl feeds `kld_z` (0.99) into
   the formula as the normal quantile z itself; that is kept.
4. After a resampling (and on the first scan) the particles are clustered: occupied bins that
   touch (26-neighbourhood) form a cluster; the estimate is the weighted mean of the heaviest
   cluster, heading as the circular mean.

Where scanloc departs from amcl (documented pitfalls):
- Heading bins wrap at ±π (amcl bins the unwrapped heading, so a cluster straddling ±π splits).
- The world→cell lookup is exact unless `map_half_cell_offset` asks for amcl's half-cell shift.
- The covariance reported is the heaviest cluster's, 3 × 3: x/y block and θθ = -2·ln(R̄) as
  amcl's cluster statistics, plus the x-θ and y-θ terms (θ deviations wrapped) that amcl leaves
  at 0. (amcl publishes the whole particle set's x/y/θθ covariance instead.)
- The bin histogram covers the map plus a 2 m margin; particles beyond it share the edge bins.

Between filter updates the estimate is the last published pose carried forward by odometry:
pose = estimate ⊕ (odom at the estimate)⁻¹ ⊕ odom now, which is what amcl's published map→odom
transform gives a user looking up the robot in the map frame.

Randomness comes from one numpy Generator (seeded), so a run is reproducible whatever the thread
count; the per-particle loops are numba-compiled.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numba
import numpy as np
import pandas as pd

from scanloc.localize.config_params import params_from_config
from scanloc.localize.estimates import estimate_table, wrap_angle
from scanloc.localize.likelihood_field import beam_weights, build_likelihood_field, select_beams
from scanloc.localize.motion_model import ODOM_MODELS, odometry_delta, sample_motion
from scanloc.sensor.laser import LaserSpec
from scanloc.world.occupancy_grid import OccupancyGrid

BIN_XY: float = 0.5  # metres, amcl's pf_kdtree cell size in x and y
BIN_THETA: float = math.radians(10.0)  # amcl's pf_kdtree cell size in heading
BIN_MARGIN: float = 2.0  # metres of histogram around the map
_CONFIG_META_KEYS = frozenset({"name", "kind", "mode", "seed"})


@dataclass(frozen=True)
class AmclParams:
    """amcl's parameters, named as in ROS 1 amcl, with ROS 1's defaults.

    Exception: the recovery alphas default to 0.001 / 0.1 (the values the ROS wiki recommends and
    the paper-spec §7 uses); ROS 1's code default is 0.0 for both, which disables recovery.
    `odom_alpha5` only matters for amcl's omni models, which scanloc does not implement; it is
    accepted so that configs can carry it. `laser_min_range` / `laser_max_range` <= 0 mean "use
    the scanner's". `map_half_cell_offset` and `selective_resampling` are scanloc / later-ROS
    switches (default off, as in ROS 1).
    """

    min_particles: int = 100
    max_particles: int = 5000
    kld_err: float = 0.01
    kld_z: float = 0.99
    update_min_d: float = 0.2
    update_min_a: float = math.pi / 6.0
    resample_interval: int = 2
    selective_resampling: bool = False
    recovery_alpha_slow: float = 0.001
    recovery_alpha_fast: float = 0.1
    initial_cov_xx: float = 0.5 * 0.5
    initial_cov_yy: float = 0.5 * 0.5
    initial_cov_aa: float = (math.pi / 12.0) * (math.pi / 12.0)
    laser_model_type: str = "likelihood_field"
    laser_min_range: float = -1.0
    laser_max_range: float = -1.0
    laser_max_beams: int = 30
    laser_z_hit: float = 0.95
    laser_z_rand: float = 0.05
    laser_sigma_hit: float = 0.2
    laser_likelihood_max_dist: float = 2.0
    odom_model_type: str = "diff"
    odom_alpha1: float = 0.2
    odom_alpha2: float = 0.2
    odom_alpha3: float = 0.2
    odom_alpha4: float = 0.2
    odom_alpha5: float = 0.2
    map_half_cell_offset: bool = False

    def __post_init__(self) -> None:
        if not 1 <= self.min_particles <= self.max_particles:
            raise ValueError(
                "need 1 <= min_particles <= max_particles, got "
                f"{self.min_particles}, {self.max_particles}"
            )
        if not (self.kld_err > 0 and self.kld_z > 0):
            raise ValueError(f"kld_err and kld_z must be > 0, got {self.kld_err}, {self.kld_z}")
        if self.resample_interval < 1:
            raise ValueError(f"resample_interval must be >= 1, got {self.resample_interval}")
        if self.update_min_d < 0 or self.update_min_a < 0:
            raise ValueError("update_min_d and update_min_a must be >= 0")
        if self.laser_model_type != "likelihood_field":
            raise ValueError(
                f"laser_model_type must be 'likelihood_field', got {self.laser_model_type!r}"
            )
        if self.odom_model_type not in ODOM_MODELS:
            raise ValueError(
                f"odom_model_type must be one of {ODOM_MODELS}, got {self.odom_model_type!r}"
            )
        if self.laser_max_beams < 2:
            raise ValueError(f"laser_max_beams must be >= 2, got {self.laser_max_beams}")
        if min(self.odom_alpha1, self.odom_alpha2, self.odom_alpha3, self.odom_alpha4) < 0:
            raise ValueError("odom_alpha1..4 must be >= 0")
        if not (0 <= self.recovery_alpha_slow <= 1 and 0 <= self.recovery_alpha_fast <= 1):
            raise ValueError("recovery_alpha_slow / _fast must lie in [0, 1]")
        if not (self.laser_sigma_hit > 0 and self.laser_likelihood_max_dist > 0):
            raise ValueError("laser_sigma_hit and laser_likelihood_max_dist must be > 0")

    @classmethod
    def from_config(cls, config: Mapping[str, object]) -> AmclParams:
        """Parameters from a localizer config (keys `name`, `kind`, `mode`, `seed` are skipped).

        Raises ValueError for an unknown key, naming it and listing the known ones.
        """
        return params_from_config(cls, config, "amcl", skip=_CONFIG_META_KEYS)


@dataclass(frozen=True)
class Estimate:
    """The filter's output for one scan.

    Attributes:
        mean: (x, y, θ) in the map frame; between filter updates the last estimate carried
            forward by odometry.
        cov: 3 × 3 covariance of the heaviest cluster at the last estimate.
        n_particles: current number of particles.
        updated: whether this scan triggered a filter update (motion + sensor model).
    """

    mean: np.ndarray
    cov: np.ndarray
    n_particles: int
    updated: bool


def kld_limit(k: int, min_particles: int, max_particles: int, kld_err: float, kld_z: float) -> int:
    """amcl's pf_resample_limit: particles needed for k occupied bins (KLD bound, clamped)."""
    return int(_kld_limit(k, min_particles, max_particles, kld_err, kld_z))


@numba.njit(cache=True)
def _kld_limit(k: int, min_n: int, max_n: int, err: float, z: float) -> int:
    if k < 1 or k > max_n or k == 1:
        return max_n
    b = 2.0 / (9.0 * (k - 1))
    x = 1.0 - b + math.sqrt(b) * z
    n = math.ceil((k - 1) / (2.0 * err) * x * x * x)
    return min(max(n, min_n), max_n)


@numba.njit(cache=True, inline="always")
def _bin_of(x: float, y: float, th: float, lo_x: int, lo_y: int, nx: int, ny: int, nt: int) -> int:
    kx = min(max(math.floor(x / BIN_XY) - lo_x, 0), nx - 1)
    ky = min(max(math.floor(y / BIN_XY) - lo_y, 0), ny - 1)
    kt = math.floor((th + math.pi) / BIN_THETA) % nt
    return (kx * ny + ky) * nt + kt


@numba.njit(cache=True)
def _resample_kld(
    poses: np.ndarray,
    weights: np.ndarray,
    u_pick: np.ndarray,
    u_inject: np.ndarray,
    w_diff: float,
    inject_u: np.ndarray,
    free_xy: np.ndarray,
    min_n: int,
    max_n: int,
    err: float,
    z: float,
    dims: np.ndarray,
    occupied: np.ndarray,
    out: np.ndarray,
) -> int:
    """amcl's pf_update_resample: draw until the KLD bound of the occupied bins is exceeded."""
    n = poses.shape[0]
    cum = np.empty(n + 1)
    cum[0] = 0.0
    for i in range(n):
        cum[i + 1] = cum[i] + weights[i]
    lo_x, lo_y, nx, ny, nt = dims[0], dims[1], dims[2], dims[3], dims[4]
    touched = np.empty(max_n, dtype=np.int64)
    k = 0
    limit = _kld_limit(0, min_n, max_n, err, z)
    count = 0
    while count < max_n:
        if u_inject[count] < w_diff:
            cell = min(int(inject_u[count, 0] * free_xy.shape[0]), free_xy.shape[0] - 1)
            out[count, 0] = free_xy[cell, 0]
            out[count, 1] = free_xy[cell, 1]
            out[count, 2] = inject_u[count, 1] * 2.0 * math.pi - math.pi
        else:
            j = np.searchsorted(cum, u_pick[count], side="right") - 1
            j = min(max(j, 0), n - 1)
            out[count, 0] = poses[j, 0]
            out[count, 1] = poses[j, 1]
            out[count, 2] = poses[j, 2]
        b = _bin_of(out[count, 0], out[count, 1], out[count, 2], lo_x, lo_y, nx, ny, nt)
        if occupied[b] == 0:
            occupied[b] = 1
            touched[k] = b
            k += 1
            limit = _kld_limit(k, min_n, max_n, err, z)
        count += 1
        if count > limit:
            break
    for i in range(k):
        occupied[touched[i]] = 0
    return count


@numba.njit(cache=True)
def _cluster_labels(poses: np.ndarray, dims: np.ndarray, labels_grid: np.ndarray) -> np.ndarray:
    """Label particles by connected occupied bins (26-neighbourhood, heading wraps at ±π).

    `labels_grid` is a work array of -1 over all bins; it is left as it was found.
    """
    lo_x, lo_y, nx, ny, nt = dims[0], dims[1], dims[2], dims[3], dims[4]
    n = poses.shape[0]
    bins = np.empty(n, dtype=np.int64)
    occupied = np.empty(n, dtype=np.int64)
    n_occ = 0
    for i in range(n):
        b = _bin_of(poses[i, 0], poses[i, 1], poses[i, 2], lo_x, lo_y, nx, ny, nt)
        bins[i] = b
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


@numba.njit(cache=True)
def _heaviest_cluster(
    poses: np.ndarray, weights: np.ndarray, labels: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean and 3 × 3 covariance of the heaviest cluster (amcl's pf_cluster_stats)."""
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
        sc += wi * math.cos(poses[i, 2])
        ss += wi * math.sin(poses[i, 2])
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
        dt = poses[i, 2] - mean[2]
        dt = math.atan2(math.sin(dt), math.cos(dt))
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
        dims = _bin_dims(
            float(poses[:, 0].min()),
            float(poses[:, 1].min()),
            float(poses[:, 0].max()),
            float(poses[:, 1].max()),
        )
    labels_grid = np.full(int(np.prod(dims[2:])), -1, dtype=np.int64)
    labels = _cluster_labels(poses, dims, labels_grid)
    mean, cov = _heaviest_cluster(poses, weights, labels)
    return mean, cov, labels


def _bin_dims(x_min: float, y_min: float, x_max: float, y_max: float) -> np.ndarray:
    """(lo_x, lo_y, nx, ny, n_theta) of a histogram with amcl's bins covering a box + margin."""
    lo_x = math.floor((x_min - BIN_MARGIN) / BIN_XY)
    lo_y = math.floor((y_min - BIN_MARGIN) / BIN_XY)
    nx = math.floor((x_max + BIN_MARGIN) / BIN_XY) - lo_x + 1
    ny = math.floor((y_max + BIN_MARGIN) / BIN_XY) - lo_y + 1
    nt = round(2.0 * math.pi / BIN_THETA)
    return np.array([lo_x, lo_y, nx, ny, nt], dtype=np.int64)


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ⊕ b: pose b (given in a's frame) expressed in a's parent frame; θ wrapped."""
    c, s = math.cos(a[2]), math.sin(a[2])
    theta = a[2] + b[2]
    return np.array(
        [
            a[0] + c * b[0] - s * b[1],
            a[1] + s * b[0] + c * b[1],
            float(wrap_angle(theta)),
        ]
    )


def inverse(a: np.ndarray) -> np.ndarray:
    """⊖a: the pose whose composition with a gives the identity."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]])


class Amcl:
    """amcl's particle filter on an occupancy grid with a planar laser at the robot centre."""

    def __init__(
        self,
        grid: OccupancyGrid,
        laser_spec: LaserSpec,
        params: AmclParams | None = None,
        seed: int = 0,
    ) -> None:
        self.grid = grid
        self.spec = laser_spec
        self.params = params or AmclParams()
        p = self.params
        self.rng = np.random.default_rng(seed)
        free_rows, free_cols = np.nonzero(grid.free)
        if free_rows.size == 0:
            raise ValueError("the map has no free cell: amcl needs free space to place particles")
        offset = 0.5 if p.map_half_cell_offset else 0.0
        self._free_xy = np.column_stack(
            [
                grid.origin[0] + (free_cols + 0.5 - offset) * grid.resolution,
                grid.origin[1] + (free_rows + 0.5 - offset) * grid.resolution,
            ]
        )
        self.range_min = (
            max(laser_spec.range_min, p.laser_min_range)
            if p.laser_min_range > 0
            else laser_spec.range_min
        )
        self.range_max = (
            min(laser_spec.range_max, p.laser_max_range)
            if p.laser_max_range > 0
            else laser_spec.range_max
        )
        self.field = build_likelihood_field(
            grid,
            z_hit=p.laser_z_hit,
            z_rand=p.laser_z_rand,
            sigma_hit=p.laser_sigma_hit,
            max_dist=p.laser_likelihood_max_dist,
            range_max=self.range_max,
            half_cell_offset=p.map_half_cell_offset,
        )
        self._angles = laser_spec.beam_angles()
        width_m, height_m = grid.size_m
        self._dims = _bin_dims(
            grid.origin[0], grid.origin[1], grid.origin[0] + width_m, grid.origin[1] + height_m
        )
        n_bins = int(np.prod(self._dims[2:]))
        self._bin_occupied = np.zeros(n_bins, dtype=np.uint8)
        self._bin_labels = np.full(n_bins, -1, dtype=np.int64)
        self.poses = np.empty((0, 3))
        self.weights = np.empty(0)
        self.w_slow = 0.0
        self.w_fast = 0.0
        self._initialised = False
        self._pf_init = False
        self._pf_odom_pose = np.zeros(3)
        self._resample_count = 0
        self._est_pose = np.zeros(3)
        self._est_cov = np.zeros((3, 3))
        self._est_odom = np.zeros(3)

    # -- initialisation ---------------------------------------------------------------------
    def initialize_pose(self, mean: np.ndarray, cov: np.ndarray | None = None) -> None:
        """Tracking: max_particles drawn from N(mean, cov) (default: the initial_cov_* params)."""
        mean = np.asarray(mean, dtype=np.float64)
        if mean.shape != (3,) or not np.all(np.isfinite(mean)):
            raise ValueError(f"initial pose must be 3 finite numbers (x, y, θ), got {mean}")
        if cov is None:
            p = self.params
            cov = np.diag([p.initial_cov_xx, p.initial_cov_yy, p.initial_cov_aa])
        cov = np.asarray(cov, dtype=np.float64)
        if (
            cov.shape != (3, 3)
            or not np.allclose(cov, cov.T)
            or np.linalg.eigvalsh(cov).min() < -1e-12
        ):
            raise ValueError(f"initial covariance must be a symmetric PSD 3 x 3 matrix, got {cov}")
        n = self.params.max_particles
        poses = self.rng.multivariate_normal(mean, cov, size=n, method="eigh")
        poses[:, 2] = wrap_angle(poses[:, 2])
        self._reset(poses)

    def initialize_global(self) -> None:
        """Global localization: max_particles at random free cells, headings uniform."""
        n = self.params.max_particles
        self._reset(self._random_free_poses(self.rng.random((n, 2))))

    def _random_free_poses(self, u: np.ndarray) -> np.ndarray:
        cells = np.minimum((u[:, 0] * len(self._free_xy)).astype(np.int64), len(self._free_xy) - 1)
        return np.column_stack([self._free_xy[cells], u[:, 1] * 2.0 * math.pi - math.pi])

    def _reset(self, poses: np.ndarray) -> None:
        self.poses = np.ascontiguousarray(poses, dtype=np.float64)
        self.weights = np.full(len(poses), 1.0 / len(poses))
        self.w_slow = self.w_fast = 0.0
        self._initialised = True
        self._pf_init = False

    # -- the filter -------------------------------------------------------------------------
    def update(self, odom_pose: np.ndarray, ranges: np.ndarray) -> Estimate:
        """Process one scan with the odometry pose at its time (amcl's laserReceived)."""
        if not self._initialised:
            raise RuntimeError("call initialize_pose() or initialize_global() before update()")
        odom_pose = np.asarray(odom_pose, dtype=np.float64)
        if odom_pose.shape != (3,) or not np.all(np.isfinite(odom_pose)):
            raise ValueError(f"odom_pose must be 3 finite numbers (x, y, θ), got {odom_pose}")
        ranges = np.asarray(ranges)
        if ranges.shape != (self.spec.num_beams,):
            raise ValueError(
                f"scan has shape {ranges.shape}, expected ({self.spec.num_beams},) ranges "
                "(LaserSpec.num_beams)"
            )
        if np.isnan(ranges).any():
            raise ValueError(
                "scan contains NaN ranges; expected metres, with 'no return' as a fill value"
            )
        p = self.params
        publish = False
        resampled = False
        if not self._pf_init:
            self._pf_odom_pose = odom_pose.copy()
            self._pf_init = True
            self._resample_count = 0
            do_update = publish = True
        else:
            delta = odometry_delta(self._pf_odom_pose, odom_pose)
            do_update = (
                abs(delta[0]) > p.update_min_d
                or abs(delta[1]) > p.update_min_d
                or abs(delta[2]) > p.update_min_a
            )
            if do_update:
                alphas = (p.odom_alpha1, p.odom_alpha2, p.odom_alpha3, p.odom_alpha4)
                sample_motion(
                    self.poses, self._pf_odom_pose, odom_pose, p.odom_model_type, alphas, self.rng
                )
        if do_update:
            self._sensor_update(ranges)
            self._pf_odom_pose = odom_pose.copy()
            self._resample_count += 1
            if self._resample_count % p.resample_interval == 0:
                self._resample()
                resampled = True
        if resampled or publish:
            labels = _cluster_labels(self.poses, self._dims, self._bin_labels)
            mean, cov = _heaviest_cluster(self.poses, self.weights, labels)
            self._est_pose, self._est_cov, self._est_odom = mean, cov, odom_pose.copy()
        carried = compose(self._est_pose, compose(inverse(self._est_odom), odom_pose))
        return Estimate(carried, self._est_cov.copy(), len(self.poses), bool(do_update))

    def _sensor_update(self, ranges: np.ndarray) -> None:
        """amcl's pf_update_sensor with the likelihood-field model."""
        r, b = select_beams(
            ranges, self._angles, self.range_min, self.range_max, self.params.laser_max_beams
        )
        self.weights = self.weights * beam_weights(self.field, self.poses, r, b)
        total = float(self.weights.sum())
        n = len(self.weights)
        if total > 0.0:
            w_avg = total / n
            self.weights /= total
            p = self.params
            self.w_slow = (
                w_avg
                if self.w_slow == 0.0
                else self.w_slow + p.recovery_alpha_slow * (w_avg - self.w_slow)
            )
            self.w_fast = (
                w_avg
                if self.w_fast == 0.0
                else self.w_fast + p.recovery_alpha_fast * (w_avg - self.w_fast)
            )
        else:
            self.weights = np.full(n, 1.0 / n)

    def _resample(self) -> None:
        """amcl's pf_update_resample (KLD sampling with random-pose recovery)."""
        p = self.params
        n_eff = 1.0 / float(np.sum(self.weights**2))
        if p.selective_resampling and n_eff > 0.5 * len(self.weights):
            return
        w_diff = 1.0 - self.w_fast / self.w_slow if self.w_slow > 0.0 else 0.0
        w_diff = max(w_diff, 0.0)
        m = p.max_particles
        u_inject = self.rng.random(m)
        u_pick = self.rng.random(m)
        inject_u = self.rng.random((m, 2)) if w_diff > 0.0 else np.zeros((m, 2))
        out = np.empty((m, 3))
        count = _resample_kld(
            self.poses,
            self.weights,
            u_pick,
            u_inject,
            w_diff,
            inject_u,
            self._free_xy,
            p.min_particles,
            m,
            p.kld_err,
            p.kld_z,
            self._dims,
            self._bin_occupied,
            out,
        )
        if w_diff > 0.0:  # amcl resets the averages to avoid spiralling into randomness
            self.w_slow = self.w_fast = 0.0
        self.poses = np.ascontiguousarray(out[:count])
        self.weights = np.full(count, 1.0 / count)


def run_amcl(
    grid: OccupancyGrid,
    spec: LaserSpec,
    trajectory: object,
    ranges: np.ndarray,
    params: AmclParams | None = None,
    mode: str = "tracking",
    seed: int = 0,
) -> pd.DataFrame:
    """Run amcl over a driven trajectory; one row per scan in the shared per-step table format.

    `trajectory` needs `times`, `truth` and `odometry` arrays (see trajectory.Trajectory).
    Tracking starts from the true first pose with the initial_cov_* covariance; global mode
    from particles uniform over the free space. amcl updates its filter only after
    update_min_d / update_min_a of motion and re-estimates only when it resamples; the rows in
    between hold the last estimate carried forward by odometry (what amcl's map→odom transform
    gives), with that estimate's covariance.
    """
    if mode not in ("tracking", "global"):
        raise ValueError(f"mode must be 'tracking' or 'global', got {mode!r}")
    times = np.asarray(trajectory.times)  # type: ignore[attr-defined]
    truth = np.asarray(trajectory.truth)  # type: ignore[attr-defined]
    odometry = np.asarray(trajectory.odometry)  # type: ignore[attr-defined]
    ranges = np.asarray(ranges)
    if ranges.ndim != 2 or ranges.shape[0] != len(odometry):
        raise ValueError(
            f"ranges must have shape (T, B) with T = {len(odometry)} trajectory steps, "
            f"got {ranges.shape}"
        )
    amcl = Amcl(grid, spec, params, seed=seed)
    if mode == "tracking":
        amcl.initialize_pose(truth[0])
    else:
        amcl.initialize_global()
    estimates = [amcl.update(odometry[step], ranges[step]) for step in range(len(odometry))]
    return estimate_table(
        np.arange(len(odometry)),
        times,
        np.array([est.mean for est in estimates]),
        np.array([est.cov for est in estimates]),
        np.array([est.n_particles for est in estimates]),
    )
