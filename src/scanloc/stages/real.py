"""`real` stage (beyond the paper): a real CARMEN laser log as a map, a real run and its
simulated twin (see conf/real.yaml); the localize and evaluate stages then treat both runs
like any other trajectory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from scanloc.real.carmen import read_carmen_log
from scanloc.real.carmen_laser import clean_ranges, laser_spec
from scanloc.real.carmen_odometry import scan_odometry, wrap_logged_headings
from scanloc.real.log_mapping import build_map_from_log, save_log_map
from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.noise import noise_from_config
from scanloc.sensor.simulate import laser_spec_from_config, simulate_scans
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.trajectory.format import Trajectory, save_trajectory


def check_sensor(log_path: Path, from_log: LaserSpec, configured: LaserSpec) -> None:
    """The configured sensor must be the log's: same beams and angles (the rate and range
    limits are the config's choice)."""
    same = (
        from_log.num_beams == configured.num_beams
        and abs(from_log.angle_min - configured.angle_min) < 1e-9
        and abs(from_log.angle_max - configured.angle_max) < 1e-9
    )
    if not same:
        raise ValueError(
            f"{log_path}: the laser has {from_log.num_beams} beams from {from_log.angle_min:.6f} "
            f"to {from_log.angle_max:.6f} rad, the sensor config {configured.num_beams} from "
            f"{configured.angle_min:.6f} to {configured.angle_max:.6f}: choose the log's "
            "sensor (conf/sensor/carmen_<log>.yaml)"
        )


@stage_main("real")
def main(cfg: DictConfig) -> None:
    log_path = Path(cfg.log)
    with timed_stage(f"real_{cfg.log_name}", cfg.timing_dir):
        log = read_carmen_log(log_path)
        stream = {"front": log.front, "rear": log.rear}[str(cfg.stream)]
        if stream is None:
            raise ValueError(f"{log_path}: field 'stream': no {cfg.stream} laser in this log")
        spec = laser_spec_from_config(to_dict(cfg.sensor))
        check_sensor(log_path, laser_spec(stream, spec.range_max), spec)
        count = (
            stream.num_scans if cfg.max_scans is None else min(int(cfg.max_scans), stream.num_scans)
        )
        truth = np.ascontiguousarray(stream.laser_poses[:count], dtype=np.float64)
        truth[:, 2] = wrap_logged_headings(truth[:, 2])
        ranges = clean_ranges(stream.ranges[:count], spec.range_max, spec.no_return_value)
        # Mapping: a beam with no return says nothing reliable (glass, open doors, the sensor's
        # limit), and clearing free space along all 50 m of it would open the map to its border.
        hits = np.where(ranges < spec.range_max, ranges, np.float32(np.nan))
        grid = build_map_from_log(
            truth,
            hits,
            stream.beam_angles(),
            spec.range_max,
            resolution=float(cfg.mapping.resolution),
            margin=float(cfg.mapping.margin),
        )
        save_log_map(grid, Path(cfg.map_dir) / "map.yaml", Path(cfg.map_dir) / "preview.png")
        traj = Trajectory(
            times=stream.times[:count] - stream.times[0],
            truth=truth,
            odometry=scan_odometry(log, str(cfg.stream))[:count],
        )
        meta = {
            "map": cfg.log_name,
            "log": log_path.name,
            "stream": str(cfg.stream),
            "scans": count,
            "sensor": to_dict(cfg.sensor),
        }
        save_trajectory(traj, cfg.real_dir, ranges, meta | {"name": f"{cfg.log_name}_real"}, grid)
        simulated = simulate_scans(
            grid,
            spec,
            truth,
            noise_from_config(to_dict(cfg.noise)),
            rng_seed=int(cfg.seed),
            mode=cfg.sensor.mode,
            unknown_blocks=cfg.sensor.unknown_blocks,
        )
        sim_meta = meta | {"name": f"{cfg.log_name}_sim", "noise": to_dict(cfg.noise)}
        save_trajectory(traj, cfg.sim_dir, simulated, sim_meta, grid)


if __name__ == "__main__":
    main()
