"""`trajectory` stage (paper §4.4): drive a robot through a map (or kidnap it now and then),
record truth, odometry and a scan per step (same simulator and noise as the training scans)."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
from omegaconf import DictConfig

from scanloc.sensor.laser import LaserSpec
from scanloc.sensor.noise import noise_from_config
from scanloc.sensor.simulate import laser_spec_from_config, simulate_scans
from scanloc.sites import run_part
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.trajectory.drive import drive_trajectory
from scanloc.trajectory.format import Trajectory, save_trajectory
from scanloc.trajectory.laser_odometry import chain, drift, increments, laser_odometry
from scanloc.trajectory.odometry import OdometryNoise
from scanloc.world.map_server import load_map


def scan_matched_odometry(
    traj: Trajectory, ranges: np.ndarray, spec: LaserSpec
) -> tuple[np.ndarray, int]:
    """Laser odometry of a simulated run (scan-to-scan registration seeded with the wheel
    increments), and how many steps fell back to the wheel increment. Registered within each
    stretch between kidnaps; across a kidnap it adds no motion, as the wheels do not turn."""
    bounds = (0, *traj.kidnap_steps, len(traj.times))
    steps, fallbacks = [], 0
    for start, stop in itertools.pairwise(bounds):
        if steps:
            steps.append(np.zeros((1, 3)))
        stretch, failed = laser_odometry(
            ranges[start:stop], spec.beam_angles(), spec.range_max, traj.odometry[start:stop]
        )
        steps.append(increments(stretch))
        fallbacks += failed
    return chain(traj.odometry[0], np.concatenate(steps)), fallbacks


def odometry_drift(traj: Trajectory, fallbacks: int) -> dict:
    """Wheel and laser odometry against the truth, over the run's first stretch (up to the first
    kidnap: drift is measured along one contiguous path)."""
    stop = traj.kidnap_steps[0] if traj.kidnap_steps else len(traj.times)
    assert traj.laser_odometry is not None
    return {
        "wheel": drift(traj.odometry[:stop], traj.truth[:stop]),
        "laser": drift(traj.laser_odometry[:stop], traj.truth[:stop])
        | {"fallback_steps": fallbacks},
    }


@stage_main("trajectory")
def main(cfg: DictConfig) -> None:
    run = cfg.trajectory
    num_steps = int(run.num_steps)
    kidnaps = tuple(round(f * num_steps) for f in cfg.run.kidnap_at)
    with timed_stage(f"trajectory_{cfg.name}", cfg.timing_dir):
        grid = load_map(cfg.map_yaml)
        spec = laser_spec_from_config(to_dict(cfg.sensor))
        traj = drive_trajectory(
            grid,
            num_steps=num_steps,
            rate_hz=float(run.rate_hz),
            seed=int(run.seed),
            clearance=float(run.clearance),
            max_speed=float(run.max_speed),
            max_turn_rate=float(run.max_turn_rate),
            odometry_noise=OdometryNoise(**to_dict(run.odometry_noise)),
            kidnap_steps=kidnaps,
        )
        ranges = simulate_scans(
            grid,
            spec,
            traj.truth,
            noise_from_config(to_dict(cfg.noise)),
            rng_seed=int(run.seed) + 1,
            mode=cfg.sensor.mode,
            unknown_blocks=cfg.sensor.unknown_blocks,
        )
        laser, fallbacks = scan_matched_odometry(traj, ranges, spec)
        traj = dataclasses.replace(traj, laser_odometry=laser)
        meta = {
            "name": cfg.name,
            "map": cfg.map_name,
            "run": to_dict(cfg.run),
            "part": run_part(to_dict(cfg.runs), "map", str(cfg.run.get("name", cfg.run.kind))),
            "profile": cfg.profile.name,
            "trajectory": to_dict(run),
            "sensor": to_dict(cfg.sensor),
            "noise": to_dict(cfg.noise),
            "odometry": odometry_drift(traj, fallbacks),
        }
        save_trajectory(traj, cfg.out_dir, ranges=ranges, meta=meta, grid=grid)


if __name__ == "__main__":
    main()
