"""`bag` stage (beyond the paper): a ROS bag of a real robot as a scanloc run, and its map, for
the real-log stages (see conf/bag.yaml; scanloc.bags.read does the reading)."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from scanloc.bags.layout import layout_from_config
from scanloc.bags.read import BagRunOptions, read_bag_run
from scanloc.io import atomic_dir
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.trajectory.format import save_trajectory
from scanloc.world.map_server import load_map, save_map


def bag_options(cfg: DictConfig) -> BagRunOptions:
    """The reading options of a bag stage config."""
    layout = layout_from_config(
        to_dict(cfg.topics) | to_dict(cfg.frames) | {"odom_source": str(cfg.odom_source)}
    )
    return BagRunOptions(
        layout=layout,
        truth_topic=cfg.truth_topic,
        truth_csv=cfg.truth_csv,
        csv_time=str(cfg.csv_time),
        pairing_tolerance_s=float(cfg.pairing_tolerance_s),
        max_scans=cfg.max_scans,
    )


@stage_main("bag")
def main(cfg: DictConfig) -> None:
    with timed_stage(f"bag_{cfg.name}", cfg.timing_dir):
        spec = laser_spec_from_config(to_dict(cfg.sensor))
        grid = None if cfg.map_yaml is None else load_map(cfg.map_yaml)
        traj, ranges, meta = read_bag_run(cfg.bag, spec, bag_options(cfg))
        meta |= {"name": f"{cfg.name}_real", "map": str(cfg.name), "sensor": to_dict(cfg.sensor)}
        with atomic_dir(cfg.out_dir) as tmp:
            save_trajectory(traj, tmp, ranges, meta, grid)
        if grid is not None:
            with atomic_dir(cfg.map_dir) as tmp:
                save_map(grid, Path(tmp) / "map.yaml")


if __name__ == "__main__":
    main()
