"""`evaluate` stage: Table 2 (paper §4.4), modern and global-localization metrics for every
localizer on every localized run of every site (`sites` on the command line, conf/seeds.yaml
`runs` per kind); the look-alike stretches of each simulated map's evaluation runs; then, per
site, the figures over its evaluation seeds (success rates with Wilson intervals, steps to
converge and to recover, re-losses, false convergences, the rates where the scans can tell);
and, per run over filter seeds and odometry source, the compared localizers' figures."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from scanloc.evaluate.look_alikes import LookAlikeParams, look_alikes_json, map_look_alikes
from scanloc.evaluate.seeds import evaluate_filter_seeds, global_localization
from scanloc.evaluate.table2 import evaluate_runs, nested_json
from scanloc.io import atomic_path
from scanloc.stages._app import stage_main, timed_stage


def maps_look_alikes(cfg: DictConfig, sets: Mapping[str, Sequence[str]]) -> dict[str, Any]:
    """{map: look-alike figures of its evaluation runs} (evaluate/look_alikes.py)."""
    options = {k: v for k, v in cfg.look_alikes.items() if k != "kinds"}
    params = LookAlikeParams.from_config(options, "conf/evaluate.yaml: field 'look_alikes'")
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
        sites: dict[str, str] = dict(cfg.sites or {})
        if not sites:  # dvc.yaml passes them; by hand: sites={name: kind, ...}
            raise ValueError(
                "conf/evaluate.yaml: field 'sites': expected {name: kind} of at least one site "
                "(dvc.yaml passes sites.yaml's `site_list`)"
            )
        runs = {site: cfg.runs[kind] for site, kind in sites.items()}
        names = [f"{site}_{run}" for site, kind in runs.items() for run in kind.localized]
        metrics = evaluate_runs(
            names,
            Path(cfg.trajectory_root),
            [Path(p) for p in cfg.localize_roots],
            Path(cfg.metrics_path),
            Path(cfg.table2_dir),
        )
        sets = {
            site: [f"{site}_{run}" for run in kind.scored_over_seeds]
            for site, kind in runs.items()
            if kind.scored_over_seeds
        }
        exact = [site for site in sets if sites[site] in cfg.look_alikes.kinds]
        look_alikes = maps_look_alikes(cfg, {site: sets[site] for site in exact})
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
            f"{site}_{run}": {
                odometry: evaluate_filter_seeds(
                    Path(cfg.trajectory_root) / f"{site}_{run}",
                    Path(cfg.localize_seeds_root) / f"{site}_{run}_{odometry}",
                )
                for odometry in cfg.odometry
            }
            for site, kind in runs.items()
            for run in kind.over_filter_seeds
        }
        with atomic_path(Path(cfg.real_seeds_path)) as tmp:
            tmp.write_text(nested_json(real_seeds), encoding="utf-8")


if __name__ == "__main__":
    main()
