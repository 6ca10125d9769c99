"""Maps drawn from geometry: rasterisation rules, config validation, the paper's two maps."""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from scanloc.world.build import build_map, render_map_preview
from scanloc.world.geometry import (
    GeometryConfigError,
    MapGeometry,
    Polyline,
    Rect,
    geometry_from_config,
    rasterize,
)
from scanloc.world.map_server import load_map, save_map
from scanloc.world.occupancy_grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

REPO_ROOT = Path(__file__).resolve().parents[1]
CONF_MAPS = REPO_ROOT / "conf" / "map"


def conf(name: str) -> dict:
    return yaml.safe_load((CONF_MAPS / f"{name}.yaml").read_text())


def test_rect_covers_cells_whose_centre_is_inside() -> None:
    geom = MapGeometry(1.0, 0.5, 0.1, origin=(-0.2, 0.3), rects=(Rect(0.0, 0.4, 0.3, 0.2),))
    grid = rasterize(geom)
    assert grid.origin == (-0.2, 0.3, 0.0) and (grid.width, grid.height) == (10, 5)
    # x in [0.0, 0.3) -> cols 2..4; y in [0.4, 0.6) -> rows 1..2
    assert np.argwhere(grid.occupied).tolist() == [[1, 2], [1, 3], [1, 4], [2, 2], [2, 3], [2, 4]]


def test_paint_order_and_clipping() -> None:
    geom = MapGeometry(
        1.0,
        1.0,
        0.25,
        unknown=(Rect(-5.0, -5.0, 5.5, 10.0),),  # left half, clipped to the grid
        rects=(Rect(0.25, 0.25, 0.5, 0.25),),
    )
    cells = rasterize(geom).cells
    expected = np.array(
        [[UNKNOWN, UNKNOWN, FREE, FREE]] * 4,
        dtype=np.int8,
    )
    expected[1, 1:3] = OCCUPIED  # occupied painted over unknown
    np.testing.assert_array_equal(cells, expected)


@settings(max_examples=60, deadline=None)
@given(
    x0=st.integers(0, 40),
    y0=st.integers(0, 30),
    length=st.integers(1, 30),
    thickness=st.integers(1, 6),
    horizontal=st.booleans(),
    reverse=st.booleans(),
)
def test_axis_aligned_polyline_draws_like_the_rectangle(
    x0: int, y0: int, length: int, thickness: int, horizontal: bool, reverse: bool
) -> None:
    res = 0.05  # coordinates in whole cells, times the resolution
    end = (x0 + length, y0) if horizontal else (x0, y0 + length)
    points = ((x0 * res, y0 * res), (end[0] * res, end[1] * res))
    if reverse:
        points = points[::-1]
    half = thickness / 2
    w, h = (length + thickness, thickness) if horizontal else (thickness, length + thickness)
    rect = Rect((x0 - half) * res, (y0 - half) * res, w * res, h * res)
    line = Polyline(points, thickness * res)
    line_grid = rasterize(MapGeometry(2.5, 2.0, res, polylines=(line,)))
    rect_grid = rasterize(MapGeometry(2.5, 2.0, res, rects=(rect,)))
    np.testing.assert_array_equal(line_grid.cells, rect_grid.cells)
    # By hand, in cells: the wall spans [x0 - t/2, x0 + length + t/2) along and [y0 - t/2,
    # y0 + t/2) across; cell i's centre i + 1/2 lies in [a, b) for i = ceil(a - 1/2) ..
    # ceil(b - 1/2) - 1, i.e. from start - ceil(t/2) to end + floor(t/2) - 1 (odd t: the edges
    # pass through cell centres, the lower one inclusive). Clipped to the 50 x 40 cell grid.
    lo, hi = thickness - thickness // 2, thickness // 2
    along = (x0, x0 + length) if horizontal else (y0, y0 + length)
    across = y0 if horizontal else x0
    expected = np.zeros((40, 50), dtype=bool)
    first, stop = (max(along[0] - lo, 0), along[1] + hi), (max(across - lo, 0), across + hi)
    if horizontal:
        expected[slice(*stop), slice(*first)] = True
    else:
        expected[slice(*first), slice(*stop)] = True
    np.testing.assert_array_equal(line_grid.occupied, expected)


