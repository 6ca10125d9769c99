"""A particle filter's config in sections (conf/localizer/amcl.yaml), each read by its part:

- `filter` (`FilterParams`): ROS 1 amcl's filter keys (`min_particles`, `update_min_d`,
  `resample_interval`, `recovery_alpha_slow`, ...), the start (`mode`) and `seed`, and the
  policies (`update_trigger`, `resampler`, `estimator`);
- `motion` (`OdometryParams`): ROS's `odom_model_type` and `odom_alpha1..5`;
- `sensor` (`SensorParams`): ROS's `laser_model_type` and `laser_*` keys (every model's keys
  are checked, as ROS reads every parameter), and `map_half_cell_offset` (true: amcl's
  half-cell world→cell shift, conf/localizer/amcl_ros_exact.yaml);
- `proposal`, `mixing`, `weighting`: parts chosen by their registered `type` (parts.py).

ROS's parameter names stay as ROS writes them inside the sections, so a user's amcl YAML
reads across: `MclConfig.from_ros` sorts a flat one into the sections. A key no part knows is
an error naming the config file, the section and the key; each default is its part's own.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

from scanloc.estimates import Localization
from scanloc.localize.config_params import parse_section, section_values
from scanloc.localize.mcl.estimator import ESTIMATORS, map_bins
from scanloc.localize.mcl.filter import FilterParams, ParticleFilter, run_filter
from scanloc.localize.mcl.mixing import Mixing
from scanloc.localize.mcl.motion import OdometryParams
from scanloc.localize.mcl.parts import MIXINGS, PROPOSALS, WEIGHTINGS, PartsContext
from scanloc.localize.mcl.proposals import Proposal, UniformProposal, Weighting
from scanloc.localize.mcl.sensor_models import SENSOR_MODELS, LaserGeometry, LaserParams
from scanloc.sensor.laser import LaserSpec
from scanloc.world.occupancy_grid import OccupancyGrid

# The sections a particle filter's config may have (beside the catalog's `meta`).
FILTER_SECTIONS = ("filter", "motion", "sensor", "proposal", "mixing", "weighting")
_MODEL_PARAMS = tuple(dict.fromkeys(model.Params for model in SENSOR_MODELS.values()))


@dataclass(frozen=True)
class _SensorChoice:
    """The `sensor` keys that are not a model's parameters."""

    laser_model_type: str = "likelihood_field"
    map_half_cell_offset: bool = False


_SENSOR_PARTS = (_SensorChoice, LaserParams, *_MODEL_PARAMS)


def _names(part: type) -> set[str]:
    return {f.name for f in fields(part)}


@dataclass(frozen=True)
class MclConfig:
    """The parts' parameters of one particle filter config."""

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
    def from_sections(cls, config: Mapping[str, Any], where: str) -> MclConfig:
        """The `filter`, `motion` and `sensor` sections of `config`; errors name `where`."""
        sensor = section_values(config, "sensor", where)
        known = sorted(set().union(*(_names(part) for part in _SENSOR_PARTS)))
        for key in sensor:
            if key not in known:
                raise ValueError(
                    f"{where}: section 'sensor': unknown key {key!r}; known: {', '.join(known)}"
                )

        choice = sensor_part(_SensorChoice, config, where)
        if choice.laser_model_type not in SENSOR_MODELS:
            raise ValueError(
                f"{where}: section 'sensor': key 'laser_model_type': expected one of "
                f"{sorted(SENSOR_MODELS)}, got {choice.laser_model_type!r}"
            )
        for params in _MODEL_PARAMS:  # every model's keys are checked, as ROS reads them all
            sensor_part(params, config, where)
        return cls(
            filter=parse_section(FilterParams, config, "filter", where),
            odometry=parse_section(OdometryParams, config, "motion", where),
            laser=sensor_part(LaserParams, config, where),
            laser_model_type=choice.laser_model_type,
            sensor=sensor_part(SENSOR_MODELS[choice.laser_model_type].Params, config, where),
            map_half_cell_offset=choice.map_half_cell_offset,
        )

    @classmethod
    def from_ros(cls, ros: Mapping[str, Any], where: str = "<ROS parameters>") -> MclConfig:
        """A flat ROS amcl parameter mapping (a user's amcl YAML), each key sorted into the
        section of the part that has it."""
        return cls.from_sections(ros_sections(ros, where), where)

    def with_filter(self, **changes: Any) -> MclConfig:
        """A copy with some FilterParams changed."""
        return replace(self, filter=replace(self.filter, **changes))


