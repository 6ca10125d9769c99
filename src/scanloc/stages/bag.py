"""`bag` stage (beyond the paper): a ROS bag of a real robot as a scanloc run, and its map, for
the real-log stages (see conf/bag.yaml; scanloc.bags.read does the reading). With `map_yaml`
the map is copied and the whole bag is the run; without it, a bag with truth is split as a real
log is (scanloc.bags.truth_map): its mapping part builds the map, its evaluation part is the run.

The sensor is a conf/sensor file or, with `sensor=auto` (conf/sensor/auto.yaml, a marker), the
bag's own LaserScans' (scanloc.bags.describe); either way it goes to data/maps/<name>/sensor.yaml,
so that the later stages load the laser the run was read with (`~sensor
+sensor_file=data/maps/<name>/sensor.yaml`, as the real logs' stages do).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import yaml
from hydra import compose
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from scanloc.bags.describe import sensor_yaml
from scanloc.bags.layout import layout_from_config
from scanloc.bags.read import BagRunOptions, read_bag_run
from scanloc.bags.truth_map import SplitSettings, map_from_truth
from scanloc.io import atomic_dir
from scanloc.real.log_mapping import save_log_map
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.sites import check_listed, load_runs, run_part
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.stages.site_budget import check_site
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
        pairing_tolerance_s=(
            None if cfg.pairing_tolerance_s is None else float(cfg.pairing_tolerance_s)
        ),
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


def sensor_file_text(cfg: DictConfig, sensor: dict[str, Any], meta: dict[str, Any]) -> str:
    """data/maps/<name>/sensor.yaml: the auto sensor with describe's comments, or the named
    conf/sensor file's fields."""
    if is_auto(cfg):
        return sensor_yaml(sensor, cfg.bag, str(cfg.topics.scan), int(meta["bag_scans"]))
    return yaml.safe_dump(sensor, sort_keys=False)


def is_auto(cfg: DictConfig) -> bool:
    """`sensor=auto`: conf/sensor/auto.yaml's marker."""
    return bool(cfg.sensor.get("auto", False))


@stage_main("bag")
def main(cfg: DictConfig) -> None:
    check_listed(str(cfg.name))
    with timed_stage(f"bag_{cfg.name}", cfg.timing_dir):
        given_map = bool(cfg.map_yaml)
        if not given_map and not (cfg.truth_topic or cfg.truth_csv):
            raise no_map_error(cfg)
        spec = None if is_auto(cfg) else laser_spec_from_config(to_dict(cfg.sensor))
        grid = load_map(cfg.map_yaml) if given_map else None
        traj, ranges, meta = read_bag_run(cfg.bag, spec, bag_options(cfg))
        sensor = meta["sensor"] if spec is None else to_dict(cfg.sensor)
        spec = laser_spec_from_config(sensor)
        if not given_map:
            if not meta["has_truth"]:
                raise no_map_error(cfg)
            built = map_from_truth(str(cfg.bag), traj, ranges, meta, spec, split_settings(cfg))
            grid, traj, ranges, meta = built.grid, built.run, built.ranges, meta | built.meta
        training = check_site(
            f"bag {cfg.name} ({cfg.bag})", grid, str(cfg.name), str(cfg.profile.name),
            to_dict(compose("maps").checks), True, spec.num_beams,
        )  # fmt: skip
        print(f"bag: {cfg.name}: {training}", file=sys.stderr)
        meta |= {"name": f"{cfg.name}_real", "map": str(cfg.name), "sensor": sensor}
        meta["part"] = run_part(load_runs(), "bag", "real")
        choice = HydraConfig.get().runtime.choices.get("sensor")
        meta.setdefault("sensor_source", f"conf/sensor/{choice}.yaml")
        with atomic_dir(cfg.map_dir) as tmp:
            if given_map:
                save_map(grid, Path(tmp) / "map.yaml")
            else:
                save_log_map(grid, Path(tmp) / "map.yaml", Path(tmp) / "preview.png")
            (Path(tmp) / "sensor.yaml").write_text(sensor_file_text(cfg, sensor, meta))
        with atomic_dir(cfg.out_dir) as tmp:
            save_trajectory(traj, tmp, ranges, meta, grid)


if __name__ == "__main__":
    main()
