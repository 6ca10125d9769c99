"""`evaluate` stage: Table 2 (paper §4.4), modern and global-localization metrics for every
localizer on every trajectory of the pipeline's maps (params.yaml `maps`) and real logs
(`real_logs`); the look-alike stretches of each map's evaluation runs; then, per map and log,
the figures over its evaluation seeds (success rates with Wilson intervals, steps to converge
and to recover, re-losses, false convergences, the rates where the scans can tell); and,
per real log, run and odometry source, the compared localizers over filter seeds
(localize_seeds stage)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml
from omegaconf import DictConfig

from scanloc.evaluate.look_alikes import LookAlikeParams, look_alikes_json, map_look_alikes
from scanloc.evaluate.seeds import evaluate_filter_seeds, global_localization
from scanloc.evaluate.table2 import evaluate_runs, nested_json
from scanloc.io import atomic_path
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


def pipeline_bags(params_path: Path = Path("params.yaml")) -> list[str]:
    """The bag names of params.yaml `bags` (none when the field is absent or empty)."""
    bags = yaml.safe_load(params_path.read_text()).get("bags") or {}
    if not isinstance(bags, dict):
        raise ValueError(f"{params_path}: field 'bags': expected a mapping of bag entries")
    return list(bags)


def maps_look_alikes(cfg: DictConfig, sets: Mapping[str, Sequence[str]]) -> dict[str, Any]:
    """{map: look-alike figures of its evaluation runs} (evaluate/look_alikes.py)."""
    params = LookAlikeParams.from_config(
        dict(cfg.look_alikes), "conf/evaluate.yaml: field 'look_alikes'"
    )
    root = Path(cfg.trajectory_root)
    return {
        name: map_look_alikes(
            Path(cfg.map_root) / name / "map.yaml", {r: root / r for r in runs}, params
        )
        for name, runs in sets.items()
    }


@stage_main("evaluate")
def main(cfg: DictConfig) -> None:
    with timed_stage("evaluate", cfg.timing_dir):
        maps, logs = pipeline_maps(), pipeline_real_logs()
        names = [f"{m}_{run}" for m in maps for run in cfg.runs]
        names += [f"{log}_{run}" for log in logs for run in cfg.real_runs]
        names += [f"{bag}_real" for bag in pipeline_bags()]  # a bag is one real run
        metrics = evaluate_runs(
            names,
            Path(cfg.trajectory_root),
            [Path(p) for p in cfg.localize_roots],
            Path(cfg.metrics_path),
            Path(cfg.table2_dir),
        )
        sets = {m: [f"{m}_{run}" for run in cfg.seed_runs] for m in maps}
        sets |= {log: [f"{log}_{run}" for run in cfg.real_seed_runs] for log in logs}
        look_alikes = maps_look_alikes(cfg, {m: sets[m] for m in maps})
        with atomic_path(Path(cfg.look_alikes_path)) as tmp:
            tmp.write_text(look_alikes_json(look_alikes), encoding="utf-8")
        ambiguous = {
            run: [bool(s["ambiguous"]) for s in stretches]
            for doc in look_alikes.values()
            for run, stretches in doc["runs"].items()
        }
        figures = global_localization(metrics, sets, int(cfg.converge_within_steps), ambiguous)
        with atomic_path(Path(cfg.global_metrics_path)) as tmp:
            tmp.write_text(nested_json(figures), encoding="utf-8")
        real_seeds = {
            f"{log}_{run}": {
                odometry: evaluate_filter_seeds(
                    Path(cfg.trajectory_root) / f"{log}_{run}",
                    Path(cfg.localize_seeds_root) / f"{log}_{run}_{odometry}",
                )
                for odometry in cfg.seed_study.odometry
            }
            for log in logs
            for run in cfg.seed_study.runs
        }
        with atomic_path(Path(cfg.real_seeds_path)) as tmp:
            tmp.write_text(nested_json(real_seeds), encoding="utf-8")


if __name__ == "__main__":
    main()
