"""Seeded generator of further maps, beyond the paper's two (its future work: other structures).

Two kinds, both returned as a `MapGeometry` so that they are drawn by the same rasteriser as
the hand-made maps:
- `sparse`: a closed outer wall and random boxes and thin straight/L/U walls (like the paper's
  map 1) added until a target occupied fraction or count is reached; an obstacle that would
  split the free space is rejected, so free space stays connected.
- `rooms`: a corridor across the map with a row of rooms on each side (like map 2); every room
  has a door into the corridor, a deep room is split into a chain of rooms joined by doors, and
  some neighbouring rooms get a door between them.
All coordinates are multiples of the resolution, and the same seed gives the same map.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping
from dataclasses import replace
from itertools import pairwise
from typing import Any

import numpy as np
from scipy import ndimage

from scanloc.world.geometry import MapGeometry, Polyline, Rect, rasterize
from scanloc.world.occupancy_grid import OccupancyGrid

_FOUR_CONNECTED = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]])
DENSITY_TOLERANCE = 0.01  # generate_sparse ends with density in [asked, asked + this]


def free_components(grid: OccupancyGrid) -> int:
    """Number of 4-connected components of free cells."""
    return int(ndimage.label(grid.free, structure=_FOUR_CONNECTED)[1])


class _Snap:
    """Rounds metric values to whole cells so that generated shapes rasterise exactly."""

    def __init__(self, resolution: float) -> None:
        self.resolution = resolution

    def __call__(self, value: float) -> float:
        return round(round(value / self.resolution) * self.resolution, 9)


def _outer_wall(width: float, height: float, thickness: float) -> tuple[Rect, ...]:
    return (
        Rect(0.0, 0.0, width, thickness),
        Rect(0.0, height - thickness, width, thickness),
        Rect(0.0, 0.0, thickness, height),
        Rect(width - thickness, 0.0, thickness, height),
    )


def _random_obstacle(
    rng: np.random.Generator,
    snap: _Snap,
    lo: tuple[float, float],
    hi: tuple[float, float],
    box_fraction: float,
    size_range: tuple[float, float],
    wall_thickness: float,
) -> Rect | Polyline:
    """A box, or a thin straight / L / U wall, placed uniformly inside [lo, hi]."""
    if rng.random() < box_fraction:
        w, h = (snap(rng.uniform(*size_range)) for _ in range(2))
        x = snap(rng.uniform(lo[0], hi[0] - w))
        y = snap(rng.uniform(lo[1], hi[1] - h))
        return Rect(x, y, w, h)
    legs = int(rng.integers(1, 4))  # 1: straight, 2: L, 3: U
    a, b = (snap(rng.uniform(*size_range)) for _ in range(2))
    shape = [(0.0, 0.0), (a, 0.0), (a, b), (0.0, b)][: legs + 1]
    sx, sy = rng.choice([-1.0, 1.0], size=2)
    swap = rng.random() < 0.5
    shape = [(sy * v, sx * u) if swap else (sx * u, sy * v) for u, v in shape]
    xs, ys = [p[0] for p in shape], [p[1] for p in shape]
    margin = wall_thickness / 2.0
    x0 = snap(rng.uniform(lo[0] + margin - min(xs), hi[0] - margin - max(xs)))
    y0 = snap(rng.uniform(lo[1] + margin - min(ys), hi[1] - margin - max(ys)))
    return Polyline(tuple((x0 + u, y0 + v) for u, v in shape), wall_thickness)


def _inflated(shape: Rect | Polyline, margin: float) -> Rect | Polyline:
    """The shape grown by `margin` on every side (square corners)."""
    if isinstance(shape, Rect):
        return Rect(shape.x - margin, shape.y - margin, shape.w + 2 * margin, shape.h + 2 * margin)
    return Polyline(shape.points, shape.thickness + 2 * margin)


def _footprint(base: MapGeometry, shape: Rect | Polyline) -> np.ndarray:
    """Occupied mask of one shape on the grid of `base`."""
    if isinstance(shape, Rect):
        return rasterize(replace(base, rects=(shape,), polylines=())).occupied
    return rasterize(replace(base, rects=(), polylines=(shape,))).occupied


def generate_sparse(
    width: float,
    height: float,
    resolution: float,
    seed: int,
    *,
    density: float | None = 0.1,
    count: int | None = None,
    outer_wall: float = 0.12,
    wall_thickness: float = 0.1,
    box_fraction: float = 0.3,
    size_range: tuple[float, float] = (0.5, 2.0),
    clearance: float = 0.4,
    max_attempts: int = 5000,
) -> MapGeometry:
    """Random sparse obstacles until `count` are placed or else `density` (occupied fraction of
    the area inside the outer wall) is reached, overshooting by at most DENSITY_TOLERANCE.
    An obstacle must keep `clearance` from the other obstacles and the outer wall and must not
    split the free space (checked), so every gap is passable and free space is one
    4-connected component."""
    if count is None and (density is None or not 0.0 < density < 0.5):
        raise ValueError(f"density must be in (0, 0.5) when no count is given, got {density}")
    snap = _Snap(resolution)
    wall = snap(outer_wall)
    inset = wall + clearance
    lo, hi = (inset, inset), (width - inset, height - inset)
    if min(hi[0] - lo[0], hi[1] - lo[1]) < 2 * size_range[1]:
        raise ValueError(
            f"map {width} x {height} m is too small for obstacles up to {size_range[1]} m"
        )
    base = MapGeometry(width, height, resolution, rects=_outer_wall(width, height, wall))
    occupied = rasterize(base).occupied
    interior = ~occupied
    rng = np.random.default_rng(seed)
    shapes: list[Rect | Polyline] = []
    for _ in range(max_attempts):
        if len(shapes) == count or (count is None and occupied[interior].mean() >= density):
            break
        shape = _random_obstacle(rng, snap, lo, hi, box_fraction, size_range, snap(wall_thickness))
        if (_footprint(base, _inflated(shape, clearance)) & occupied).any():
            continue
        candidate = occupied | _footprint(base, shape)
        if count is None and candidate[interior].mean() > density + DENSITY_TOLERANCE:
            continue
        if ndimage.label(~candidate, structure=_FOUR_CONNECTED)[1] == 1:
            occupied = candidate
            shapes.append(shape)
    else:
        reached = f"{len(shapes)} obstacles, density {occupied[interior].mean():.3f}"
        raise ValueError(
            f"could not place obstacles (count={count}, density={density}) in {max_attempts} "
            f"attempts with seed {seed} ({reached}); lower density/count or clearance, or raise "
            f"box_fraction (about 0.12 is reachable with the defaults)"
        )
    return replace(
        base,
        rects=base.rects + tuple(s for s in shapes if isinstance(s, Rect)),
        polylines=tuple(s for s in shapes if isinstance(s, Polyline)),
    )


def _split(rng: np.random.Generator, snap: _Snap, start: float, stop: float, lo: float, hi: float):
    """Cut [start, stop] into consecutive spans of length in [lo, hi] (the last may be longer)."""
    cuts = [start]
    while stop - cuts[-1] > hi:
        nxt = snap(cuts[-1] + rng.uniform(lo, hi))
        if stop - nxt < lo:
            break
        cuts.append(nxt)
    return [*cuts, stop]


def _gaps(start: float, stop: float, doors: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The solid spans of a wall from `start` to `stop` once the door spans are cut out."""
    spans, pos = [], start
    for d0, d1 in sorted(doors):
        if d0 > pos:
            spans.append((pos, d0))
        pos = max(pos, d1)
    if stop > pos:
        spans.append((pos, stop))
    return spans


