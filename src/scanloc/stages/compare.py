"""`compare`: the offline comparison page of two or more DVC experiments or of the jobs of a
Hydra multirun (scanloc.report.compare); not a DVC stage, it only reads what runs left."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from scanloc.report.compare import Run, experiment_runs, multirun_runs, write_compare
from scanloc.stages._app import stage_main


def load_runs(cfg: DictConfig) -> tuple[list[Run], str]:
    """The runs the config names (exactly one of `experiments` and `multirun`) and a phrase
    saying where they come from."""
    experiments = [str(name) for name in cfg.experiments or []]
    if bool(experiments) == (cfg.multirun is not None):
        raise ValueError(
            "compare: give either experiments=[<name or revision>,...] (two or more) or "
            f"multirun=<folder>, not both or neither; got experiments={experiments}, "
            f"multirun={cfg.multirun}"
        )
    if cfg.multirun is not None:
        folder = Path(str(cfg.multirun))
        return multirun_runs(folder), f"the jobs of the Hydra multirun {folder}"
    repo = Path(str(cfg.repo))
    return experiment_runs(experiments, repo), f"DVC experiments of {repo.resolve().name}"


@stage_main("compare")
def main(cfg: DictConfig) -> None:
    runs, source = load_runs(cfg)
    out_dir = Path(cfg.out_dir)
    write_compare(runs, out_dir, source, str(cfg.trajectory), [str(n) for n in cfg.localizers])
    print(f"compare: wrote {out_dir / 'compare.html'} and {out_dir / 'compare.md'}")


if __name__ == "__main__":
    main()
