"""`maps` stage: draw one map from its geometric description (or load a ROS map) and save it
in ROS map_server format with a preview image.

A map the pipeline cannot use fails here, before anything is written: first the memory its
largest later stage would need, estimated from the map's size before it is built
(scanloc.stages.budget); then, once built, its content (free space, semantics, border,
components: scanloc.world.map_checks). The folder data/maps/<name>/ appears complete or not at
all.
"""

from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import DictConfig

from scanloc.io import atomic_dir, write_json
from scanloc.models.trainer_setup import cpu_has_native_bf16
from scanloc.sites import check_listed
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.stages.budget import (
    check_memory,
    estimate_memory,
    format_bytes,
    free_pose_cells,
    physical_memory,
    pipeline_sizes,
)
from scanloc.stages.site_budget import check_training_time, training_limit_minutes
from scanloc.world.build import build_map, map_provenance, render_map_preview
from scanloc.world.map_checks import (
    border_advice,
    cell_shares,
    check_map,
    map_label,
    planned_shape,
)
from scanloc.world.map_server import read_map_metadata, save_map


@stage_main("maps")
def main(cfg: DictConfig) -> None:
    out_dir = Path(cfg.out_dir)
    map_cfg = to_dict(cfg.map)
    label = map_label(map_cfg)
    checks = cfg.checks
    check_listed(str(cfg.map.name))
    with timed_stage(f"maps_{cfg.map.name}", cfg.timing_dir):
        shape = planned_shape(map_cfg)
        estimate = None
        if shape is not None:
            sizes = pipeline_sizes(str(cfg.map.name), str(checks.profile))
            estimate = estimate_memory(*shape, sizes)
            check_memory(estimate, label, float(checks.memory_budget))
        grid = build_map(map_cfg)
        from_file = map_cfg.get("source") == "file"
        border_fix = border_advice(read_map_metadata(Path(map_cfg["path"]))) if from_file else None
        components = check_map(
            grid, label, from_file, float(checks.max_occupied_share), border_fix=border_fix
        )
        training = ""
        if estimate is not None:
            cells = free_pose_cells(grid, sizes)
            profile = str(checks.profile)
            limit = training_limit_minutes(to_dict(checks), profile)
            training = "; " + check_training_time(
                label, sizes, cells, profile, limit, cpu_has_native_bf16()
            )
        provenance = map_provenance(map_cfg)
        with atomic_dir(out_dir) as tmp:
            save_map(grid, tmp / "map.yaml")
            render_map_preview(grid, tmp / "preview.png")
            if provenance is not None:  # only maps the stage changed: the others keep their bytes
                write_json(tmp / "meta.json", provenance)
    shares = cell_shares(grid)
    memory = ""
    if estimate is not None:
        memory = (
            f"; estimated peak {format_bytes(estimate.need)} ({estimate.peak_stage}, profile "
            f"{checks.profile}) of {format_bytes(physical_memory())}{training}"
        )
    print(
        f"maps: {label}: {grid.width} x {grid.height} cells at {grid.resolution:g} m, free "
        f"{shares['free']:.1%}, occupied {shares['occupied']:.1%}, unknown "
        f"{shares['unknown']:.1%}, {len(components)} free-space component(s){memory}",
        file=sys.stderr,
    )


if __name__ == "__main__":
    main()
