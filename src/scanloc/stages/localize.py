"""`localize` stage (paper §4.4): one localizer along a driven trajectory, one row per step."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from scanloc.io import atomic_path, write_json
from scanloc.localize.kinds import LocalizeInputs, run_localizer
from scanloc.localize.trajectory import load_trajectory
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.stages._app import stage_main, timed_stage, to_dict


@stage_main("localize")
def main(cfg: DictConfig) -> None:
    with timed_stage(f"localize_{cfg.localizer.name}"):
        traj, ranges = load_trajectory(cfg.trajectory_dir)
        inputs = LocalizeInputs(
            traj, ranges, Path(cfg.map_yaml), laser_spec_from_config(to_dict(cfg.sensor))
        )
        run = run_localizer(to_dict(cfg.localizer), inputs)
        with atomic_path(cfg.out_path) as tmp:
            run.table.to_csv(tmp, index=False, float_format="%.9g")
        write_json(Path(cfg.timing_path), run.timing())


if __name__ == "__main__":
    main()
