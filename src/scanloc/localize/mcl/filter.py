"""The particle filter: Monte Carlo localization as ROS 1 amcl runs it (amcl_node.cpp's
laserReceived, pf/*.c), assembled from parts, each behind a small Protocol:
motion model (motion.py), sensor model (sensor_models.py), proposal and its weighting
(proposals.py), mixing (mixing.py), resampler (resampler.py), estimator (estimator.py) and
update trigger (trigger.py). `config.py` builds them from a localizer config's sections.

The filter, step by step:
1. The first scan after an initialisation only records the odometry pose and weights the
   particles (no motion update), and publishes the estimate that the initialisation computed
   (amcl's pf_init / pf_init_model: uniform weights, before this sensor update).
2. Later scans update the filter once the trigger says the odometry moved enough. An update
   applies the motion model from the odometry pose of the previous update, draws the mixing's
   share of particles from the proposal (weighted by the weighting), then the sensor model:
   weights are multiplied by the model's factors, normalised, and the recovery averages
   w_slow / w_fast follow the mean weight
   (alphas `recovery_alpha_slow` / `_fast`; amcl_node.cpp's defaults 0.001 / 0.1 are what
   ROS 1 runs, as its dynamic-reconfigure callback ignores the .cfg defaults of 0.0).
3. When the trigger says so, the filter resamples (with probability max(0, 1 - w_fast/w_slow)
   a draw is a pose from the proposal instead) and estimates; estimates are published only
   then (and on the first scan), or after every update (`publish_every_update`).

Between updates the estimate is the last published pose carried forward by odometry:
pose = estimate ⊕ (odom at the estimate)⁻¹ ⊕ odom now, which is what amcl's published map→odom
transform gives. Randomness comes from one numpy Generator (seeded), so a run is reproducible
whatever the thread count.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from scanloc.estimates import Localization, estimate_table
from scanloc.localize.likelihood_field_prob import converged
from scanloc.localize.mcl.averages import LikelihoodAverages
from scanloc.localize.mcl.estimator import ESTIMATORS, Estimator
from scanloc.localize.mcl.mixing import Mixing, NoMixing
from scanloc.localize.mcl.motion import MotionModel
from scanloc.localize.mcl.proposals import PriorWeights, Proposal, Weighting
from scanloc.localize.mcl.resampler import RESAMPLERS, Resampler, SelectiveResampling
from scanloc.localize.mcl.sensor_models import SensorModel
from scanloc.localize.mcl.trigger import UPDATE_TRIGGERS, Schedule, UpdateTrigger
from scanloc.pose import compose, inverse, wrap_angle

MODES = ("tracking", "global")


@dataclass(frozen=True)
class FilterParams:
    """The `filter` section: ROS 1 amcl's names and defaults (amcl_node.cpp), how the filter
    starts (`mode`: `tracking` from a pose, `global` without one) and its random `seed`, and
    which policies it runs: `update_trigger` (trigger.py), `resampler` (resampler.py; with
    `selective_resampling` around it) and `estimator` (estimator.py)."""

    mode: str = "tracking"
    seed: int = 0
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
    publish_every_update: bool = False
    update_trigger: str = "on_motion"
    resampler: str = "kld"
    estimator: str = "heaviest_cluster"

    def __post_init__(self) -> None:
        for key, choices in (
            ("mode", MODES),
            ("update_trigger", UPDATE_TRIGGERS),
            ("resampler", RESAMPLERS),
            ("estimator", ESTIMATORS),
        ):
            if getattr(self, key) not in choices:
                raise ValueError(
                    f"{key} must be one of {sorted(choices)}, got {getattr(self, key)!r}"
                )
        if not 1 <= self.min_particles <= self.max_particles:
            raise ValueError(
                "need 1 <= min_particles <= max_particles, got "
                f"{self.min_particles}, {self.max_particles}"
            )
        if not (self.kld_err > 0 and self.kld_z > 0):
            raise ValueError(f"kld_err and kld_z must be > 0, got {self.kld_err}, {self.kld_z}")
        self.recovery()  # validates the alphas
        self.trigger()  # and the update and resample rules
        self.schedule()

    def trigger(self) -> UpdateTrigger:
        return UPDATE_TRIGGERS[self.update_trigger](self.update_min_d, self.update_min_a)

    def schedule(self) -> Schedule:
        return Schedule(self.resample_interval, self.publish_every_update)

    def recovery(self) -> LikelihoodAverages:
        """amcl's recovery averages (w_slow, w_fast)."""
        return LikelihoodAverages(self.recovery_alpha_slow, self.recovery_alpha_fast)

    def resampler_for(self, dims: np.ndarray) -> Resampler:
        resampler = RESAMPLERS[self.resampler](
            dims, self.min_particles, self.max_particles, self.kld_err, self.kld_z
        )
        return SelectiveResampling(resampler) if self.selective_resampling else resampler

    @property
    def initial_cov(self) -> np.ndarray:
        return np.diag([self.initial_cov_xx, self.initial_cov_yy, self.initial_cov_aa])


