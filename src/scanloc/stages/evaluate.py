"""`evaluate` stage: Table 2 (paper §4.4) and modern metrics for every localizer's table."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from scanloc.evaluate.table2 import evaluate_dir
from scanloc.stages._app import stage_main, timed_stage


@stage_main("evaluate")
def main(cfg: DictConfig) -> None:
    with timed_stage("evaluate"):
        evaluate_dir(
            Path(cfg.truth), Path(cfg.localize_dir), Path(cfg.metrics_path), Path(cfg.table2_path)
        )


if __name__ == "__main__":
    main()
