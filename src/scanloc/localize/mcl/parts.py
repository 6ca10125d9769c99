"""Parts chosen by a registered `type`: the `proposal`, `mixing` and `weighting` sections of a
particle filter's config (conf/localizer/<name>.yaml). Each registered type owns a parameter
dataclass (its section's keys besides `type`, defaults in the dataclass) and a builder; amcl's
parts (`uniform`, `none`, `prior`) register in this package, the hybrid's (`learned`,
`constant`, `adaptive`, `verified_gate`, `importance`) in localize/hybrid.py."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

from scanloc.localize.config_params import parse_section, section_values
from scanloc.localize.mcl.mixing import NoMixing
from scanloc.localize.mcl.proposals import PriorWeights, UniformProposal
from scanloc.sensor.laser import LaserSpec
from scanloc.world.occupancy_grid import OccupancyGrid


@dataclass
class PartsContext:
    """What a part's builder may need beside its own parameters: the map, the laser and its
    mount, the whole config (`sections`, for a part that reads a shared section such as
    `verifier`) and its file (`where`), the learned localizer's hypotheses (built on first use),
    and the proposal once built (the mixing and the weighting use it)."""

    grid: OccupancyGrid
    laser: LaserSpec
    laser_mount: tuple[float, float, float] = (0.0, 0.0, 0.0)
    half_cell_offset: bool = False
    sections: Mapping[str, Any] = field(default_factory=dict)
    where: str = "<config>"
    hypotheses: Callable[[], Callable[[Any], Any]] | None = None
    proposal: Any = None

    @cached_property
    def uniform(self) -> UniformProposal:
        """amcl's uniform proposal over the free space (the learned proposal's defensive share)."""
        return UniformProposal(self.grid, self.half_cell_offset)

    def section(self, cls: type, name: str) -> Any:
        """Another section of the config, read into `cls`."""
        return parse_section(cls, self.sections, name, self.where)


@dataclass(frozen=True)
class PartType:
    params: type
    build: Callable[[Any, PartsContext], Any]


class PartRegistry:
    """The types one section may name, with their parameters and builders."""

    def __init__(self, section: str, default: str) -> None:
        self.section, self.default = section, default
        self.types: dict[str, PartType] = {}

    def register(self, name: str, params: type) -> Callable[[Callable], Callable]:
        """Register the decorated builder `(params, context) -> part` under `name`."""

        def add(build: Callable[[Any, PartsContext], Any]) -> Callable:
            if name in self.types and self.types[name].build is not build:
                raise ValueError(f"{self.section} type {name!r} is registered twice")
            self.types[name] = PartType(params, build)
            return build

        return add

    def params(self, sections: Mapping[str, Any], where: str) -> tuple[str, Any]:
        """(type, its parameters) of the section in `sections` (absent: the default type)."""
        values = section_values(sections, self.section, where)
        name = str(values.pop("type", self.default))
        if name not in self.types:
            raise ValueError(
                f"{where}: section '{self.section}': key 'type': expected one of "
                f"{sorted(self.types)}, got {name!r}"
            )
        params = parse_section(self.types[name].params, {self.section: values}, self.section, where)
        return name, params

    def build(self, context: PartsContext) -> Any:
        """The part the config's section describes."""
        name, params = self.params(context.sections, context.where)
        return self.types[name].build(params, context)


PROPOSALS = PartRegistry("proposal", default="uniform")
MIXINGS = PartRegistry("mixing", default="none")
WEIGHTINGS = PartRegistry("weighting", default="prior")


@dataclass(frozen=True)
class NoParams:
    """A part type without parameters."""


@PROPOSALS.register("uniform", NoParams)
def uniform_proposal(params: NoParams, context: PartsContext) -> UniformProposal:
    """amcl's proposal: free cells uniformly, headings uniformly."""
    return context.uniform


@MIXINGS.register("none", NoParams)
def no_mixing(params: NoParams, context: PartsContext) -> NoMixing:
    return NoMixing()


@WEIGHTINGS.register("prior", NoParams)
def prior_weights(params: NoParams, context: PartsContext) -> PriorWeights:
    return PriorWeights()
