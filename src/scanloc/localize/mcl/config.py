"""A flat, ROS-named localizer config (conf/localizer/amcl.yaml: `laser_z_hit`, `odom_alpha1`,
`resample_interval`, ...) mapped onto the particle filter's parts.

The keys are ROS 1 amcl's, as users know them; each part takes its own: the filter
(`FilterParams`), the odometry model (`OdometryParams`, `odom_*`), the laser range limits
(`LaserParams`) and the sensor model `laser_model_type` names (its `Params`). Keys of the
sensor models not chosen are checked too (as ROS reads every parameter), and
`map_half_cell_offset` (true: amcl's half-cell world→cell shift, conf/localizer/
amcl_ros_exact.yaml) goes to the sensor model and the uniform proposal. A key no part knows is
an error naming the config file and the key.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

from scanloc.estimates import Localization
from scanloc.localize.catalog import META_KEYS
from scanloc.localize.config_params import params_from_config
from scanloc.localize.mcl.estimator import ClusterEstimator, map_bins
from scanloc.localize.mcl.filter import FilterParams, ParticleFilter, run_filter
from scanloc.localize.mcl.motion import OdometryParams
from scanloc.localize.mcl.proposals import Proposal, UniformProposal, Weighting
from scanloc.localize.mcl.resampler import KldResampler
from scanloc.localize.mcl.sensor_models import SENSOR_MODELS, LaserGeometry, LaserParams
from scanloc.sensor.laser import LaserSpec
from scanloc.world.occupancy_grid import OccupancyGrid

_SENSOR_PARAMS = tuple(dict.fromkeys(model.Params for model in SENSOR_MODELS.values()))
_PARTS = (FilterParams, OdometryParams, LaserParams, *_SENSOR_PARAMS)


def known_keys() -> list[str]:
    """Every parameter a ROS-named filter config may set, sorted."""
    names = {f.name for part in _PARTS for f in fields(part)}
    return sorted(names | {f.name for f in fields(_OwnKeys)})


@dataclass(frozen=True)
class MclConfig:
    """The parts' parameters of one localizer config."""

    filter: FilterParams = field(default_factory=FilterParams)
    odometry: OdometryParams = field(default_factory=OdometryParams)
    laser: LaserParams = field(default_factory=LaserParams)
    laser_model_type: str = "likelihood_field"
    sensor: Any = None  # the chosen model's Params; None: its defaults
    map_half_cell_offset: bool = False

    def __post_init__(self) -> None:
        if self.laser_model_type not in SENSOR_MODELS:
            raise ValueError(
                f"laser_model_type must be one of {sorted(SENSOR_MODELS)}, "
                f"got {self.laser_model_type!r}"
            )
        if self.sensor is None:
            object.__setattr__(self, "sensor", SENSOR_MODELS[self.laser_model_type].Params())

    @classmethod
    def from_ros(cls, config: Mapping[str, Any], source: str | None = None) -> MclConfig:
        """The parts of a flat ROS-named config (meta keys such as `name` are skipped).

        `source` names the config in errors (default: conf/localizer/<name>.yaml).
        """
        where = source or f"conf/localizer/{config.get('name', '<unnamed>')}.yaml"
        values = {k: v for k, v in config.items() if k not in META_KEYS}
        known = known_keys()
        for key in values:
            if key not in known:
                raise ValueError(
                    f"{where}: field {key!r}: unknown parameter; known: {', '.join(known)}"
                )
        own = _parse(_OwnKeys, values, where)
        parts = {part: _parse(part, values, where) for part in _PARTS}
        model = own.laser_model_type
        if model not in SENSOR_MODELS:
            raise ValueError(
                f"{where}: field 'laser_model_type': expected one of {sorted(SENSOR_MODELS)}, "
                f"got {model!r}"
            )
        return cls(
            filter=parts[FilterParams],
            odometry=parts[OdometryParams],
            laser=parts[LaserParams],
            laser_model_type=model,
            sensor=parts[SENSOR_MODELS[model].Params],
            map_half_cell_offset=own.map_half_cell_offset,
        )

    def with_filter(self, **changes: Any) -> MclConfig:
        """A copy with some FilterParams changed."""
        return replace(self, filter=replace(self.filter, **changes))


@dataclass(frozen=True)
class _OwnKeys:
    """The types and defaults of the keys the builder itself reads."""

    laser_model_type: str = "likelihood_field"
    map_half_cell_offset: bool = False


def _parse(part: type, values: Mapping[str, Any], where: str) -> Any:
    """The dataclass `part` from the keys of `values` it has; errors name `where`."""
    names = {f.name for f in fields(part)}
    try:
        return params_from_config(part, {k: v for k, v in values.items() if k in names}, where)
    except ValueError as err:
        if str(err).startswith(where):
            raise
        raise ValueError(f"{where}: {err}") from None


def build_filter(
    grid: OccupancyGrid,
    spec: LaserSpec,
    config: MclConfig | None = None,
    seed: int = 0,
    proposal: Proposal | None = None,
    weighting: Weighting | None = None,
    laser_mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> ParticleFilter:
    """The particle filter `config` describes, on `grid` with the laser `spec` mounted at
    `laser_mount` (x, y, θ in the base frame); the proposal defaults to amcl's uniform one over
    the free space, the weighting to amcl's."""
    config = config or MclConfig()
    dims = map_bins(grid)
    p = config.filter
    laser = LaserGeometry.of(spec, config.laser, laser_mount)
    model = SENSOR_MODELS[config.laser_model_type]
    return ParticleFilter(
        params=p,
        motion=config.odometry.model(),
        sensor=model.build(grid, laser, config.sensor, config.map_half_cell_offset),
        proposal=proposal or UniformProposal(grid, config.map_half_cell_offset),
        resampler=KldResampler(
            dims, p.min_particles, p.max_particles, p.kld_err, p.kld_z, p.selective_resampling
        ),
        estimator=ClusterEstimator(dims),
        trigger=p.trigger(),
        num_beams=spec.num_beams,
        weighting=weighting,
        seed=seed,
    )


def run_mcl(
    grid: OccupancyGrid,
    spec: LaserSpec,
    trajectory: object,
    ranges: Any,
    config: MclConfig | None = None,
    mode: str = "tracking",
    seed: int = 0,
    laser_mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Localization:
    """amcl over a driven trajectory: tracking from the true first pose with the initial_cov_*
    covariance, or global from particles uniform over the free space (see filter.run_filter)."""
    start = time.perf_counter()
    pf = build_filter(grid, spec, config, seed=seed, laser_mount=laser_mount)
    return run_filter(pf, trajectory, ranges, mode, time.perf_counter() - start)
