"""`scans` stage: simulate one dataset of laser scans at poses drawn over a map's free space."""

from __future__ import annotations

from omegaconf import DictConfig

from scanloc.data.scan_dataset import generate_scan_dataset
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.stages.group_files import load_group_files
from scanloc.world.map_server import load_map


@stage_main("scans")
def main(cfg: DictConfig) -> None:
    load_group_files(cfg)
    dataset = cfg.dataset
    with timed_stage(f"scans_{dataset.name}", cfg.timing_dir):
        generate_scan_dataset(
            cfg.out_dir,
            grid=load_map(cfg.map_yaml),
            spec=laser_spec_from_config(to_dict(cfg.sensor)),
            noise_cfg=to_dict(cfg.noise),
            num_samples=dataset.num_samples,
            seed=dataset.seed,
            clearance_radius=dataset.clearance_radius,
            val_fraction=dataset.val_fraction,
            map_name=dataset.map,
            mode=cfg.sensor.mode,
            unknown_blocks=cfg.sensor.unknown_blocks,
        )


if __name__ == "__main__":
    main()
