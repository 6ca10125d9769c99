"""Turn a conf/map entry into an OccupancyGrid, and draw a preview of it.

`cfg["source"]` chooses how:
- `geometry`: the shapes in the entry itself (conf/map/sparse_obstacles.yaml, simple_rooms.yaml);
- `file`: an existing ROS map_server YAML named by `path`; a relative path is resolved against
  the current working directory (the repository root when run by DVC), not against conf/;
- `generated`: the seeded generator, `kind: sparse | rooms` (conf/map/generated_*.yaml).
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from scanloc.io import atomic_path
from scanloc.world.generator import generate_geometry
from scanloc.world.geometry import geometry_from_config, rasterize
from scanloc.world.map_server import load_map
from scanloc.world.occupancy_grid import FREE, OCCUPIED, OccupancyGrid

SOURCES = ("geometry", "file", "generated")
PREVIEW_FREE, PREVIEW_OCCUPIED, PREVIEW_UNKNOWN = 255, 0, 128


def build_map(cfg: Mapping[str, Any]) -> OccupancyGrid:
    """The map a conf/map entry describes (a Hydra node converted to a plain dict)."""
    name = cfg.get("name", "<unnamed>")
    source = cfg.get("source")
    if source == "geometry":
        return rasterize(geometry_from_config(cfg))
    if source == "generated":
        return rasterize(generate_geometry(cfg))
    if source == "file":
        path = cfg.get("path")
        if not isinstance(path, str) or not path:
            raise ValueError(f"map '{name}': field 'path': expected a map YAML path, got {path!r}")
        return load_map(Path(path))
    raise ValueError(f"map '{name}': field 'source': expected one of {SOURCES}, got {source!r}")


def render_map_preview(grid: OccupancyGrid, path: str | os.PathLike[str]) -> Path:
    """Write a greyscale PNG, one pixel per cell, north up: free white, occupied black,
    unknown grey. Written atomically; the bytes depend only on the grid."""
    pixels = np.full(grid.cells.shape, PREVIEW_UNKNOWN, dtype=np.uint8)
    pixels[grid.cells == FREE] = PREVIEW_FREE
    pixels[grid.cells == OCCUPIED] = PREVIEW_OCCUPIED
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(pixels[::-1])).save(buffer, format="PNG")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buffer.getvalue())
    return Path(path)