@dataclass(frozen=True)
class Estimate:
    """The filter's output for one scan.

    Attributes:
        mean: (x, y, θ) in the map frame; between filter updates the last estimate carried
            forward by odometry.
        cov: 3 × 3 covariance of the estimate.
        n_particles: current number of particles.
        updated: whether this scan triggered a filter update (motion + sensor model).
    """

    mean: np.ndarray
    cov: np.ndarray
    n_particles: int
    updated: bool


class ParticleFilter:
    """A particle filter from parts (see the module docstring) for scans of `num_beams`."""

    def __init__(
        self,
        params: FilterParams,
        motion: MotionModel,
        sensor: SensorModel,
        proposal: Proposal,
        resampler: Resampler,
        estimator: Estimator,
        num_beams: int,
        mixing: Mixing | None = None,
        weighting: Weighting | None = None,
        seed: int | None = None,
    ) -> None:
        self.params, self.motion, self.sensor_model = params, motion, sensor
        self.proposal, self.resampler, self.estimator = proposal, resampler, estimator
        self.trigger, self.schedule = params.trigger(), params.schedule()
        self.num_beams = num_beams
        self.mixing = mixing or NoMixing()
        self.weighting = weighting or PriorWeights()
        self.rng = np.random.default_rng(params.seed if seed is None else seed)
        self.poses = np.empty((0, 3))
        self.weights = np.empty(0)
        self.recovery = params.recovery()
        self.converged = False
        self._initialised = False
        self._pending_global = False
        self._pf_init = False
        self._pf_odom_pose = np.zeros(3)
        self._updates = 0
        self._est_pose = np.zeros(3)
        self._est_cov = np.zeros((3, 3))
        self._est_odom = np.zeros(3)

    # -- initialisation ---------------------------------------------------------------------
    def initialize_pose(self, mean: np.ndarray, cov: np.ndarray | None = None) -> None:
        """Tracking: max_particles drawn from N(mean, cov) (default: the initial_cov_* params)."""
        mean = np.asarray(mean, dtype=np.float64)
        if mean.shape != (3,) or not np.all(np.isfinite(mean)):
            raise ValueError(f"initial pose must be 3 finite numbers (x, y, θ), got {mean}")
        cov = self.params.initial_cov if cov is None else np.asarray(cov, dtype=np.float64)
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
        """Global localization: max_particles from the proposal (amcl: uniform over the free
        space), weighted by the weighting; a proposal that needs a scan draws on the first."""
        if self.proposal.needs_scan:
            self._pending_global = self._initialised = True
        else:
            self._draw_global()

    def _draw_global(self) -> None:
        poses = self.proposal.sample(self.params.max_particles, self.rng)
        self.reset(poses, self.weighting.initial_weights(poses))

    def reset(self, poses: np.ndarray, weights: np.ndarray) -> None:
        """A new particle set (weights normalised here); the next scan starts the filter.

        As amcl's pf_init, the estimate is computed now, from these weights.
        """
        self.poses = np.ascontiguousarray(poses, dtype=np.float64)
        weights = np.asarray(weights, dtype=np.float64)
        self.weights = weights / weights.sum()
        self.recovery.reset()
        self.converged = False
        self._initialised = True
        self._pf_init = False
        self._est_pose, self._est_cov = self.estimator.estimate(self.poses, self.weights)

    # -- the filter -------------------------------------------------------------------------
    def update(self, odom_pose: np.ndarray, ranges: np.ndarray) -> Estimate:
        """Process one scan with the odometry pose at its time (amcl's laserReceived)."""
        if not self._initialised:
            raise RuntimeError("call initialize_pose() or initialize_global() before update()")
        odom_pose = np.asarray(odom_pose, dtype=np.float64)
        if odom_pose.shape != (3,) or not np.all(np.isfinite(odom_pose)):
            raise ValueError(f"odom_pose must be 3 finite numbers (x, y, θ), got {odom_pose}")
        ranges = np.asarray(ranges)
        if ranges.shape != (self.num_beams,):
            raise ValueError(
                f"scan has shape {ranges.shape}, expected ({self.num_beams},) ranges "
                "(LaserSpec.num_beams)"
            )
        if self.proposal.needs_scan:
            self.proposal.observe(ranges)
        if self._pending_global:
            self._pending_global = False
            self._draw_global()
        first = not self._pf_init
        if first:
            self._pf_odom_pose = odom_pose.copy()
            self._pf_init = True
            self._updates = 0
            do_update = True
            self._est_odom = odom_pose.copy()  # the initialisation's estimate, published now
        else:
            do_update = self.trigger.moved(self._pf_odom_pose, odom_pose)
            if do_update:
                self.motion.sample(self.poses, self._pf_odom_pose, odom_pose, self.rng)
        resample_due = False
        if do_update:
            if self._updates > 0:
                self.mix_in_proposal()
            self.sensor_update(ranges)
            self._pf_odom_pose = odom_pose.copy()
            self._updates += 1
            resample_due = self.schedule.resample_due(self._updates)
            if resample_due:
                self.resample()
        if self.schedule.publishes(do_update, resample_due):
            self._est_pose, self._est_cov = self.estimator.estimate(self.poses, self.weights)
            self._est_odom = odom_pose.copy()
        carried = compose(self._est_pose, compose(inverse(self._est_odom), odom_pose))
        return Estimate(carried, self._est_cov.copy(), len(self.poses), bool(do_update))

    def mix_in_proposal(self) -> None:
        """The mixing's share of particles drawn from the proposal beside the motion-predicted
        ones, the union weighted by the weighting (none for amcl)."""
        share = self.mixing.share(self.poses, self.weights)
        if share <= 0:
            return
        proposed = self.proposal.sample(max(1, round(share * len(self.poses))), self.rng)
        weights = self.weighting.mixed_weights(self.poses, self.weights, proposed)
        self.poses = np.ascontiguousarray(np.concatenate([self.poses, proposed]))
        self.weights = weights

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
            self.mixing.observe_likelihood(w_avg)
            self.recovery.follow(w_avg)
        else:
            self.weights = np.full(n, 1.0 / n)

    def resample(self) -> None:
        """amcl's pf_update_resample: the resampler's draw, with recovery injection from the
        proposal while the short-term average weight is below the long-term one."""
        w_diff = max(self.recovery.lost(), 0.0)
        drawn = self.resampler.resample(self.poses, self.weights, w_diff, self.injection, self.rng)
        if drawn is None:
            return
        if w_diff > 0.0:  # amcl resets the averages to avoid spiralling into randomness
            self.recovery.reset()
        self.poses, self.weights = drawn
        self.converged = converged(self.poses)

    def injection(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """m poses from the proposal for recovery, and their weights."""
        poses = self.proposal.sample(m, self.rng)
        return poses, self.weighting.injection_weights(poses)

    def warm_up(self, ranges: np.ndarray) -> None:
        """Run every compiled kernel once on a copy (numba loads or compiles on the first call),
        so that timed updates measure the filter, not the compiler. The state is unchanged."""
        rng_state = self.rng.bit_generator.state
        poses = self.poses[:4].copy() if len(self.poses) >= 4 else np.zeros((4, 3))
        self.sensor_model(poses, np.asarray(ranges), False)
        self.motion.sample(poses, np.zeros(3), np.array([1.0, 0.0, 0.1]), self.rng)
        saved = (self.poses, self.weights, self.recovery.slow, self.recovery.fast, self.converged)
        self.poses, self.weights = poses, np.full(4, 0.25)
        self.resample()
        self.estimator.estimate(self.poses, self.weights)
        self.poses, self.weights, self.recovery.slow, self.recovery.fast, self.converged = saved
        self.rng.bit_generator.state = rng_state


def run_filter(
    pf: ParticleFilter,
    trajectory: object,
    ranges: np.ndarray,
    mode: str | None = None,
    setup_s: float = 0.0,
) -> Localization:
    """Run a built filter over a trajectory (`times`, `truth`, `odometry` arrays, see
    trajectory.Trajectory): tracking from the true first pose, or global. Setup (building the
    filter, `setup_s`, and the kernels' first call) is timed apart from the per-scan updates.
    Rows between filter updates hold the last estimate carried forward by odometry. Its counts:
    the recovery's injected particles, the mixing's and the proposal's own. `mode` defaults to
    the filter's (its `filter` section)."""
    mode = pf.params.mode if mode is None else mode
    if mode not in MODES:
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
        pf.initialize_pose(truth[0])
    else:
        pf.initialize_global()
    pf.warm_up(ranges[0])
    setup_s += time.perf_counter() - start
    estimates, seconds = [], np.empty(len(odometry))
    for step in range(len(odometry)):
        tick = time.perf_counter()
        estimates.append(pf.update(odometry[step], ranges[step]))
        seconds[step] = time.perf_counter() - tick
    table = estimate_table(
        np.arange(len(odometry)),
        times,
        np.array([est.mean for est in estimates]),
        np.array([est.cov for est in estimates]),
        np.array([est.n_particles for est in estimates]),
    )
    counts = {"n_injected": pf.resampler.injected} | pf.mixing.counts() | pf.proposal.counts()
    return Localization(table, setup_s, seconds, counts)
