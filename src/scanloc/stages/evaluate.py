"""`evaluate` stage: Table 2 (paper §4.4), modern and global-localization metrics for every
localizer on every trajectory of the pipeline's maps (params.yaml `maps`) and real logs
(`real_logs`)."""

from __future__ import annotations

from pathlib import Path

import yaml
from omegaconf import DictConfig

from scanloc.evaluate.table2 import evaluate_runs
from scanloc.stages._app import stage_main, timed_stage


def pipeline_maps(params_path: Path = Path("params.yaml")) -> list[str]:
    """The map names of params.yaml `maps`, in their order."""
    maps = yaml.safe_load(params_path.read_text()).get("maps")
    if not isinstance(maps, dict) or not maps:
        raise ValueError(f"{params_path}: field 'maps': expected a mapping of map entries")
    return list(maps)


def pipeline_real_logs(params_path: Path = Path("params.yaml")) -> list[str]:
    """The log names of params.yaml `real_logs` (none when the field is absent or empty)."""
    logs = yaml.safe_load(params_path.read_text()).get("real_logs") or {}
    if not isinstance(logs, dict):
        raise ValueError(f"{params_path}: field 'real_logs': expected a mapping of log entries")
    return list(logs)


@stage_main("evaluate")
def main(cfg: DictConfig) -> None:
    with timed_stage("evaluate", cfg.timing_dir):
        names = [f"{m}_{run}" for m in pipeline_maps() for run in cfg.runs]
        names += [f"{log}_{run}" for log in pipeline_real_logs() for run in cfg.real_runs]
        evaluate_runs(
            names,
            Path(cfg.trajectory_root),
            [Path(p) for p in cfg.localize_roots],
            Path(cfg.localize_timing_dir),
            Path(cfg.metrics_path),
            Path(cfg.table2_dir),
        )


if __name__ == "__main__":
    main()
