"""Is a map fit for the pipeline? Checked by the maps stage before it writes anything.

Every later stage assumes what a real map gives: trinary cells with free space to stand in,
enclosed by walls or bounded by unknown cells, occupied cells a minority. A map that breaks
one of these does not crash later: it gives scans of open space, particles off the map or a
robot living inside walls, and results that look merely bad. So the maps stage fails first,
naming the file and what was expected (`check_map`). Whether the map's arrays fit in memory is
the stages' knowledge, checked before the map is built (scanloc.stages.budget).

What is checked, and why the thresholds (measured on the paper's maps, their STDR originals
and the generated maps at several sizes: 6-31 % of the known cells occupied, no free cell on
the image border, free space connected):
- no free cell: an error (nowhere to put the robot);
- inverted semantics (`negate` wrong): an error when occupied cells outnumber free ones
  (occupied share of the known cells > 0.5). Real maps measure 0.06-0.31; negating one turns
  its free cells, and its unknown 205 pixels too, into occupied ones, giving 0.69 and more;
- free space on the image border: an error. Free space must be enclosed by occupied cells or
  bounded by unknown ones; otherwise rays leave the map and see nothing, and amcl's particles
  (drawn from every free cell) walk off it. None of the paper or generated maps has one, so
  the rule holds for every source;
- several free-space components: a warning with their sizes. It is legitimate (a closed room,
  a floor plan with unmapped doors), and the datasets, the learned model's pose grid and amcl
  sample all of them; the trajectory stage drives in the largest only.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from scipy import ndimage

from scanloc.world.map_server import MapMetadata, read_map_metadata, unknown_pixel_value
from scanloc.world.occupancy_grid import OccupancyGrid

MAX_OCCUPIED_SHARE = 0.5  # occupied / (occupied + free); real maps 0.06-0.31, negated >= 0.69
LISTED_COMPONENTS = 5  # the warning names this many component sizes, then sums the rest


class MapCheckError(ValueError):
    """A map the pipeline cannot use; the message names the map, what is wrong and what to do."""


class MapWarning(UserWarning):
    """A map the pipeline can use, with something the user should know (split free space)."""


# --- what the map is called in messages -----------------------------------------------------


def map_label(cfg: Mapping[str, Any]) -> str:
    """How messages name a conf/map entry: its YAML file, or the entry and its source."""
    name = cfg.get("name", "<unnamed>")
    if cfg.get("source") == "file":
        return f"{cfg.get('path')} (map '{name}')"
    return f"map '{name}' (conf/map, source: {cfg.get('source')})"


def planned_shape(cfg: Mapping[str, Any]) -> tuple[int, int, float] | None:
    """(rows, cols, resolution) of the map a conf/map entry describes, without building it;
    None when the entry does not say (building it then fails with the reason).

    For a ROS map only the YAML and the image header are read, so a map too large to load is
    caught before it is loaded.
    """
    if cfg.get("source") == "file":
        meta = read_map_metadata(Path(str(cfg.get("path"))))
        try:
            with Image.open(meta.image) as image:
                cols, rows = image.size
        except (OSError, ValueError) as exc:
            raise MapCheckError(
                f"{cfg.get('path')}: field 'image': cannot read {meta.image}: {exc}"
            ) from exc
        pad = 2 * int(cfg.get("pad_unknown", 0) or 0)  # build_map validates the value
        return rows + pad, cols + pad, meta.resolution
    try:
        resolution = float(cfg["resolution"])
        rows = round(float(cfg["height"]) / resolution)
        cols = round(float(cfg["width"]) / resolution)
    except (KeyError, TypeError, ValueError, ZeroDivisionError, OverflowError):
        return None
    return (rows, cols, resolution) if rows > 0 and cols > 0 and resolution > 0 else None


# --- content checks -------------------------------------------------------------------------


def cell_shares(grid: OccupancyGrid) -> dict[str, float]:
    """Share of all cells that is free, occupied and unknown."""
    total = grid.cells.size
    return {kind: count / total for kind, count in grid.counts().items()}


def _shares_text(grid: OccupancyGrid) -> str:
    s = cell_shares(grid)
    return f"free {s['free']:.1%}, occupied {s['occupied']:.1%}, unknown {s['unknown']:.1%}"


def border_free_cells(grid: OccupancyGrid) -> dict[str, int]:
    """Free cells on each edge of the image: top (image row 0, the map's north), bottom,
    left, right. A corner cell counts on both of its edges."""
    free = grid.free
    return {
        "top": int(free[-1].sum()),  # cells are stored bottom row first
        "bottom": int(free[0].sum()),
        "left": int(free[:, 0].sum()),
        "right": int(free[:, -1].sum()),
    }


def border_advice(meta: MapMetadata) -> str:
    """How to bound a file map's free space at the image border, from the map's own
    thresholds: the pixel value that reads as unknown under them, and the opt-in padding."""
    value = unknown_pixel_value(meta)
    thresholds = (
        f"occupied_thresh {meta.occupied_thresh:g}, free_thresh {meta.free_thresh:g}, "
        f"negate {int(meta.negate)}"
    )
    if value is None:
        return (
            f"no 8-bit pixel value reads as unknown under this map's thresholds ({thresholds}): "
            "close the outer wall, or widen the band between free_thresh and occupied_thresh"
        )
    return (
        f"set map.pad_unknown: <cells> to let the maps stage surround the map with unknown "
        f"cells, or pad the image with pixels of value {value}, which read as unknown under "
        f"this map's thresholds ({thresholds}), or close the outer wall"
    )


def free_component_sizes(grid: OccupancyGrid) -> np.ndarray:
    """Cell counts of the 4-connected free-space components, largest first (as the generator
    counts them: a robot cannot pass between two cells that only touch at a corner)."""
    labels, count = ndimage.label(grid.free)
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    return np.sort(np.bincount(labels.ravel())[1:])[::-1]


def check_map(
    grid: OccupancyGrid,
    label: str,
    from_file: bool,
    max_occupied_share: float = MAX_OCCUPIED_SHARE,
    border_fix: str | None = None,
) -> np.ndarray:
    """Raise MapCheckError for a map the pipeline cannot use; warn (MapWarning) when its free
    space splits into several components. `label` names the map (see `map_label`);
    `from_file`: a ROS map_server map, whose YAML's `negate` is the likely culprit;
    `border_fix`: how to bound free space that reaches the image border (`border_advice`).
    Returns the free-space component sizes in cells, largest first."""
    counts = grid.counts()
    negate_hint = (
        "check `negate` in the map YAML (0: dark pixels are occupied, 1: light pixels are)"
        if from_file
        else "check the map's shapes"
    )
    if counts["free"] == 0:
        hint = f"; {negate_hint}" if counts["occupied"] > 0 else ""
        raise MapCheckError(
            f"{label}: no free cell ({_shares_text(grid)} of {grid.width} x {grid.height}); "
            f"expected free space for the robot to stand in{hint}"
        )
    share = counts["occupied"] / (counts["occupied"] + counts["free"])
    if share > max_occupied_share:
        what = "field 'negate': " if from_file else ""
        raise MapCheckError(
            f"{label}: {what}{share:.1%} of the known cells are occupied ({_shares_text(grid)}), "
            f"expected at most {max_occupied_share:.0%} (real maps: 6-31 %; inverted semantics "
            f"make free space occupied): {negate_hint}, or raise checks.max_occupied_share in "
            "conf/maps.yaml for a map that really is mostly walls"
        )
    sides = border_free_cells(grid)
    if any(sides.values()):
        border = np.zeros(grid.cells.shape, dtype=bool)
        border[[0, -1], :] = border[:, [0, -1]] = True
        where = ", ".join(f"{side} {n}" for side, n in sides.items() if n)
        raise MapCheckError(
            f"{label}: free space reaches the image border: {int((grid.free & border).sum())} "
            f"free border cells ({where}); expected free space enclosed by occupied cells or "
            "bounded by unknown cells, so that rays and sampled poses stay on the map "
            f"({border_fix or 'close the outer wall'})"
        )
    sizes = free_component_sizes(grid)
    if len(sizes) > 1:
        area = grid.resolution**2
        listed = ", ".join(f"{n * area:.2f} m² ({n} cells)" for n in sizes[:LISTED_COMPONENTS])
        rest = sizes[LISTED_COMPONENTS:]
        more = f" and {len(rest)} more ({rest.sum() * area:.2f} m² in all)" if len(rest) else ""
        warnings.warn(
            f"{label}: free space splits into {len(sizes)} separate components: "
            f"{listed}{more}. The scans datasets, the learned model's pose grid and amcl sample "
            "all of them; the trajectory stage drives (and kidnaps) in the largest only. "
            "Expected one connected free space where the robot can reach every part: check "
            "for closed doors",
            MapWarning,
            stacklevel=2,
        )
    return sizes