def _door(rng: np.random.Generator, snap: _Snap, a0: float, a1: float, width: float, margin: float):
    """A door span of `width` placed uniformly in [a0 + margin, a1 - margin]."""
    start = snap(rng.uniform(a0 + margin, a1 - margin - width))
    return start, snap(start + width)


def generate_rooms(
    width: float,
    height: float,
    resolution: float,
    seed: int,
    *,
    wall_thickness: float = 0.15,
    corridor_width: float = 1.8,
    door_width: float = 1.0,
    room_size: tuple[float, float] = (3.0, 6.0),
    extra_door_probability: float = 0.3,
) -> MapGeometry:
    """Rooms on both sides of a straight corridor along the longer side, all reachable.

    Works in (along, across) corridor coordinates; walls are (along0, along1, across0, across1).
    """
    snap = _Snap(resolution)
    t, door = snap(wall_thickness), snap(door_width)
    lo_size, hi_size = room_size
    rng = np.random.default_rng(seed)
    vertical = bool(rng.random() < 0.5) if math.isclose(width, height) else height > width
    length, depth = (height, width) if vertical else (width, height)
    if (
        depth < 2 * lo_size + corridor_width + 4 * t
        or length < 2 * lo_size + 2 * t
        or (door + 3 * t > lo_size)
    ):
        raise ValueError(
            f"map {width} x {height} m is too small for rooms of {room_size} m, corridor "
            f"{corridor_width} m, walls {wall_thickness} m and doors {door_width} m"
        )
    c0 = snap(rng.uniform(2 * t + lo_size, depth - 2 * t - lo_size - corridor_width))
    c1 = snap(c0 + snap(corridor_width))
    walls: list[tuple[float, float, float, float]] = []
    lower = ((t, snap(c0 - t)), (snap(c0 - t), c0))  # (room row span, corridor wall span)
    upper = ((snap(c1 + t), snap(depth - t)), (c1, snap(c1 + t)))
    for row, wall in (lower, upper):
        cuts = _split(rng, snap, t, length - t, lo_size, hi_size)
        doors = []
        for i, (a0, a1) in enumerate(pairwise(cuts)):
            a0 = snap(a0 + t) if i else a0  # the divider wall occupies [cut, cut + t]
            doors.append(_door(rng, snap, a0, a1, door, t))
            for cut in _split(rng, snap, *row, lo_size, hi_size)[1:-1]:  # deep: a chain of rooms
                inner = _door(rng, snap, a0, a1, door, t)
                walls += [(s0, s1, cut, snap(cut + t)) for s0, s1 in _gaps(a0, a1, [inner])]
        walls += [(s0, s1, *wall) for s0, s1 in _gaps(t, length - t, doors)]
        for cut in cuts[1:-1]:
            openings = []
            if rng.random() < extra_door_probability:
                openings.append(_door(rng, snap, row[0], row[1], door, t))
            walls += [(cut, snap(cut + t), s0, s1) for s0, s1 in _gaps(*row, openings)]
    rects = list(_outer_wall(width, height, t))
    for a0, a1, b0, b1 in walls:
        rects.append(Rect(b0, a0, b1 - b0, a1 - a0) if vertical else Rect(a0, b0, a1 - a0, b1 - b0))
    geom = MapGeometry(width, height, resolution, rects=tuple(rects))
    if free_components(rasterize(geom)) != 1:
        raise RuntimeError(f"rooms generator left free space disconnected (seed {seed})")
    return geom


