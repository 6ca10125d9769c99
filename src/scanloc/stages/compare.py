"""`compare`: the offline comparison page of two or more DVC experiments or of the jobs of a
Hydra multirun (scanloc.report.compare); not a DVC stage, it only reads what runs left. It also
prints the changed parameters and the headline metrics as plain tables, one row per parameter
or metric and one column per run, so that they fit a terminal (docs/experiments.md)."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from scanloc.report.compare import write_compare
from scanloc.report.compare_runs import ComparedRun, experiment_runs, multirun_runs
from scanloc.report.render.document import Table
from scanloc.stages._app import stage_main


def load_runs(cfg: DictConfig) -> tuple[list[ComparedRun], str]:
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


def text_table(table: Table) -> str:
    """A table as aligned plain-text columns (no borders: narrow terminals)."""
    rows = [table.header, *table.rows]
    widths = [max(len(row[i]) for row in rows) for i in range(len(table.header))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)) for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(line.rstrip() for line in lines)


@stage_main("compare")
def main(cfg: DictConfig) -> None:
    runs, source = load_runs(cfg)
    out_dir = Path(cfg.out_dir)
    sections = write_compare(
        runs, out_dir, source, str(cfg.trajectory), [str(n) for n in cfg.localizers]
    )
    for section in sections[:2]:  # the parameter differences and the headline metrics
        tables = [block for block in section.blocks if isinstance(block, Table)]
        print(f"{section.title}:", *(text_table(t) for t in tables) or ["(none)"], sep="\n")
    for name in ("compare.html", "compare.md"):
        print(f"compare: wrote {out_dir / name}")


if __name__ == "__main__":
    main()
