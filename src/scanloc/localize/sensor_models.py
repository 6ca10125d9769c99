"""The laser models amcl weights its particles with, chosen by `laser_model_type` as in ROS.

Each model is built once per map (its tables) and then called per scan: `model(poses, scan,
filter_converged)` returns, for each particle, the factor its weight is multiplied by.
- `likelihood_field` (ROS 1's default; `likelihood_field.py`): 1 + Σ pz³ over the beam end
  points' distances to the nearest obstacle;
- `likelihood_field_prob` (nav2 and ROS 1 noetic; `likelihood_field_prob.py`): Π pz, with
  optional beam skipping once the filter has converged;
- `beam` (`beam_model.py`): 1 + Σ pz³ of ROS's four-part beam mixture against the ranges
  the map predicts, read from a precomputed range table.
Every model skips NaN readings; each keeps its own ROS rule for which beams it evaluates.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

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
from scanloc.world.occupancy_grid import OccupancyGrid

if TYPE_CHECKING:
    from scanloc.localize.amcl import AmclParams


class SensorModel(Protocol):
    """A laser model: per-particle weight factors for one scan."""

    def __call__(self, poses: np.ndarray, scan: np.ndarray, filter_converged: bool) -> np.ndarray:
        """Factors (N,) for particles (N, 3) given the scan's ranges (num_beams,)."""
        ...


@dataclass(frozen=True)
class LaserGeometry:
    """What every model needs of the laser: beam bearings and the range limits amcl applies."""

    angles: np.ndarray
    range_min: float
    range_max: float
    max_beams: int


@dataclass(frozen=True)
class LikelihoodFieldModel:
    field: LikelihoodField
    laser: LaserGeometry

    def __call__(self, poses: np.ndarray, scan: np.ndarray, filter_converged: bool) -> np.ndarray:
        lz = self.laser
        r, b = select_beams(scan, lz.angles, lz.range_min, lz.range_max, lz.max_beams)
        return beam_weights(self.field, poses, r, b)


@dataclass(frozen=True)
class LikelihoodFieldProbModel:
    field: LikelihoodFieldProb
    laser: LaserGeometry
    do_beamskip: bool
    beam_skip_threshold: float
    beam_skip_error_threshold: float

    def __call__(self, poses: np.ndarray, scan: np.ndarray, filter_converged: bool) -> np.ndarray:
        lz = self.laser
        r, b = select_beams_prob(scan, lz.angles, lz.range_min, lz.range_max, lz.max_beams)
        return prob_weights(
            self.field,
            poses,
            r,
            b,
            self.do_beamskip,
            self.beam_skip_threshold,
            self.beam_skip_error_threshold,
            filter_converged,
        )


@dataclass(frozen=True)
class BeamModel:
    table: RangeTable
    laser: LaserGeometry
    mixture: BeamMixture

    def __call__(self, poses: np.ndarray, scan: np.ndarray, filter_converged: bool) -> np.ndarray:
        lz = self.laser
        obs, b = select_beams_beam_model(scan, lz.angles, lz.range_min, lz.range_max, lz.max_beams)
        return beam_model_weights(self.table, poses, obs, b, self.mixture)


def _likelihood_field(grid: OccupancyGrid, laser: LaserGeometry, p: AmclParams) -> SensorModel:
    field = build_likelihood_field(
        grid,
        z_hit=p.laser_z_hit,
        z_rand=p.laser_z_rand,
        sigma_hit=p.laser_sigma_hit,
        max_dist=p.laser_likelihood_max_dist,
        range_max=laser.range_max,
        half_cell_offset=p.map_half_cell_offset,
    )
    return LikelihoodFieldModel(field, laser)


def _likelihood_field_prob(grid: OccupancyGrid, laser: LaserGeometry, p: AmclParams) -> SensorModel:
    field = build_likelihood_field_prob(
        grid,
        z_hit=p.laser_z_hit,
        z_rand=p.laser_z_rand,
        sigma_hit=p.laser_sigma_hit,
        max_dist=p.laser_likelihood_max_dist,
        range_max=laser.range_max,
        beam_skip_distance=p.beam_skip_distance,
        half_cell_offset=p.map_half_cell_offset,
    )
    return LikelihoodFieldProbModel(
        field, laser, p.do_beamskip, p.beam_skip_threshold, p.beam_skip_error_threshold
    )


def _beam(grid: OccupancyGrid, laser: LaserGeometry, p: AmclParams) -> SensorModel:
    table = build_range_table(
        grid,
        laser.range_max,
        p.beam_lut_resolution,
        p.beam_lut_angles,
        half_cell_offset=p.map_half_cell_offset,
    )
    mixture = BeamMixture(
        z_hit=p.laser_z_hit,
        z_short=p.laser_z_short,
        z_max=p.laser_z_max,
        z_rand=p.laser_z_rand,
        sigma_hit=p.laser_sigma_hit,
        lambda_short=p.laser_lambda_short,
    )
    return BeamModel(table, laser, mixture)


SENSOR_MODELS: dict[str, Callable[[OccupancyGrid, LaserGeometry, AmclParams], SensorModel]] = {
    "likelihood_field": _likelihood_field,
    "likelihood_field_prob": _likelihood_field_prob,
    "beam": _beam,
}


def build_sensor_model(
    grid: OccupancyGrid, laser: LaserGeometry, params: AmclParams
) -> SensorModel:
    """The model `params.laser_model_type` names, built for `grid`."""
    kind = params.laser_model_type
    if kind not in SENSOR_MODELS:
        raise ValueError(f"laser_model_type must be one of {sorted(SENSOR_MODELS)}, got {kind!r}")
    return SENSOR_MODELS[kind](grid, laser, params)
