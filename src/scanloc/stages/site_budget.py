"""Whether a site's learned localizer can train on this machine: the training time and the
memory its map implies at a profile, estimated before anything trains, printed, and refused
above the limits of conf/maps.yaml `checks`.

Every stage that makes a map the learned localizer will train on runs it as soon as the map
exists: `maps` (a drawn map or the user's), `real` (a CARMEN log's map, right after it is built
from the mapping part, before the rest of the log is processed) and `bag`. So a building too
large for the machine is refused in seconds, with the estimate and the setting to change,
instead of training for hours. The estimates are scanloc.stages.budget's (fitted to measured
trainings on 2 CPU cores), in the precision that `precision: auto` picks on this CPU.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from scanloc.models.trainer_setup import cpu_has_native_bf16
from scanloc.progress import duration
from scanloc.scanlocnet.schedule import training_epochs
from scanloc.stages.budget import (
    PipelineSizes,
    check_memory,
    estimate_memory,
    free_pose_cells,
    pipeline_sizes,
    scanlocnet_training_seconds,
)
from scanloc.world.map_checks import MapCheckError
from scanloc.world.occupancy_grid import OccupancyGrid


def limit_field(profile: str) -> str:
    return f"conf/maps.yaml: field 'checks.max_training_min.{profile}'"


class TrainingTooLongError(MapCheckError):
    """A site whose learned localizer would train longer than the configured limit."""


def training_limit_minutes(checks: Mapping[str, Any], profile: str) -> float | None:
    """checks.max_training_min at `profile`: minutes, or None for no limit."""
    limits = checks.get("max_training_min")
    if not isinstance(limits, Mapping) or profile not in limits:
        raise ValueError(
            f"{limit_field(profile)}: expected a limit in minutes (or null) for profile "
            f"{profile!r}, got {limits!r}"
        )
    limit = limits[profile]
    if limit is None:
        return None
    if isinstance(limit, bool) or not isinstance(limit, int | float) or not limit > 0:
        raise ValueError(f"{limit_field(profile)}: expected minutes > 0 or null, got {limit!r}")
    return float(limit)


def check_training_time(
    label: str,
    sizes: PipelineSizes,
    cells: int,
    profile: str,
    limit_min: float | None,
    bf16: bool,
) -> str:
    """A sentence with the learned localizer's estimated training on `cells` pose cells; raises
    TrainingTooLongError with it, the limit and what to change when it is over `limit_min`."""
    seconds = scanlocnet_training_seconds(sizes, cells, bf16=bf16)
    epochs = sizes.epochs
    if epochs and sizes.scans_per_epoch:
        epochs = training_epochs(
            epochs, sizes.scans_per_epoch, max(cells, 1), sizes.min_samples_per_cell
        )
    precision = "bf16" if bf16 else "float32"
    sentence = (
        f"ScanLocNet's training at profile {profile}: {cells} pose cells, {epochs} epochs, "
        f"~{duration(seconds)} in {precision} on this CPU (2 cores)"
    )
    if limit_min is None or seconds <= 60.0 * limit_min:
        return sentence
    raise TrainingTooLongError(
        f"{label}: {sentence}, over the limit of {limit_min:g} min ({limit_field(profile)}). "
        f"Expected a site whose learned localizer trains within the limit: crop the map to the "
        f"area the robot uses, coarsen the pose grid (conf/scanlocnet.yaml grid.cell_size), use "
        f"a smaller profile, or raise checks.max_training_min.{profile} in conf/maps.yaml "
        "(null: no limit) to train anyway"
    )


def check_site(
    label: str,
    grid: OccupancyGrid,
    map_name: str,
    profile: str,
    checks: Mapping[str, Any],
    real_log: bool,
    num_beams: int,
) -> str:
    """Memory, then training time, of the stages that follow a site's map at `profile`
    (`real_log`: the denser training of a real log's or a bag's map); the training sentence,
    or MapTooLargeError / TrainingTooLongError."""
    sizes = dataclasses.replace(
        pipeline_sizes(map_name, profile, real_log=real_log), num_beams=int(num_beams)
    )
    estimate = estimate_memory(grid.height, grid.width, grid.resolution, sizes)
    check_memory(estimate, label, float(checks["memory_budget"]))
    cells = free_pose_cells(grid, sizes)
    limit = training_limit_minutes(checks, profile)
    return check_training_time(label, sizes, cells, profile, limit, cpu_has_native_bf16())