def test_oblique_polyline_is_a_rotated_rectangle() -> None:
    line = Polyline(((1.0, 1.0), (4.0, 5.0)), 0.4)  # length 5 m
    grid = rasterize(MapGeometry(6.0, 6.0, 0.02, polylines=(line,)))
    area = grid.occupied.sum() * 0.02**2
    assert area == pytest.approx(0.4 * (5.0 + 0.4), rel=0.01)
    col, row = grid.world_to_cell(np.array([2.5, 2.5, 1.0]), np.array([3.0, 2.0, 5.0]))
    assert grid.occupied[row, col].tolist() == [True, False, False]


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"width": None}, "width"),
        ({"resolution": -0.1}, "resolution"),
        ({"width": 1.03}, "width"),
        ({"height": 0.95}, "height"),
        ({"origin": [0.0, 0.0, 0.3]}, "origin"),
        ({"rects": [[0.0, 0.0, 1.0]]}, "rects[0]"),
        ({"rects": [[0.0, 0.0, 0.0, 1.0]]}, "rects[0]"),
        ({"unknown": [[0.0, 0.0, "a", 1.0]]}, "unknown[0]"),
        ({"polylines": [{"points": [[0.0, 0.0]], "thickness": 0.1}]}, "polylines[0].points"),
        ({"polylines": [{"points": [[0, 0], [1, 0]], "thickness": 0}]}, "polylines[0].thickness"),
        ({"polylines": [{"points": [[0, 0], [1, 0]]}]}, "polylines[0]"),
    ],
)
def test_bad_geometry_config_names_map_and_field(changes: dict, field: str) -> None:
    cfg = {"name": "tiny", "source": "geometry", "resolution": 0.1, "width": 2.0, "height": 1.0}
    cfg.update(changes)
    cfg = {k: v for k, v in cfg.items() if v is not None}
    with pytest.raises(GeometryConfigError, match=re.escape(f"map 'tiny': field '{field}'")):
        geometry_from_config(cfg)


@pytest.mark.parametrize(
    ("name", "shape", "min_occupied_iou", "min_free_iou"),
    [("sparse_obstacles", (746, 775), 0.99, 0.975), ("simple_rooms", (300, 400), 1.0, 1.0)],
)
def test_paper_maps_match_the_stdr_originals(
    stdr_maps_dir: Path, name: str, shape: tuple, min_occupied_iou: float, min_free_iou: float
) -> None:
    drawn = build_map(conf(name))
    original = load_map(stdr_maps_dir / f"{name}.yaml")
    assert drawn.cells.shape == original.cells.shape == shape
    assert drawn.resolution == original.resolution

    def iou(a: np.ndarray, b: np.ndarray) -> float:
        return float((a & b).sum() / (a | b).sum())

    assert iou(drawn.occupied, original.occupied) >= max(min_occupied_iou, 0.95)
    assert iou(drawn.free, original.free) >= min_free_iou


def test_paper_map_configs_are_compact() -> None:
    for name in ("sparse_obstacles", "simple_rooms"):
        cfg = conf(name)
        shapes = len(cfg.get("rects", [])) + len(cfg.get("polylines", []))
        assert cfg["name"] == name and cfg["source"] == "geometry" and 10 <= shapes <= 60


@pytest.mark.parametrize("path", sorted(CONF_MAPS.glob("*.yaml")), ids=lambda p: p.stem)
def test_every_map_config_builds(path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(REPO_ROOT)  # `source: file` paths are relative to the working directory
    cfg = yaml.safe_load(path.read_text())
    assert cfg["name"] == path.stem
    if cfg["source"] == "file" and not Path(cfg["path"]).is_file():
        pytest.skip(f"{cfg['path']} lies outside the repository and is absent here")
    grid = build_map(cfg)
    assert grid.occupied.any() and grid.free.any()


def test_build_map_from_file_resolves_against_cwd(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    grid = OccupancyGrid(np.array([[FREE, OCCUPIED], [UNKNOWN, FREE]], dtype=np.int8), 0.1)
    save_map(grid, tmp_path / "maps" / "m.yaml")
    monkeypatch.chdir(tmp_path)
    built = build_map({"name": "f", "source": "file", "path": "maps/m.yaml"})
    np.testing.assert_array_equal(built.cells, grid.cells)
    with pytest.raises(ValueError, match="map 'f': field 'path'"):
        build_map({"name": "f", "source": "file"})


def test_build_map_rejects_unknown_source() -> None:
    with pytest.raises(ValueError, match=r"map 'x': field 'source': expected one of"):
        build_map({"name": "x", "source": "magic"})


def test_preview_colours_orientation_and_determinism(tmp_path: Path) -> None:
    cells = np.array([[OCCUPIED, FREE, UNKNOWN], [FREE, FREE, FREE]], dtype=np.int8)
    grid = OccupancyGrid(cells, 0.1)
    first = render_map_preview(grid, tmp_path / "a" / "preview.png")
    second = render_map_preview(grid, tmp_path / "b" / "preview.png")
    assert first.read_bytes() == second.read_bytes()
    pixels = np.asarray(Image.open(io.BytesIO(first.read_bytes())))
    assert pixels.tolist() == [[255, 255, 255], [0, 255, 128]]  # row 0 of the image = top