def sensor_part(part: type, config: Mapping[str, Any], where: str) -> Any:
    """One part's parameters (`LaserParams`, a sensor model's `Params`) from the `sensor`
    section's keys it has."""
    own = {k: v for k, v in section_values(config, "sensor", where).items() if k in _names(part)}
    return parse_section(part, {"sensor": own}, "sensor", where)


def sensor_model_params(config: Mapping[str, Any], where: str) -> dict[str, Any]:
    """Every sensor model's parameters as the `sensor` section sets them (ROS reads them all,
    whichever model it runs)."""
    return {
        f.name: getattr(sensor_part(params, config, where), f.name)
        for params in _MODEL_PARAMS
        for f in fields(params)
    }


def ros_sections(ros: Mapping[str, Any], where: str) -> dict[str, dict[str, Any]]:
    """A flat ROS amcl parameter mapping as the sections `filter`, `motion`, `sensor`."""
    owners = {"filter": _names(FilterParams), "motion": _names(OdometryParams)}
    owners["sensor"] = set().union(*(_names(part) for part in _SENSOR_PARTS))
    sections: dict[str, dict[str, Any]] = {name: {} for name in owners}
    for key, value in ros.items():
        section = next((name for name, keys in owners.items() if key in keys), None)
        if section is None:
            known = sorted(set().union(*owners.values()))
            raise ValueError(f"{where}: unknown parameter {key!r}; known: {', '.join(known)}")
        sections[section][key] = value
    return sections


def build_filter(
    grid: OccupancyGrid,
    spec: LaserSpec,
    config: MclConfig | None = None,
    seed: int | None = None,
    proposal: Proposal | None = None,
    weighting: Weighting | None = None,
    laser_mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
    mixing: Mixing | None = None,
) -> ParticleFilter:
    """The particle filter `config` describes, on `grid` with the laser `spec` mounted at
    `laser_mount` (x, y, θ in the base frame); the proposal defaults to amcl's uniform one over
    the free space, the mixing to none and the weighting to amcl's; `seed` to the config's."""
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
        resampler=p.resampler_for(dims),
        estimator=ESTIMATORS[p.estimator](dims),
        num_beams=spec.num_beams,
        mixing=mixing,
        weighting=weighting,
        seed=seed,
    )


def filter_from_sections(
    config: Mapping[str, Any], where: str, context: PartsContext
) -> ParticleFilter:
    """The particle filter a sectioned config describes, its proposal, mixing and weighting
    built by their registered types (`context`: the map, the laser, the learned hypotheses)."""
    mcl = MclConfig.from_sections(config, where)
    context.sections, context.where = config, where
    context.half_cell_offset = mcl.map_half_cell_offset
    context.proposal = PROPOSALS.build(context)
    return build_filter(
        context.grid,
        context.laser,
        mcl,
        proposal=context.proposal,
        weighting=WEIGHTINGS.build(context),
        laser_mount=context.laser_mount,
        mixing=MIXINGS.build(context),
    )


def run_mcl(
    grid: OccupancyGrid,
    spec: LaserSpec,
    trajectory: object,
    ranges: Any,
    config: MclConfig | None = None,
    mode: str | None = None,
    seed: int | None = None,
    laser_mount: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Localization:
    """amcl over a driven trajectory: tracking from the true first pose with the initial_cov_*
    covariance, or global from particles uniform over the free space (see filter.run_filter);
    `mode` and `seed` default to the config's."""
    start = time.perf_counter()
    pf = build_filter(grid, spec, config, seed=seed, laser_mount=laser_mount)
    return run_filter(pf, trajectory, ranges, mode, time.perf_counter() - start)
