"""The laser models amcl weights its particles with, chosen by `laser_model_type` as in ROS.

Each model owns its parameters (a small dataclass of ROS's `laser_*` keys, with ROS 1's
defaults) and is built once per map (its tables), then called per scan: `model(poses, scan,
filter_converged)` returns, for each particle, the factor its weight is multiplied by.
- `likelihood_field` (ROS 1's default; kernels in `localize/likelihood_field.py`): 1 + Σ pz³
  over the beam end points' distances to the nearest obstacle;
- `likelihood_field_prob` (nav2 and ROS 1 noetic; `localize/likelihood_field_prob.py`): Π pz,
  with optional beam skipping once the filter has converged;
- `beam` (`localize/beam_model.py`): 1 + Σ pz³ of ROS's four-part beam mixture against the
  ranges the map predicts, read from a precomputed range table.
Every model skips NaN readings; each keeps its own ROS rule for which beams it evaluates.
`LaserParams` are the keys every model shares (range limits, beam count). A new model is one
class with a `Params` dataclass and a `build` classmethod, registered in `SENSOR_MODELS`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from scanloc.localize.beam_model import (
    BeamMixture,
    RangeTable,
    beam_model_weights,
    build_range_table,
    select_beams_beam_model,
)
from scanloc.localize.likelihood_field import (
    LikelihoodField,
    beam_weights,
    build_likelihood_field,
    select_beams,
)
from scanloc.localize.likelihood_field_prob import (
    LikelihoodFieldProb,
    build_likelihood_field_prob,
    prob_weights,
    select_beams_prob,
)
from scanloc.pose import wrap_angle
from scanloc.sensor.laser import LaserSpec
from scanloc.world.occupancy_grid import OccupancyGrid


class SensorModel(Protocol):
    """A laser model: per-particle weight factors for one scan."""

    def __call__(self, poses: np.ndarray, scan: np.ndarray, filter_converged: bool) -> np.ndarray:
        """Factors (N,) for particles (N, 3) given the scan's ranges (num_beams,)."""
        ...


@dataclass(frozen=True)
class LaserParams:
    """What every model takes of the laser config: range limits (<= 0: the scanner's own) and
    how many beams amcl evaluates."""

    laser_min_range: float = -1.0
    laser_max_range: float = -1.0
    laser_max_beams: int = 30

    def __post_init__(self) -> None:
        if self.laser_max_beams < 2:
            raise ValueError(f"laser_max_beams must be >= 2, got {self.laser_max_beams}")


