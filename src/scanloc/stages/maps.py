"""`maps` stage: draw one map from its geometric description (or load a ROS map) and save it
in ROS map_server format with a preview image."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from scanloc.stages._app import stage_main, timed_stage, to_dict
from scanloc.world.build import build_map, render_map_preview
from scanloc.world.map_server import save_map


@stage_main("maps")
def main(cfg: DictConfig) -> None:
    out_dir = Path(cfg.out_dir)
    with timed_stage(f"maps_{cfg.map.name}"):
        grid = build_map(to_dict(cfg.map))
        save_map(grid, out_dir / "map.yaml")
        render_map_preview(grid, out_dir / "preview.png")


if __name__ == "__main__":
    main()
