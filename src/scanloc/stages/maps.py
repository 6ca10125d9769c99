"""`maps` stage: draw one map from its geometric description (or load a ROS map) and save it
in ROS map_server format with a preview image.

A map the pipeline cannot use fails here, before anything is written (scanloc.world.map_checks):
first the memory its largest later stage would need, estimated from the map's size before it
is built; then, once built, its content (free space, semantics, border, components). The
folder data/maps/<name>/ appears complete or not at all.
"""

from __future__ import annotations

import sys
from pathlib import Path

from hydra import compose
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig

from scanloc.io import atomic_dir
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.world.build import build_map, render_map_preview
from scanloc.world.map_checks import (
    PipelineSizes,
    cell_shares,
    check_map,
    check_memory,
    estimate_memory,
    format_bytes,
    map_label,
    physical_memory,
    planned_shape,
)
from scanloc.world.map_server import save_map


def pipeline_sizes(map_name: str, profile: str) -> PipelineSizes:
    """What the later stages allocate for map `map_name` at `profile`, read from their own
    configs as DVC composes them: the scans datasets of this map (its validation scans, and
    Table 1's where they are drawn on it), the learned model's training scans and pose grid,
    and whether some localizer builds amcl's beam-model range table."""

    def conf(name: str, *overrides: str) -> DictConfig:
        return compose(name, overrides=[f"profile={profile}", *overrides])

    val = conf("scans", "dataset=map_validation", f"dataset.map={map_name}")
    datasets = {str(val.dataset.name): int(val.dataset.num_samples)}
    for option in GlobalHydra.instance().config_loader().get_group_options("dataset"):
        dataset = conf("scans", f"dataset={option}").dataset
        if option != "map_validation" and dataset.map == map_name:
            datasets[str(dataset.name)] = int(dataset.num_samples)
    net = conf("scanlocnet", f"map_name={map_name}")
    localizers = conf("localize", f"map_name={map_name}").localizers.values()
    beam = [loc for loc in localizers if loc.get("laser_model_type") == "beam"]
    return PipelineSizes(
        datasets=datasets,
        num_beams=int(val.sensor.num_beams),
        scans_per_epoch=int(net.training.scans_per_epoch),
        pose_cell_size=float(net.grid.cell_size),
        heading_bins=int(net.grid.heading_bins),
        features=int(net.net.features),
        beam_lut=(
            (float(beam[0].beam_lut_resolution), int(beam[0].beam_lut_angles)) if beam else None
        ),
    )


@stage_main("maps")
def main(cfg: DictConfig) -> None:
    out_dir = Path(cfg.out_dir)
    map_cfg = to_dict(cfg.map)
    label = map_label(map_cfg)
    checks = cfg.checks
    with timed_stage(f"maps_{cfg.map.name}", cfg.timing_dir):
        shape = planned_shape(map_cfg)
        estimate = None
        if shape is not None:
            sizes = pipeline_sizes(str(cfg.map.name), str(checks.profile))
            estimate = estimate_memory(*shape, sizes)
            check_memory(estimate, label, float(checks.memory_budget))
        grid = build_map(map_cfg)
        components = check_map(
            grid, label, map_cfg.get("source") == "file", float(checks.max_occupied_share)
        )
        with atomic_dir(out_dir) as tmp:
            save_map(grid, tmp / "map.yaml")
            render_map_preview(grid, tmp / "preview.png")
    shares = cell_shares(grid)
    memory = (
        f"; estimated peak {format_bytes(estimate.need)} ({estimate.peak_stage}, profile "
        f"{checks.profile}) of {format_bytes(physical_memory())}"
        if estimate is not None
        else ""
    )
    print(
        f"maps: {label}: {grid.width} x {grid.height} cells at {grid.resolution:g} m, free "
        f"{shares['free']:.1%}, occupied {shares['occupied']:.1%}, unknown "
        f"{shares['unknown']:.1%}, {len(components)} free-space component(s){memory}",
        file=sys.stderr,
    )


if __name__ == "__main__":
    main()
