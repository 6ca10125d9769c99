"""`localize_seeds` stage: the compared localizers (`compared`) over several filter seeds on
one run with one odometry source (conf/localize_seeds.yaml). The localizers are composed
exactly as the localize stage composes them (conf/localizer/, with this stage's overrides); a
seeded one (a particle filter) runs once per seed, a deterministic one once. Each table goes
to <out_dir>/s<seed>/<name>.csv; the folder is replaced whole, never left half-written."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from scanloc.io import atomic_dir, write_json
from scanloc.localize.kinds import is_seeded, run_localizer, with_seed
from scanloc.progress import steps
from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.stages.group_files import load_group_files
from scanloc.stages.localize import localize_inputs, localizers_to_run


def seed_runs(cfg: DictConfig, localizers: dict[str, dict[str, Any]]) -> list[tuple[str, int]]:
    """(name, seed) of every run: each seed for a seeded localizer, the first for the others."""
    seeds = [int(s) for s in cfg.filter_seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValueError(
            f"conf/localize_seeds.yaml: field 'filter_seeds': expected distinct seeds, got {seeds}"
        )
    return [
        (name, seed)
        for name, localizer in localizers.items()
        for seed in (seeds if is_seeded(localizer) else seeds[:1])
    ]


@stage_main("localize_seeds")
def main(cfg: DictConfig) -> None:
    load_group_files(cfg)
    overrides = list(HydraConfig.get().overrides.task)
    with timed_stage(f"localize_seeds_{cfg.trajectory}_{cfg.odometry}", cfg.timing_dir):
        composed = localizers_to_run(cfg, "localize", overrides, config_name="localize_seeds")
        missing = [n for n in cfg.compared if n not in composed]
        if missing:
            raise ValueError(
                f"conf/localize_seeds.yaml: field 'compared': {missing} are not localizers "
                f"of the localize stage ({sorted(composed)})"
            )
        localizers = {str(n): to_dict(composed[n]) for n in cfg.compared}
        inputs = localize_inputs(cfg)
        timings: dict[str, dict[str, Any]] = {}
        with atomic_dir(cfg.out_dir) as tmp:
            for name, seed in steps(seed_runs(cfg, localizers), f"seeds {cfg.trajectory}"):
                run = run_localizer(with_seed(localizers[name], seed), inputs)
                (tmp / f"s{seed}").mkdir(exist_ok=True)
                run.table.to_csv(tmp / f"s{seed}" / f"{name}.csv", index=False, float_format="%.9g")
                timings.setdefault(name, {})[f"s{seed}"] = run.timing()
        write_json(Path(cfg.timing_path), timings)


if __name__ == "__main__":
    main()