@dataclass(frozen=True)
class LaserGeometry:
    """Beam bearings and the range limits amcl applies: the scanner's, narrowed by the
    config's `laser_min_range` / `laser_max_range` where those are > 0; and the laser's
    `mount` (x, y, θ) in the robot base frame, which ROS amcl reads from tf: every beam is
    cast from base ⊕ mount."""

    angles: np.ndarray
    range_min: float
    range_max: float
    max_beams: int
    mount: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def of(
        cls,
        spec: LaserSpec,
        params: LaserParams,
        mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> LaserGeometry:
        p = params
        range_min = (
            max(spec.range_min, p.laser_min_range) if p.laser_min_range > 0 else spec.range_min
        )
        range_max = (
            min(spec.range_max, p.laser_max_range) if p.laser_max_range > 0 else spec.range_max
        )
        mount = tuple(float(v) for v in mount)
        if len(mount) != 3 or not all(np.isfinite(mount)):
            raise ValueError(f"laser mount must be 3 finite numbers (x, y, θ), got {mount}")
        return cls(spec.beam_angles(), range_min, range_max, p.laser_max_beams, mount)

    def laser_poses(self, poses: np.ndarray) -> np.ndarray:
        """The laser's poses for robot base poses (N, 3): base ⊕ mount (the poses themselves
        when the mount is zero)."""
        if not any(self.mount):
            return poses
        mx, my, mth = self.mount
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        return np.ascontiguousarray(
            np.column_stack(
                [
                    poses[:, 0] + c * mx - s * my,
                    poses[:, 1] + s * mx + c * my,
                    wrap_angle(poses[:, 2] + mth),
                ]
            )
        )


@dataclass(frozen=True)
class LikelihoodFieldParams:
    """The likelihood field's mixture: hits (Gaussian in the end point's obstacle distance,
    capped at `laser_likelihood_max_dist`) and random readings."""

    laser_z_hit: float = 0.95
    laser_z_rand: float = 0.05
    laser_sigma_hit: float = 0.2
    laser_likelihood_max_dist: float = 2.0

    def __post_init__(self) -> None:
        if not (self.laser_sigma_hit > 0 and self.laser_likelihood_max_dist > 0):
            raise ValueError("laser_sigma_hit and laser_likelihood_max_dist must be > 0")
        if min(self.laser_z_hit, self.laser_z_rand) < 0:
            raise ValueError("laser_z_* must be >= 0")


@dataclass(frozen=True)
class LikelihoodFieldProbParams(LikelihoodFieldParams):
    """The likelihood field's parameters and nav2's beam skipping (`do_beamskip`)."""

    do_beamskip: bool = False
    beam_skip_distance: float = 0.5
    beam_skip_threshold: float = 0.3
    beam_skip_error_threshold: float = 0.9

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (0 <= self.beam_skip_threshold <= 1 and 0 <= self.beam_skip_error_threshold <= 1):
            raise ValueError("beam_skip_threshold and beam_skip_error_threshold must lie in [0, 1]")


@dataclass(frozen=True)
class BeamParams:
    """ROS's four-part beam mixture, and scanloc's range table: its cell (m) and heading bins
    (`beam_lut_resolution`, `beam_lut_angles`; see beam_model.py)."""

    laser_z_hit: float = 0.95
    laser_z_short: float = 0.1
    laser_z_max: float = 0.05
    laser_z_rand: float = 0.05
    laser_sigma_hit: float = 0.2
    laser_lambda_short: float = 0.1
    beam_lut_resolution: float = 0.05
    beam_lut_angles: int = 360

    def __post_init__(self) -> None:
        weights = (self.laser_z_hit, self.laser_z_short, self.laser_z_max, self.laser_z_rand)
        if min(weights) < 0 or self.laser_lambda_short <= 0:
            raise ValueError("laser_z_* must be >= 0 and laser_lambda_short > 0")
        if self.laser_sigma_hit <= 0:
            raise ValueError("laser_sigma_hit must be > 0")


@dataclass(frozen=True)
class LikelihoodFieldModel:
    Params: ClassVar[type] = LikelihoodFieldParams
    field: LikelihoodField
    laser: LaserGeometry

    @classmethod
    def build(
        cls,
        grid: OccupancyGrid,
        laser: LaserGeometry,
        p: LikelihoodFieldParams,
        half_cell_offset: bool = False,
    ) -> LikelihoodFieldModel:
        field = build_likelihood_field(
            grid,
            z_hit=p.laser_z_hit,
            z_rand=p.laser_z_rand,
            sigma_hit=p.laser_sigma_hit,
            max_dist=p.laser_likelihood_max_dist,
            range_max=laser.range_max,
            half_cell_offset=half_cell_offset,
        )
        return cls(field, laser)

    def __call__(self, poses: np.ndarray, scan: np.ndarray, filter_converged: bool) -> np.ndarray:
        lz = self.laser
        r, b = select_beams(scan, lz.angles, lz.range_min, lz.range_max, lz.max_beams)
        return beam_weights(self.field, lz.laser_poses(poses), r, b)


@dataclass(frozen=True)
class LikelihoodFieldProbModel:
    Params: ClassVar[type] = LikelihoodFieldProbParams
    field: LikelihoodFieldProb
    laser: LaserGeometry
    params: LikelihoodFieldProbParams

    @classmethod
    def build(
        cls,
        grid: OccupancyGrid,
        laser: LaserGeometry,
        p: LikelihoodFieldProbParams,
        half_cell_offset: bool = False,
    ) -> LikelihoodFieldProbModel:
        field = build_likelihood_field_prob(
            grid,
            z_hit=p.laser_z_hit,
            z_rand=p.laser_z_rand,
            sigma_hit=p.laser_sigma_hit,
            max_dist=p.laser_likelihood_max_dist,
            range_max=laser.range_max,
            beam_skip_distance=p.beam_skip_distance,
            half_cell_offset=half_cell_offset,
        )
        return cls(field, laser, p)

    def __call__(self, poses: np.ndarray, scan: np.ndarray, filter_converged: bool) -> np.ndarray:
        lz, p = self.laser, self.params
        r, b = select_beams_prob(scan, lz.angles, lz.range_min, lz.range_max, lz.max_beams)
        return prob_weights(
            self.field,
            lz.laser_poses(poses),
            r,
            b,
            p.do_beamskip,
            p.beam_skip_threshold,
            p.beam_skip_error_threshold,
            filter_converged,
        )


@dataclass(frozen=True)
class BeamModel:
    Params: ClassVar[type] = BeamParams
    table: RangeTable
    laser: LaserGeometry
    mixture: BeamMixture

    @classmethod
    def build(
        cls,
        grid: OccupancyGrid,
        laser: LaserGeometry,
        p: BeamParams,
        half_cell_offset: bool = False,
    ) -> BeamModel:
        table = build_range_table(
            grid,
            laser.range_max,
            p.beam_lut_resolution,
            p.beam_lut_angles,
            half_cell_offset=half_cell_offset,
        )
        mixture = BeamMixture(
            z_hit=p.laser_z_hit,
            z_short=p.laser_z_short,
            z_max=p.laser_z_max,
            z_rand=p.laser_z_rand,
            sigma_hit=p.laser_sigma_hit,
            lambda_short=p.laser_lambda_short,
        )
        return cls(table, laser, mixture)

    def __call__(self, poses: np.ndarray, scan: np.ndarray, filter_converged: bool) -> np.ndarray:
        lz = self.laser
        obs, b = select_beams_beam_model(scan, lz.angles, lz.range_min, lz.range_max, lz.max_beams)
        return beam_model_weights(self.table, lz.laser_poses(poses), obs, b, self.mixture)


# `laser_model_type` (ROS's name) -> the model's class.
SENSOR_MODELS: dict[str, type] = {
    "likelihood_field": LikelihoodFieldModel,
    "likelihood_field_prob": LikelihoodFieldProbModel,
    "beam": BeamModel,
}
