"""`bag` stage (beyond the paper): a ROS bag of a real robot as a scanloc run, and its map, for
the real-log stages (see conf/bag.yaml; scanloc.bags.read does the reading). With `map_yaml`
the map is copied and the whole bag is the run; without it, a bag with truth is split as a real
log is (scanloc.bags.truth_map): its mapping part builds the map, its evaluation part is the run.
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from scanloc.bags.layout import layout_from_config
from scanloc.bags.read import BagRunOptions, read_bag_run
from scanloc.bags.truth_map import SplitSettings, map_from_truth
from scanloc.io import atomic_dir
from scanloc.real.log_mapping import save_log_map
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


def split_settings(cfg: DictConfig) -> SplitSettings:
    """conf/bag.yaml `split` and `mapping`: how a map is built from a bag with truth."""
    return SplitSettings(
        mode=str(cfg.split.mode),
        window=tuple(float(f) for f in cfg.split.window),
        map_share=float(cfg.split.map_share),
        max_evaluation_scans=cfg.split.max_evaluation_scans,
        resolution=float(cfg.mapping.resolution),
        margin=float(cfg.mapping.margin),
    )


def no_map_error(cfg: DictConfig) -> ValueError:
    return ValueError(
        f"bag {cfg.bag}: no map: expected conf/bag.yaml field 'map_yaml' (a map_server YAML) "
        "or ground truth to build the map from (field 'truth_topic' or 'truth_csv')"
    )


@stage_main("bag")
def main(cfg: DictConfig) -> None:
    with timed_stage(f"bag_{cfg.name}", cfg.timing_dir):
        given_map = bool(cfg.map_yaml)
        if not given_map and not (cfg.truth_topic or cfg.truth_csv):
            raise no_map_error(cfg)
        spec = laser_spec_from_config(to_dict(cfg.sensor))
        grid = load_map(cfg.map_yaml) if given_map else None
        traj, ranges, meta = read_bag_run(cfg.bag, spec, bag_options(cfg))
        if not given_map:
            if not meta["has_truth"]:
                raise no_map_error(cfg)
            built = map_from_truth(str(cfg.bag), traj, ranges, meta, spec, split_settings(cfg))
            grid, traj, ranges, meta = built.grid, built.run, built.ranges, meta | built.meta
        meta |= {"name": f"{cfg.name}_real", "map": str(cfg.name), "sensor": to_dict(cfg.sensor)}
        with atomic_dir(cfg.map_dir) as tmp:
            if given_map:
                save_map(grid, Path(tmp) / "map.yaml")
            else:
                save_log_map(grid, Path(tmp) / "map.yaml", Path(tmp) / "preview.png")
        with atomic_dir(cfg.out_dir) as tmp:
            save_trajectory(traj, tmp, ranges, meta, grid)


if __name__ == "__main__":
    main()
