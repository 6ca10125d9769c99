"""Turn a conf/map entry into an OccupancyGrid, and draw a preview of it.

`cfg["source"]` chooses how:
- `geometry`: the shapes in the entry itself (conf/map/sparse_obstacles.yaml, simple_rooms.yaml);
- `file`: an existing ROS map_server YAML named by `path`; a relative path is resolved against
  the current working directory (the repository root when run by DVC), not against conf/;
  `pad_unknown: <cells>` (opt-in, default 0) surrounds it with that many unknown cells, for a
  slam_toolbox or gmapping map whose free space touches the image border;
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
from scanloc.world.map_server import (
    load_map,
    pad_with_unknown,
    read_map_metadata,
    unknown_pixel_value,
)
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
        return pad_with_unknown(load_map(Path(path)), pad_cells(cfg))
    raise ValueError(f"map '{name}': field 'source': expected one of {SOURCES}, got {source!r}")


def pad_cells(cfg: Mapping[str, Any]) -> int:
    """The entry's `pad_unknown` (cells of unknown space around a file map), checked."""
    cells = cfg.get("pad_unknown", 0) or 0
    if isinstance(cells, bool) or not isinstance(cells, int) or cells < 0:
        raise ValueError(
            f"map '{cfg.get('name', '<unnamed>')}': field 'pad_unknown': expected a number of "
            f"cells >= 0, got {cells!r}"
        )
    return cells


def map_provenance(cfg: Mapping[str, Any]) -> dict[str, Any] | None:
    """What the maps stage changed of a file map, for data/maps/<name>/meta.json: the unknown
    padding (cells and the pixel value that reads as unknown under the map's own thresholds),
    or None when the map is written as it was read."""
    if cfg.get("source") != "file" or pad_cells(cfg) == 0:
        return None
    meta = read_map_metadata(Path(cfg["path"]))
    return {
        "source": str(cfg["path"]),
        "pad_unknown": {
            "cells": pad_cells(cfg),
            "pixel_value": unknown_pixel_value(meta),
            "occupied_thresh": meta.occupied_thresh,
            "free_thresh": meta.free_thresh,
            "negate": meta.negate,
        },
    }


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
