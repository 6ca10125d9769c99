"""Monte Carlo localization as ROS 1 amcl runs it (navigation, noetic: amcl_node.cpp and pf/*.c).

The filter is assembled from parts, each in its own module:
- motion model: `motion_model.py` (amcl's `diff` / `diff-corrected` odometry models);
- sensor model: `sensor_models.py` (`likelihood_field`, `likelihood_field_prob`, `beam`);
- proposal: `proposals.py` (where global initialisation and recovery put new particles);
- resampler: `kld_resampling.py` (KLD sampling with random-pose injection);
- estimator: `clustering.py` (the heaviest cluster's weighted mean and covariance).

The filter, step by step, as in amcl's `laserReceived`:
1. The first scan after an initialisation only records the odometry pose and weights the
   particles (no motion update), and publishes the cluster estimate that the initialisation
   computed (amcl's pf_init / pf_init_model: uniform weights, before this sensor update).
2. Later scans update the filter only once the odometry has moved more than `update_min_d`
   along the odometry frame's x OR y axis (each on its own, as amcl compares them) or turned
   more than `update_min_a`. An update applies the motion model from the odometry pose of the
   previous update, then the sensor model: weights are multiplied by the model's factors,
   normalised, and the recovery averages w_slow / w_fast follow the mean weight (alphas
   `recovery_alpha_slow` / `_fast`; amcl_node.cpp's defaults 0.001 / 0.1 are what ROS 1 runs,
   as its dynamic-reconfigure callback ignores the .cfg defaults of 0.0 on the first call).
3. Every `resample_interval`-th update resamples (KLD sampling; with probability
   max(0, 1 - w_fast/w_slow) a draw is a pose from the proposal instead), then clusters the
   particles: the estimate is the heaviest cluster's weighted mean. Estimates are published
   only then (and on the first scan), as amcl does; `publish_every_update` (a scanloc switch)
   also publishes after updates that do not resample.

Readings that are NaN are skipped by every sensor model (as amcl's likelihood field does); a
scan of the wrong length is an error. `map_half_cell_offset` reproduces amcl's half-cell
world→cell shift (conf/localizer/amcl_ros_exact.yaml); scanloc's default is the exact mapping.

Between filter updates the estimate is the last published pose carried forward by odometry:
pose = estimate ⊕ (odom at the estimate)⁻¹ ⊕ odom now, which is what amcl's published map→odom
transform gives a user looking up the robot in the map frame.

Randomness comes from one numpy Generator (seeded), so a run is reproducible whatever the thread
count; the per-particle loops are numba-compiled.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from scanloc.estimates import Localization, estimate_table
from scanloc.localize.catalog import META_KEYS
from scanloc.localize.clustering import bin_dims, cluster_labels, heaviest_cluster
from scanloc.localize.config_params import params_from_config
from scanloc.localize.kld_resampling import resample_kld
from scanloc.localize.likelihood_field_prob import converged
from scanloc.localize.motion_model import ODOM_MODELS, odometry_delta, sample_motion
from scanloc.localize.proposals import Proposal, UniformProposal
from scanloc.localize.sensor_models import SENSOR_MODELS, LaserGeometry, build_sensor_model
from scanloc.pose import compose, inverse, wrap_angle
from scanloc.sensor.laser import LaserSpec
from scanloc.world.occupancy_grid import OccupancyGrid

_CONFIG_META_KEYS = frozenset(META_KEYS)


@dataclass(frozen=True)
class AmclParams:
    """amcl's parameters, named as in ROS 1 amcl, with ROS 1's defaults (amcl_node.cpp).

    `odom_alpha5` only matters for amcl's omni models, which scanloc does not implement; it is
    accepted so that configs can carry it. `laser_min_range` / `laser_max_range` <= 0 mean "use
    the scanner's". scanloc's own switches (ROS has none of them): `map_half_cell_offset`
    (true: amcl's half-cell world→cell shift), `publish_every_update` and the beam model's
    range table `beam_lut_resolution` (m) / `beam_lut_angles` (see beam_model.py).
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
    laser_z_short: float = 0.1
    laser_z_max: float = 0.05
    laser_z_rand: float = 0.05
    laser_sigma_hit: float = 0.2
    laser_lambda_short: float = 0.1
    laser_likelihood_max_dist: float = 2.0
    do_beamskip: bool = False
    beam_skip_distance: float = 0.5
    beam_skip_threshold: float = 0.3
    beam_skip_error_threshold: float = 0.9
    odom_model_type: str = "diff"
    odom_alpha1: float = 0.2
    odom_alpha2: float = 0.2
    odom_alpha3: float = 0.2
    odom_alpha4: float = 0.2
    odom_alpha5: float = 0.2
    map_half_cell_offset: bool = False
    publish_every_update: bool = False
    beam_lut_resolution: float = 0.05
    beam_lut_angles: int = 360

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
        if self.laser_model_type not in SENSOR_MODELS:
            raise ValueError(
                f"laser_model_type must be one of {sorted(SENSOR_MODELS)}, "
                f"got {self.laser_model_type!r}"
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
        weights = (self.laser_z_hit, self.laser_z_short, self.laser_z_max, self.laser_z_rand)
        if min(weights) < 0 or self.laser_lambda_short <= 0:
            raise ValueError("laser_z_* must be >= 0 and laser_lambda_short > 0")
        if not (0 <= self.beam_skip_threshold <= 1 and 0 <= self.beam_skip_error_threshold <= 1):
            raise ValueError("beam_skip_threshold and beam_skip_error_threshold must lie in [0, 1]")

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


class Amcl:
    """amcl's particle filter on an occupancy grid with a planar laser at the robot centre.

    `proposal` is where global initialisation and recovery draw new particles; by default
    amcl's uniform free-space proposal.
    """

    def __init__(
        self,
        grid: OccupancyGrid,
        laser_spec: LaserSpec,
        params: AmclParams | None = None,
        seed: int = 0,
        proposal: Proposal | None = None,
    ) -> None:
        self.grid = grid
        self.spec = laser_spec
        self.params = params or AmclParams()
        p = self.params
        self.rng = np.random.default_rng(seed)
        self.proposal = proposal or UniformProposal(grid, p.map_half_cell_offset)
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
        laser = LaserGeometry(
            laser_spec.beam_angles(), self.range_min, self.range_max, p.laser_max_beams
        )
        self.sensor_model = build_sensor_model(grid, laser, p)
        width_m, height_m = grid.size_m
        self._dims = bin_dims(
            grid.origin[0], grid.origin[1], grid.origin[0] + width_m, grid.origin[1] + height_m
        )
        n_bins = int(np.prod(self._dims[2:]))
        self._bin_occupied = np.zeros(n_bins, dtype=np.uint8)
        self._bin_labels = np.full(n_bins, -1, dtype=np.int64)
        self.poses = np.empty((0, 3))
        self.weights = np.empty(0)
        self.w_slow = 0.0
        self.w_fast = 0.0
        self.converged = False
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
        self.reset(poses, np.full(n, 1.0 / n))

    def initialize_global(self) -> None:
        """Global localization: max_particles drawn from the proposal (amcl: uniform over the
        free space), weighted by prior / proposal density (1 for the uniform proposal)."""
        n = self.params.max_particles
        poses = self.proposal.sample(n, self.rng)
        self.reset(poses, np.full(n, 1.0 / n))

    def reset(self, poses: np.ndarray, weights: np.ndarray) -> None:
        """A new particle set (weights normalised here); the next scan starts the filter.

        As amcl's pf_init, the cluster estimate is computed now, from these weights.
        """
        self.poses = np.ascontiguousarray(poses, dtype=np.float64)
        weights = np.asarray(weights, dtype=np.float64)
        self.weights = weights / weights.sum()
        self.w_slow = self.w_fast = 0.0
        self.converged = False
        self._initialised = True
        self._pf_init = False
        self._est_pose, self._est_cov = self._cluster_estimate()

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
        p = self.params
        first = not self._pf_init
        resampled = False
        if first:
            self._pf_odom_pose = odom_pose.copy()
            self._pf_init = True
            self._resample_count = 0
            do_update = True
            self._est_odom = odom_pose.copy()  # the initialisation's estimate, published now
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
            self.sensor_update(ranges)
            self._pf_odom_pose = odom_pose.copy()
            self._resample_count += 1
            if self._resample_count % p.resample_interval == 0:
                self.resample()
                resampled = True
        if resampled or (do_update and p.publish_every_update):
            self._est_pose, self._est_cov = self._cluster_estimate()
            self._est_odom = odom_pose.copy()
        carried = compose(self._est_pose, compose(inverse(self._est_odom), odom_pose))
        return Estimate(carried, self._est_cov.copy(), len(self.poses), bool(do_update))

    def sensor_update(self, ranges: np.ndarray) -> None:
        """amcl's pf_update_sensor: weights times the sensor model's factors, normalised; the
        recovery averages follow the mean unnormalised weight."""
        factors = self.sensor_model(self.poses, ranges, self.converged)
        self.weights = self.weights * factors
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

    def resample(self) -> None:
        """amcl's pf_update_resample: KLD sampling with injection from the proposal."""
        p = self.params
        n_eff = 1.0 / float(np.sum(self.weights**2))
        if p.selective_resampling and n_eff > 0.5 * len(self.weights):
            return
        w_diff = 1.0 - self.w_fast / self.w_slow if self.w_slow > 0.0 else 0.0
        w_diff = max(w_diff, 0.0)
        m = p.max_particles
        u_inject = self.rng.random(m)
        u_pick = self.rng.random(m)
        if w_diff > 0.0:
            inject_poses, inject_weights = self.injection(m)
        else:
            inject_poses, inject_weights = np.zeros((m, 3)), np.zeros(m)
        out, out_weights = np.empty((m, 3)), np.empty(m)
        count = resample_kld(
            self.poses,
            self.weights,
            u_pick,
            u_inject,
            w_diff,
            inject_poses,
            inject_weights,
            p.min_particles,
            m,
            p.kld_err,
            p.kld_z,
            self._dims,
            self._bin_occupied,
            out,
            out_weights,
        )
        if w_diff > 0.0:  # amcl resets the averages to avoid spiralling into randomness
            self.w_slow = self.w_fast = 0.0
        self.poses = np.ascontiguousarray(out[:count])
        self.weights = out_weights[:count] / out_weights[:count].sum()
        self.converged = converged(self.poses)

    def injection(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """m poses from the proposal for recovery, and their weights (1: amcl's uniform poses,
        which sample the prior directly)."""
        return self.proposal.sample(m, self.rng), np.ones(m)

    def warm_up(self, ranges: np.ndarray) -> None:
        """Run every compiled kernel once on a copy (numba loads or compiles on the first call),
        so that timed updates measure the filter, not the compiler. The state is unchanged."""
        rng_state = self.rng.bit_generator.state
        poses = self.poses[:4].copy() if len(self.poses) >= 4 else np.zeros((4, 3))
        self.sensor_model(poses, np.asarray(ranges), False)
        sample_motion(poses, np.zeros(3), np.array([1.0, 0.0, 0.1]), "diff", (0.1,) * 4, self.rng)
        saved = (self.poses, self.weights, self.w_slow, self.w_fast, self.converged)
        self.poses, self.weights = poses, np.full(4, 0.25)
        self.resample()
        self._cluster_estimate()
        self.poses, self.weights, self.w_slow, self.w_fast, self.converged = saved
        self.rng.bit_generator.state = rng_state

    def _cluster_estimate(self) -> tuple[np.ndarray, np.ndarray]:
        labels = cluster_labels(self.poses, self._dims, self._bin_labels)
        return heaviest_cluster(self.poses, self.weights, labels)


def run_amcl(
    grid: OccupancyGrid,
    spec: LaserSpec,
    trajectory: object,
    ranges: np.ndarray,
    params: AmclParams | None = None,
    mode: str = "tracking",
    seed: int = 0,
) -> Localization:
    """Run amcl over a driven trajectory: the per-step table and what each scan cost.

    Tracking starts from the true first pose with the initial_cov_* covariance; global mode
    from particles uniform over the free space. amcl updates its filter only after
    update_min_d / update_min_a of motion and re-estimates only when it resamples; the rows in
    between hold the last estimate carried forward by odometry (what amcl's map→odom transform
    gives), with that estimate's covariance.
    """
    start = time.perf_counter()
    amcl = Amcl(grid, spec, params, seed=seed)
    return run_filter(amcl, trajectory, ranges, mode, time.perf_counter() - start)


def run_filter(
    amcl: Amcl, trajectory: object, ranges: np.ndarray, mode: str, setup_s: float = 0.0
) -> Localization:
    """Run a built filter over a trajectory (`times`, `truth`, `odometry` arrays, see
    trajectory.Trajectory): tracking from the true first pose, or global. Setup (building the
    filter, `setup_s`, and the kernels' first call) is timed apart from the per-scan updates."""
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
    start = time.perf_counter()
    if mode == "tracking":
        amcl.initialize_pose(truth[0])
    else:
        amcl.initialize_global()
    amcl.warm_up(ranges[0])
    setup_s += time.perf_counter() - start
    estimates, seconds = [], np.empty(len(odometry))
    for step in range(len(odometry)):
        tick = time.perf_counter()
        estimates.append(amcl.update(odometry[step], ranges[step]))
        seconds[step] = time.perf_counter() - tick
    table = estimate_table(
        np.arange(len(odometry)),
        times,
        np.array([est.mean for est in estimates]),
        np.array([est.cov for est in estimates]),
        np.array([est.n_particles for est in estimates]),
    )
    return Localization(table, setup_s, seconds)
