"""`real` stage (beyond the paper): a real CARMEN laser log as a map built from its mapping
part, runs on its evaluation part (real scans, their simulated twin, a kidnap run) and the
mapping part as a tuning run (see conf/real.yaml); the localize and evaluate stages then treat
every run like any other trajectory.

Frames: each run's truth and odometry are the robot base's; the laser sits at `laser_mount`
(meta.json {x, y, yaw}: the laser's pose in the base frame, as the bag reader writes it;
scanloc.real.log_sensor) and its pose is base ⊕ mount. The sensor is read from the log (or
the override the `real_logs` entry names) and written with the noise to
data/maps/<log>/{sensor,noise}.yaml, which later stages load with `~sensor ~noise
+sensor_file=data/maps/<log>/sensor.yaml +noise_file=data/maps/<log>/noise.yaml`
(scanloc.stages.group_files). The laser's corruptions, measured on the mapping part against
the map (scanloc.real.residuals), go to data/maps/<log>/corruptions.yaml (the learned
localizer's training stream loads them with `+corruptions_file=`), the residual histograms to
data/maps/<log>/residuals.json.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import yaml
from hydra import compose
from omegaconf import DictConfig

from scanloc.data.scan_dataset import save_scan_dataset
from scanloc.io import write_json
from scanloc.real.carmen import CarmenLog, read_carmen_log
from scanloc.real.carmen_laser import clean_ranges
from scanloc.real.carmen_odometry import base_poses, scan_odometry, wrap_logged_headings
from scanloc.real.log_mapping import build_map_from_log, save_log_map
from scanloc.real.log_sensor import (
    log_stream,
    no_return_marker,
    resolve_mount,
    sensor_from_log,
)
from scanloc.real.residuals import laser_residuals
from scanloc.real.split import (
    Split,
    coverage,
    kidnap_segments,
    segment_run,
    segments_of,
    split_log,
    tune_holdout,
)
from scanloc.sensor.noise import noise_from_config
from scanloc.sensor.simulate import laser_spec_from_config, simulate_scans
from scanloc.sites import check_listed, load_runs, run_part
from scanloc.stages._app import conf_dir, stage_main, timed_stage, to_dict
from scanloc.stages.site_budget import check_site
from scanloc.trajectory.format import Trajectory, save_trajectory
from scanloc.trajectory.laser_odometry import drift, increments, laser_odometry


def chosen_sensor(cfg: DictConfig, from_log: dict) -> dict:
    """The log's sensor, or conf/sensor/<sensor_override> (a `real_logs` entry's overrides),
    which must have the log's beams and angles (its rate and range limits are its choice)."""
    name = cfg.sensor_override
    if name is None:
        return from_log
    path = Path(conf_dir()) / "sensor" / f"{name}.yaml"
    override = yaml.safe_load(path.read_text())
    for key in ("num_beams", "angle_min", "angle_max"):
        if abs(float(override[key]) - float(from_log[key])) > 1e-9:
            raise ValueError(
                f"{path}: field '{key}': expected the log's {from_log[key]} ({cfg.log}), "
                f"got {override[key]}"
            )
    return override


def write_log_conf(map_dir: Path, sensor: dict, noise: dict, corruptions: dict) -> None:
    """data/maps/<log>/{sensor,noise,corruptions}.yaml: what later stages load (module doc)."""
    map_dir.mkdir(parents=True, exist_ok=True)
    for group, values in (("sensor", sensor), ("noise", noise), ("corruptions", corruptions)):
        (map_dir / f"{group}.yaml").write_text(yaml.safe_dump(values))


def mapping_mount(
    cfg: DictConfig, log: CarmenLog, laser_truth: np.ndarray, mapping: np.ndarray
) -> tuple[np.ndarray, dict]:
    """The laser's mount, checked or estimated on the mapping part's own steps (none across
    its cut, none of the evaluation part)."""
    count = len(laser_truth)
    within = np.isin(np.arange(count - 1), mapping) & np.isin(np.arange(1, count), mapping)
    flat = scan_odometry(log, str(cfg.stream))[:count]  # as if the mount were 0
    steps = increments(laser_truth)[within], increments(flat)[within]
    return resolve_mount(log, str(cfg.stream), *steps)


def split_metrics(
    split: Split, count: int, covered: dict, real: Trajectory, fallbacks: int
) -> dict:
    """reports/metrics/real_<log>.json (also in every run's meta.json)."""
    out = {
        "split": {
            "mode": split.mode,
            "optimistic": split.optimistic,
            "map_scans": len(split.mapping),
            "evaluation_scans": len(split.evaluation),
            "map_share": round(len(split.mapping) / count, 4),
            "evaluation_share": round(len(split.evaluation) / count, 4),
        },
        "coverage": {k: v for k, v in covered.items() if k != "uncovered_steps"},
        "odometry": {
            "wheel": drift(real.odometry, real.truth),
            "laser": drift(real.laser_odometry, real.truth)
            | {"fallback_pairs_whole_log": fallbacks},
        },
    }
    if split.optimistic:
        out["split"]["note"] = "optimistic: the map holds every evaluated scan"
    return out


