"""Maps drawn from a compact geometric description (conf/map/*.yaml) instead of image files.

A `MapGeometry` is a metric rectangle of free space on which unknown regions and then
occupied shapes are painted: axis-aligned rectangles (x, y, w, h; bottom-left corner, metres)
and thick polylines (centre-line points in metres + thickness, square caps so that joined
segments form clean corners). A cell takes a shape's value when the cell's CENTRE lies in the
shape (half-open on the upper edges), so shapes placed on multiples of the resolution
rasterise exactly and an axis-aligned polyline segment draws exactly like the equivalent
rectangle.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np

from scanloc.world.occupancy_grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

Point = tuple[float, float]
_SNAP = 1e-6  # tolerance, in cells, for float noise when a size must be a whole cell count


@dataclass(frozen=True)
class Rect:
    """Axis-aligned rectangle: bottom-left corner (x, y), width w and height h in metres."""

    x: float
    y: float
    w: float
    h: float


@dataclass(frozen=True)
class Polyline:
    """A wall along a chain of points (metres), `thickness` wide, ends extended by thickness/2."""

    points: tuple[Point, ...]
    thickness: float


@dataclass(frozen=True)
class MapGeometry:
    """Everything needed to rasterise a map; coordinates are world coordinates in metres."""

    width: float
    height: float
    resolution: float
    origin: tuple[float, float] = (0.0, 0.0)
    unknown: tuple[Rect, ...] = ()
    rects: tuple[Rect, ...] = ()
    polylines: tuple[Polyline, ...] = ()

    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the grid; width and height must be whole multiples of resolution."""
        dims = []
        for name, size in (("height", self.height), ("width", self.width)):
            cells = size / self.resolution
            if not size > 0 or abs(cells - round(cells)) > _SNAP:
                raise ValueError(
                    f"map {name} {size} m is not a positive multiple of the resolution "
                    f"{self.resolution} m"
                )
            dims.append(round(cells))
        return dims[0], dims[1]


def _index_range(lo: float, hi: float, offset: float, resolution: float, n: int) -> slice:
    """Cells whose centre c satisfies lo <= c < hi, clipped to [0, n)."""
    first = math.ceil(round((lo - offset) / resolution - 0.5, 6))
    stop = math.ceil(round((hi - offset) / resolution - 0.5, 6))
    return slice(min(max(first, 0), n), min(max(stop, 0), n))


def _paint_rect(cells: np.ndarray, geom: MapGeometry, rect: Rect, value: int) -> None:
    rows = _index_range(rect.y, rect.y + rect.h, geom.origin[1], geom.resolution, cells.shape[0])
    cols = _index_range(rect.x, rect.x + rect.w, geom.origin[0], geom.resolution, cells.shape[1])
    cells[rows, cols] = value


def _segment_rect(a: Point, b: Point, half: float) -> Rect | None:
    """The rectangle an axis-aligned segment covers with square caps; None if it is oblique."""
    (x0, y0), (x1, y1) = a, b
    if x0 != x1 and y0 != y1:
        return None
    return Rect(
        min(x0, x1) - half, min(y0, y1) - half, abs(x1 - x0) + 2 * half, abs(y1 - y0) + 2 * half
    )


def _paint_oblique(
    cells: np.ndarray, geom: MapGeometry, a: Point, b: Point, half: float, value: int
) -> None:
    """Rotated rectangle around segment a-b (square caps), tested on its bounding window."""
    (x0, y0), (x1, y1) = a, b
    length = math.hypot(x1 - x0, y1 - y0)
    ux, uy = (x1 - x0) / length, (y1 - y0) / length
    reach = half * math.sqrt(2.0)
    rows = _index_range(
        min(y0, y1) - reach, max(y0, y1) + reach, geom.origin[1], geom.resolution, cells.shape[0]
    )
    cols = _index_range(
        min(x0, x1) - reach, max(x0, x1) + reach, geom.origin[0], geom.resolution, cells.shape[1]
    )
    yc = geom.origin[1] + (np.arange(rows.start, rows.stop) + 0.5) * geom.resolution
    xc = geom.origin[0] + (np.arange(cols.start, cols.stop) + 0.5) * geom.resolution
    dx, dy = xc[None, :] - x0, yc[:, None] - y0
    along = dx * ux + dy * uy
    across = dy * ux - dx * uy
    inside = (along >= -half) & (along < length + half) & (across >= -half) & (across < half)
    cells[rows, cols][inside] = value


