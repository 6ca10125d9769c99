"""`localize` and `localize_cnn` stages (paper §4.4): localizers along one trajectory, one row
per step each; a localizer with ranked hypotheses also writes them (<name>_hypotheses.npz).

A stage runs the localizers whose conf/localizer/<name>.yaml lists it under `stages`
(scanloc.localize.catalog), each composed by Hydra as a `localizer@localizers.<key>` entry of
the stage's config (<key>: the name, `_global_` written `-global-`: catalog.package_key), with
the stage's own overrides (map_name, sensor, ...), so that adding a localizer is adding one
yaml file. `++localizers.<key>.<section>.<field>=...` overrides a listed localizer's field;
`only=<name>` runs just one; `localizer=<config>` runs that config alone. `odometry=wheel|laser`
picks the run's odometry stream for every localizer; the laser's mounting on the robot comes
from the run's meta.json `laser_mount` (zero when absent).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from hydra import compose
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from scanloc.io import atomic_path, write_json, write_npz
from scanloc.localize.catalog import localizer_overrides
from scanloc.localize.kinds import LocalizeInputs, run_localizer
from scanloc.progress import steps
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.stages._app import conf_dir, stage_main, timed_stage, to_dict
from scanloc.stages.group_files import load_group_files
from scanloc.trajectory.format import Trajectory, load_trajectory


def localizers_to_run(
    cfg: DictConfig, stage: str, overrides: Sequence[str], config_name: str | None = None
) -> Mapping[str, DictConfig]:
    """The localizers this run runs, by name: the single `localizer` when one is chosen, else
    those conf/localizer lists for `stage`, composed by Hydra into the running stage's config
    (`config_name`, default: `stage`) with the run's `overrides`."""
    if cfg.get("localizer") is not None:
        return {str(cfg.localizer.meta.name): cfg.localizer}
    listed = localizer_overrides(stage, Path(conf_dir()) / "localizer")
    composed = compose(config_name=config_name or stage, overrides=[*overrides, *listed])
    composed = composed.localizers
    return {str(localizer.meta.name): localizer for localizer in composed.values()}


ODOMETRY_SOURCES = ("wheel", "laser")


def laser_mount(run_dir: Path) -> tuple[float, float, float]:
    """The laser's pose (x, y, θ) on the robot base from the run's meta.json `laser_mount`
    (real logs and bags carry it); zero when absent."""
    meta_path = run_dir / "meta.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    mount = meta.get("laser_mount")
    if mount is None:
        return (0.0, 0.0, 0.0)
    values = list(mount.values()) if isinstance(mount, dict) else mount
    try:
        x, y, theta = (float(v) for v in values)
    except (TypeError, ValueError):
        raise ValueError(
            f"{meta_path}: field 'laser_mount': expected [x, y, yaw] (m, m, rad), got {mount!r}"
        ) from None
    return (x, y, theta)


def select_odometry(traj: Trajectory, source: str, run_dir: Path) -> Trajectory:
    """The run with the odometry stream `source` names (wheel: odometry.npy; laser:
    laser_odometry.npy, scan-to-scan registration) as the odometry every localizer uses."""
    if source not in ODOMETRY_SOURCES:
        raise ValueError(
            f"conf/_localize_run.yaml: field 'odometry': expected one of {ODOMETRY_SOURCES}, "
            f"got {source!r}"
        )
    if source == "wheel":
        return traj
    if traj.laser_odometry is None:
        raise FileNotFoundError(
            f"{run_dir}: odometry=laser asks for laser_odometry.npy, which this run lacks "
            "(scanloc.trajectory.laser_odometry makes it)"
        )
    return replace(traj, odometry=traj.laser_odometry)


def localize_inputs(cfg: DictConfig) -> LocalizeInputs:
    """What the stage's localizers see: the run with its chosen odometry, its scans, the map,
    the laser and its mount."""
    run_dir = Path(cfg.trajectory_dir)
    traj, ranges = load_trajectory(run_dir)
    traj = select_odometry(traj, str(cfg.get("odometry", "wheel")), run_dir)
    return LocalizeInputs(
        traj,
        ranges,
        Path(cfg.map_yaml),
        laser_spec_from_config(to_dict(cfg.sensor)),
        laser_mount(run_dir),
    )


def localize_all(cfg: DictConfig, stage: str, overrides: Sequence[str]) -> dict[str, Any]:
    """Run the stage's localizers (or just cfg.only) on the trajectory; write each table;
    return the timing figures per localizer."""
    inputs = localize_inputs(cfg)
    localizers = localizers_to_run(cfg, stage, overrides)
    names = list(localizers) if cfg.only is None else [str(cfg.only)]
    unknown = [n for n in names if n not in localizers]
    if unknown:
        raise ValueError(
            f"only={unknown[0]}: not one of this stage's localizers {list(localizers)}"
        )
    out_dir = Path(cfg.out_dir)
    timings = {}
    for name in steps(names, f"localize {cfg.trajectory}"):
        localizer = to_dict(localizers[name])
        if localizer["meta"].get("name") != name:
            raise ValueError(
                f"conf/localizer/{name}.yaml: section 'meta': key 'name': expected {name!r}, "
                f"got {localizer['meta'].get('name')!r}"
            )
        run = run_localizer(localizer, inputs)
        with atomic_path(out_dir / f"{name}.csv") as tmp:
            run.table.to_csv(tmp, index=False, float_format="%.9g")
        if run.hypotheses is not None:
            write_npz(out_dir / f"{name}_hypotheses.npz", run.hypotheses)
        timings[name] = run.timing()
    return timings


def run_stage(cfg: DictConfig, stage: str, overrides: Sequence[str] | None = None) -> None:
    """The stage: localize, then write the timing figures. `overrides` are the run's
    command-line overrides (default: Hydra's record of them)."""
    load_group_files(cfg)
    if overrides is None:
        overrides = list(HydraConfig.get().overrides.task)
    with timed_stage(f"{stage}_{cfg.trajectory}", cfg.timing_dir):
        timings = localize_all(cfg, stage, overrides)
        write_json(Path(cfg.timing_path), timings)


@stage_main("localize")
def main(cfg: DictConfig) -> None:
    run_stage(cfg, "localize")


if __name__ == "__main__":
    main()