def save_mapping_scans(
    out_dir: Path,
    ranges: np.ndarray,
    laser_truth: np.ndarray,
    mapping: np.ndarray,
    tune_heldout: np.ndarray,
    meta: dict,
) -> None:
    """The mapping part's real scans with their laser poses as a scan dataset (data/scans/
    <log>_mapping), for the learned localizer's training stream: the tune map's scans are its
    training split, the tune hold-out's its validation split (never trained on: the scans its
    settings are chosen on). No scan of the evaluation part is in it."""
    is_val = np.isin(mapping, tune_heldout)
    save_scan_dataset(
        out_dir,
        ranges[mapping],
        laser_truth[mapping],
        is_val,
        meta
        | {
            "source": "real scans of the log's mapping part (validation: the tune hold-out)",
            "poses_frame": "laser (the corrected poses of the log)",
            "log_scans": segments_of(mapping),
        },
    )


@stage_main("real")
def main(cfg: DictConfig) -> None:
    log_path = Path(cfg.log)
    check_listed(str(cfg.log_name))
    with timed_stage(f"real_{cfg.log_name}", cfg.timing_dir):
        log = read_carmen_log(log_path)
        stream = log_stream(log, str(cfg.stream))
        from_log = sensor_from_log(stream, to_dict(cfg.sensor_defaults))
        sensor, noise = chosen_sensor(cfg, from_log), to_dict(cfg.noise)
        spec = laser_spec_from_config(sensor)
        count = (
            stream.num_scans if cfg.max_scans is None else min(int(cfg.max_scans), stream.num_scans)
        )
        laser_truth = np.ascontiguousarray(stream.laser_poses[:count], dtype=np.float64)
        laser_truth[:, 2] = wrap_logged_headings(laser_truth[:, 2])
        ranges = clean_ranges(stream.ranges[:count], spec.range_max, spec.no_return_value)
        angles = stream.beam_angles()
        split = split_log(
            count,
            str(cfg.split.mode),
            float(cfg.split.map_share),
            tuple(cfg.split.window),
            cfg.split.max_evaluation_scans,
        )
        m, e = split.mapping, split.evaluation
        # Mapping: a beam with no return says nothing reliable (glass, open doors, the sensor's
        # limit), and clearing free space along all of it would open the map to its border.
        hits = np.where(ranges < spec.range_max, ranges, np.float32(np.nan))
        grid = build_map_from_log(
            laser_truth[m], hits[m], angles, spec.range_max,
            resolution=float(cfg.mapping.resolution), margin=float(cfg.mapping.margin),
        )  # fmt: skip
        training = check_site(
            f"real log {cfg.log_name} ({log_path})", grid, str(cfg.log_name), str(cfg.profile.name),
            to_dict(compose("maps").checks), True, spec.num_beams,
        )  # fmt: skip
        print(
            f"real: {cfg.log_name}: {grid.width} x {grid.height} map cells; {training}",
            file=sys.stderr,
        )
        mount, mount_info = mapping_mount(cfg, log, laser_truth, m)
        truth = base_poses(laser_truth, mount)
        wheel = scan_odometry(log, str(cfg.stream), mount)[:count]
        laser, fallbacks = laser_odometry(ranges, angles, spec.range_max, wheel, mount)
        save_log_map(grid, Path(cfg.map_dir) / "map.yaml", Path(cfg.map_dir) / "preview.png")
        simulator_args = {
            "spec": spec,
            "mode": sensor["mode"],
            "unknown_blocks": sensor["unknown_blocks"],
        }
        corruptions, residuals = laser_residuals(
            grid, simulator_args, noise_from_config(noise), laser_truth[m], ranges[m],
            int(cfg.seed),
        )  # fmt: skip
        write_log_conf(Path(cfg.map_dir), sensor, noise, corruptions.to_dict())
        write_json(Path(cfg.map_dir) / "residuals.json", residuals)
        segments = {
            "real": segments_of(e),
            "tune": segments_of(m),
            "kidnap": kidnap_segments(e, int(cfg.kidnap_cuts)),
        }
        steps = increments(wheel), increments(laser)
        runs = {
            name: segment_run(seg, stream.times[:count], truth, *steps)
            for name, seg in segments.items()
        }
        covered = coverage(grid, laser_truth[e], ranges[e], angles, spec.range_max)
        uncovered = e[covered["uncovered_steps"]]  # as log scan indices
        metrics = split_metrics(split, count, covered, runs["real"][0], fallbacks)
        metrics["laser_residuals"] = residuals["measured"] | {"fitted": corruptions.to_dict()}
        # How the log's beam-angle PARAMs were read (degrees or radians): the stage's report,
        # not the runs' (their meta.json carries what the later stages use).
        angle_params = {"laser_angle_params": log.angle_params} if log.angle_params else {}
        write_json(Path(cfg.metrics_file), metrics | angle_params)
        meta = {
            "map": cfg.log_name,
            "log": log_path.name,
            "stream": str(cfg.stream),
            "scans": count,
            "sensor": sensor,
            "sensor_source": "read from the log (scanloc.real.log_sensor)"
            if sensor is from_log
            else "conf/sensor override named by the real_logs entry",
            "no_return_marker_m": no_return_marker(stream.ranges),
            # as the bag reader / writer (scanloc.bags) keep it: base_link → laser
            "laser_mount": dict(zip(("x", "y", "yaw"), mount.round(6).tolist(), strict=True)),
            "laser_mount_frame": "laser pose in the robot base frame; laser = base ⊕ mount",
            "laser_mount_info": mount_info,
            "truth_frame": "robot base (laser pose ⊕ mount⁻¹)",
            **metrics,
        }
        run_lists = load_runs()
        for name, (traj, index) in runs.items():
            run_meta = meta | {
                "name": f"{cfg.log_name}_{name}",
                "part": run_part(run_lists, "log", name),
                "log_scans": [int(index[0]), int(index[-1])],
                "uncovered_steps": np.flatnonzero(np.isin(index, uncovered)).tolist(),
            }
            if name == "tune":
                run_meta |= {"part_note": "the mapping part (for choosing settings; never scored)"}
                del run_meta["uncovered_steps"]  # in the map by construction
            save_trajectory(traj, cfg[f"{name}_dir"], ranges[index], run_meta, grid)
        real, index = runs["real"]
        simulated = simulate_scans(
            grid, spec, laser_truth[index], noise_from_config(noise),
            rng_seed=int(cfg.seed), mode=sensor["mode"], unknown_blocks=sensor["unknown_blocks"],
        )  # fmt: skip
        sim_laser, sim_fallbacks = laser_odometry(
            simulated, angles, spec.range_max, real.odometry, mount
        )
        sim = dataclasses.replace(real, laser_odometry=sim_laser)
        sim_odometry = metrics["odometry"] | {
            "laser": drift(sim_laser, real.truth) | {"fallback_pairs": sim_fallbacks}
        }
        sim_meta = meta | {
            "name": f"{cfg.log_name}_sim",
            "part": run_part(run_lists, "log", "sim"),
            "noise": noise,
            "odometry": sim_odometry,
            "log_scans": [int(index[0]), int(index[-1])],
            "uncovered_steps": np.flatnonzero(np.isin(index, uncovered)).tolist(),
        }
        save_trajectory(sim, cfg.sim_dir, simulated, sim_meta, grid)
        tune_map_scans, tune_heldout = tune_holdout(m, tuple(cfg.split.window))
        tune_grid = build_map_from_log(
            laser_truth[tune_map_scans], hits[tune_map_scans], angles, spec.range_max,
            resolution=float(cfg.mapping.resolution), margin=float(cfg.mapping.margin),
        )  # fmt: skip
        heldout_dir = Path(cfg.tune_heldout_dir)
        save_log_map(
            tune_grid, heldout_dir / "map" / "map.yaml", heldout_dir / "map" / "preview.png"
        )
        traj, index = segment_run(segments_of(tune_heldout), stream.times[:count], truth, *steps)
        tune_cover = coverage(
            tune_grid, laser_truth[tune_heldout], ranges[tune_heldout], angles, spec.range_max
        )
        heldout_meta = meta | {
            "name": f"{cfg.log_name}_tune_heldout",
            "part": run_part(run_lists, "log", "tune_heldout"),
            "part_note": (
                "the middle of each mapping stretch, localized in map/ built from the rest of the "
                "mapping part (for choosing settings where the map is incomplete; never scored)"
            ),
            "tune_map_scans": segments_of(tune_map_scans),
            "log_scans": segments_of(index),
            "coverage": {k: v for k, v in tune_cover.items() if k != "uncovered_steps"},
            "uncovered_steps": tune_cover["uncovered_steps"],
        }
        save_trajectory(traj, heldout_dir, ranges[index], heldout_meta, tune_grid)
        save_mapping_scans(
            Path(cfg.mapping_scans_dir), ranges, laser_truth, m, tune_heldout,
            meta | {"name": f"{cfg.log_name}_mapping", "seed": int(cfg.seed)},
        )  # fmt: skip


if __name__ == "__main__":
    main()