def _paint_polyline(cells: np.ndarray, geom: MapGeometry, line: Polyline, value: int) -> None:
    half = line.thickness / 2.0
    for a, b in pairwise(line.points):
        rect = _segment_rect(a, b, half)
        if rect is not None:
            _paint_rect(cells, geom, rect, value)
        else:
            _paint_oblique(cells, geom, a, b, half, value)


def rasterize(geom: MapGeometry) -> OccupancyGrid:
    """Draw the geometry: free background, then unknown regions, then occupied shapes."""
    cells = np.full(geom.shape(), FREE, dtype=np.int8)
    for rect in geom.unknown:
        _paint_rect(cells, geom, rect, UNKNOWN)
    for rect in geom.rects:
        _paint_rect(cells, geom, rect, OCCUPIED)
    for line in geom.polylines:
        _paint_polyline(cells, geom, line, OCCUPIED)
    return OccupancyGrid(cells, geom.resolution, (geom.origin[0], geom.origin[1], 0.0))


class GeometryConfigError(ValueError):
    """A geometric map description that cannot be drawn; the message names map and field."""


def _numbers(name: str, field: str, value: Any, count: int | None) -> tuple[float, ...]:
    ok = isinstance(value, Sequence) and not isinstance(value, str)
    ok = ok and (count is None or len(value) == count)
    ok = ok and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value
    )
    if not ok:
        expected = f"a list of {count} numbers" if count else "a list of numbers"
        raise GeometryConfigError(
            f"map '{name}': field '{field}': expected {expected}, got {value!r}"
        )
    return tuple(float(v) for v in value)


def _positive(name: str, field: str, value: Any) -> float:
    (number,) = _numbers(name, field, [value], 1)
    if number <= 0:
        raise GeometryConfigError(f"map '{name}': field '{field}': expected > 0, got {value!r}")
    return number


def _rects(name: str, field: str, items: Any) -> tuple[Rect, ...]:
    rects = []
    for i, item in enumerate(items or ()):
        x, y, w, h = _numbers(name, f"{field}[{i}]", item, 4)
        if w <= 0 or h <= 0:
            raise GeometryConfigError(
                f"map '{name}': field '{field}[{i}]': expected [x, y, w, h] with w, h > 0, "
                f"got {item!r}"
            )
        rects.append(Rect(x, y, w, h))
    return tuple(rects)


def _polylines(name: str, items: Any) -> tuple[Polyline, ...]:
    lines = []
    for i, item in enumerate(items or ()):
        field = f"polylines[{i}]"
        if not isinstance(item, Mapping) or set(item) != {"points", "thickness"}:
            raise GeometryConfigError(
                f"map '{name}': field '{field}': expected {{points: [[x, y], ...], thickness: t}}, "
                f"got {item!r}"
            )
        points = tuple(_numbers(name, f"{field}.points", p, 2) for p in item["points"])
        if len(points) < 2 or any(p == q for p, q in pairwise(points)):
            raise GeometryConfigError(
                f"map '{name}': field '{field}.points': expected >= 2 points, consecutive ones "
                f"distinct, got {item['points']!r}"
            )
        thickness = _positive(name, f"{field}.thickness", item["thickness"])
        lines.append(Polyline(tuple((p[0], p[1]) for p in points), thickness))
    return tuple(lines)


def geometry_from_config(cfg: Mapping[str, Any]) -> MapGeometry:
    """MapGeometry from a conf/map entry with `source: geometry`, as in conf/map/*.yaml."""
    name = str(cfg.get("name", "<unnamed>"))
    for field in ("resolution", "width", "height"):
        if field not in cfg:
            raise GeometryConfigError(f"map '{name}': field '{field}': missing")
    origin = _numbers(name, "origin", cfg.get("origin", [0.0, 0.0]), None)
    if len(origin) not in (2, 3) or (len(origin) == 3 and origin[2] != 0.0):
        raise GeometryConfigError(
            f"map '{name}': field 'origin': expected [x, y] or [x, y, 0], got {cfg.get('origin')!r}"
        )
    geom = MapGeometry(
        width=_positive(name, "width", cfg["width"]),
        height=_positive(name, "height", cfg["height"]),
        resolution=_positive(name, "resolution", cfg["resolution"]),
        origin=(origin[0], origin[1]),
        unknown=_rects(name, "unknown", cfg.get("unknown")),
        rects=_rects(name, "rects", cfg.get("rects")),
        polylines=_polylines(name, cfg.get("polylines")),
    )
    for field in ("width", "height"):
        cells = getattr(geom, field) / geom.resolution
        if abs(cells - round(cells)) > _SNAP:
            raise GeometryConfigError(
                f"map '{name}': field '{field}': expected a multiple of the resolution "
                f"{geom.resolution} m, got {cfg[field]!r}"
            )
    return geom
