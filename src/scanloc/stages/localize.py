"""`localize` and `localize_cnn` stages (paper §4.4): localizers along one trajectory, one row
per step each; a localizer with ranked hypotheses also writes them (<name>_hypotheses.npz)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from scanloc.io import atomic_path, write_json, write_npz
from scanloc.localize.kinds import LocalizeInputs, run_localizer
from scanloc.progress import steps
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.trajectory.format import load_trajectory


def localize_all(cfg: DictConfig) -> dict[str, Any]:
    """Run cfg.localizers (or just cfg.only, or the single cfg.localizer) on the trajectory;
    write each table; return the timing figures per localizer."""
    traj, ranges = load_trajectory(cfg.trajectory_dir)
    inputs = LocalizeInputs(
        traj, ranges, Path(cfg.map_yaml), laser_spec_from_config(to_dict(cfg.sensor))
    )
    localizers = cfg.localizers
    if cfg.get("localizer") is not None:
        localizers = {str(cfg.localizer.name): cfg.localizer}
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
        if localizer.get("name") != name:
            raise ValueError(
                f"conf/localizer: the config under '{name}' is named {localizer.get('name')!r}"
            )
        run = run_localizer(localizer, inputs)
        with atomic_path(out_dir / f"{name}.csv") as tmp:
            run.table.to_csv(tmp, index=False, float_format="%.9g")
        if run.hypotheses is not None:
            write_npz(out_dir / f"{name}_hypotheses.npz", run.hypotheses)
        timings[name] = run.timing()
    return timings


def run_stage(cfg: DictConfig, stage: str) -> None:
    with timed_stage(f"{stage}_{cfg.trajectory}", cfg.timing_dir):
        timings = localize_all(cfg)
        write_json(Path(cfg.timing_path), timings)


@stage_main("localize")
def main(cfg: DictConfig) -> None:
    run_stage(cfg, "localize")


if __name__ == "__main__":
    main()