GENERATORS: dict[str, Callable[..., MapGeometry]] = {
    "sparse": generate_sparse,
    "rooms": generate_rooms,
}
_COMMON = ("width", "height", "resolution", "seed")


def generate_geometry(cfg: Mapping[str, Any]) -> MapGeometry:
    """MapGeometry from a conf/map entry with `source: generated`, `kind`, `seed` and sizes;
    any further keys are the generator's keyword options (e.g. `density`, `room_size`)."""
    name = cfg.get("name", "<unnamed>")
    kind = cfg.get("kind")
    if kind not in GENERATORS:
        raise ValueError(
            f"map '{name}': field 'kind': expected one of {sorted(GENERATORS)}, got {kind!r}"
        )
    missing = [field for field in _COMMON if field not in cfg]
    if missing:
        raise ValueError(f"map '{name}': field '{missing[0]}': missing (needed by kind {kind!r})")
    generator = GENERATORS[kind]
    allowed = set(inspect.signature(generator).parameters) - set(_COMMON)
    options = {k: v for k, v in cfg.items() if k not in {"name", "source", "kind", *_COMMON}}
    for field in sorted(set(options) - allowed):
        raise ValueError(
            f"map '{name}': field '{field}': not an option of kind {kind!r} "
            f"(options: {sorted(allowed)})"
        )
    options = {k: tuple(v) if isinstance(v, list) else v for k, v in options.items()}
    seed = cfg["seed"]
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"map '{name}': field 'seed': expected an integer >= 0, got {seed!r}")
    width, height, resolution = (float(cfg[field]) for field in _COMMON[:3])
    return generator(width, height, resolution, seed, **options)
