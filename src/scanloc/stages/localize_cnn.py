"""`localize_cnn` stage (paper §4.4): the paper's CNN localizers along a trajectory of map 1."""

from __future__ import annotations

from omegaconf import DictConfig

from scanloc.stages._app import stage_main
from scanloc.stages.localize import run_stage


@stage_main("localize_cnn")
def main(cfg: DictConfig) -> None:
    run_stage(cfg, "localize_cnn")


if __name__ == "__main__":
    main()
