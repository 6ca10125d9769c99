"""ROS map_server reading and writing: trinary semantics, round trip, clear errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from PIL import Image

from scanloc.world.map_server import MapFormatError, load_map, save_map
from scanloc.world.occupancy_grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

OC, F, U = OCCUPIED, FREE, UNKNOWN  # short names for the expected tables
YAML = "image: {image}\nresolution: 0.05\norigin: [1.5, -2.0, 0.0]\nnegate: {negate}\n"
YAML += "occupied_thresh: {occ}\nfree_thresh: {free}\n"


def write_map(
    folder: Path,
    pixels: np.ndarray,
    *,
    negate: int = 0,
    occ: float = 0.6,
    free: float = 0.3,
    image: str = "m.png",
    extra: str = "",
) -> Path:
    """A map_server map from raw pixels (image row order: row 0 = top)."""
    Image.fromarray(np.asarray(pixels, dtype=np.uint8)).save(folder / image)
    yaml_path = folder / "m.yaml"
    yaml_path.write_text(YAML.format(image=image, negate=negate, occ=occ, free=free) + extra)
    return yaml_path


def cells_of(folder: Path, pixels: np.ndarray, **kwargs) -> np.ndarray:
    """Cells in image row order, to compare with the pixels directly."""
    return load_map(write_map(folder, pixels, **kwargs)).cells[::-1]


def test_grey_thresholds_are_strict_on_both_sides(tmp_path: Path) -> None:
    # p = (255 - v) / 255: v=101 -> 0.604 occ; v=102 -> 0.6 exactly (not > 0.6) unknown;
    # v=178 -> 0.302 unknown; v=179 -> 0.298 free.
    pixels = np.array([[101, 102, 178, 179, 0, 255]])
    assert cells_of(tmp_path, pixels).tolist() == [[OC, U, U, F, OC, F]]
    # p == free_thresh exactly (51/255 = 0.2) is not free.
    assert cells_of(tmp_path, np.array([[204, 205]]), free=0.2).tolist() == [[U, F]]


def test_rgb_averages_the_channels(tmp_path: Path) -> None:
    pixels = np.array([[[0, 255, 255], [0, 0, 255], [255, 0, 255]]])  # means 170, 85, 170
    assert cells_of(tmp_path, pixels).tolist() == [[U, OC, U]]


def test_rgba_averages_alpha_in(tmp_path: Path) -> None:
    pixels = np.array(
        [
            [
                [128, 128, 128, 0],  # mean 96 -> p 0.62: occupied (0.50 without alpha)
                [255, 255, 255, 0],  # mean 191.25 -> p 0.25: free at 0.3, unknown at 0.2
                [0, 0, 0, 0],
                [255, 255, 255, 255],
            ]
        ]
    )
    assert cells_of(tmp_path, pixels).tolist() == [[OC, F, OC, F]]
    assert cells_of(tmp_path, pixels, free=0.2).tolist() == [[OC, U, OC, F]]


def test_negate_inverts(tmp_path: Path) -> None:
    pixels = np.array([[0, 255, 128]])
    assert cells_of(tmp_path, pixels, negate=1).tolist() == [[F, OC, U]]


def test_rows_flipped_and_placement(tmp_path: Path) -> None:
    pixels = np.full((3, 4), 255)
    pixels[0, 3] = 0  # top-right pixel
    grid = load_map(write_map(tmp_path, pixels))
    assert (grid.width, grid.height, grid.resolution) == (4, 3, 0.05)
    assert grid.origin == (1.5, -2.0, 0.0)
    assert np.argwhere(grid.occupied).tolist() == [[2, 3]]  # row 2 = top, col 3 = right


def test_image_path_is_relative_to_the_yaml_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "maps").mkdir()
    write_map(tmp_path / "maps", np.zeros((2, 2)), image="m.pgm")
    monkeypatch.chdir(tmp_path)
    assert load_map("maps/m.yaml").occupied.all()


def random_grid(rng: np.random.Generator, shape: tuple[int, int]) -> OccupancyGrid:
    cells = rng.choice(np.array([FREE, OCCUPIED, UNKNOWN], dtype=np.int8), size=shape)
    return OccupancyGrid(cells, 0.05, (-3.25, 1e-5, 0.0))


@pytest.mark.parametrize("image_name", ["map.pgm", "map.png"])
def test_round_trip_is_exact_and_bytes_deterministic(tmp_path: Path, image_name: str) -> None:
    grid = random_grid(np.random.default_rng(0), (37, 53))
    first = save_map(grid, tmp_path / "a" / "map.yaml", image_name=image_name)
    second = save_map(grid, tmp_path / "b" / "map.yaml", image_name=image_name)
    loaded = load_map(first)
    np.testing.assert_array_equal(loaded.cells, grid.cells)
    assert (loaded.resolution, loaded.origin) == (grid.resolution, grid.origin)
    for name in ("map.yaml", image_name):
        assert (first.parent / name).read_bytes() == (second.parent / name).read_bytes()
    assert sorted(p.name for p in first.parent.iterdir()) == sorted(["map.yaml", image_name])


def test_writer_uses_map_saver_values(tmp_path: Path) -> None:
    cells = np.array([[FREE, OCCUPIED, UNKNOWN, 20, 50, 70]], dtype=np.int8)
    path = save_map(OccupancyGrid(cells, 0.05), tmp_path / "map.yaml")
    data = (tmp_path / "map.pgm").read_bytes()
    assert data.startswith(b"P5\n# CREATOR: scanloc 0.050 m/pix\n6 1\n255\n")
    assert list(data[-6:]) == [254, 0, 205, 254, 205, 0]
    assert path.read_text() == (
        "image: map.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )


@settings(max_examples=40, deadline=None)
@given(
    cells=hnp.arrays(
        np.int8,
        hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12),
        elements=st.sampled_from([FREE, OCCUPIED, UNKNOWN]),
    ),
    resolution=st.floats(1e-4, 10.0, allow_nan=False, allow_infinity=False),
    origin=st.tuples(*[st.floats(-1e6, 1e6, allow_nan=False)] * 2),
)
def test_round_trip_property(
    tmp_path_factory: pytest.TempPathFactory,
    cells: np.ndarray,
    resolution: float,
    origin: tuple[float, float],
) -> None:
    grid = OccupancyGrid(cells, resolution, (origin[0], origin[1], 0.0))
    loaded = load_map(save_map(grid, tmp_path_factory.mktemp("rt") / "map.yaml"))
    np.testing.assert_array_equal(loaded.cells, grid.cells)
    assert (loaded.resolution, loaded.origin) == (grid.resolution, grid.origin)


GOOD = {
    "image": "m.png",
    "resolution": "0.05",
    "origin": "[0.0, 0.0, 0.0]",
    "negate": "0",
    "occupied_thresh": "0.6",
    "free_thresh": "0.3",
}


@pytest.mark.parametrize(
    ("changes", "field", "hint"),
    [
        ({"free_thresh": "0.7"}, "free_thresh", "< occupied_thresh"),
        ({"free_thresh": "0.6"}, "free_thresh", "< occupied_thresh"),
        ({"occupied_thresh": "1.5"}, "occupied_thresh", "[0, 1]"),
        ({"free_thresh": "-0.1"}, "free_thresh", "[0, 1]"),
        ({"occupied_thresh": "high"}, "occupied_thresh", "number"),
        ({"mode": "scale"}, "mode", "trinary"),
        ({"mode": "fancy"}, "mode", "trinary"),
        ({"resolution": "0"}, "resolution", "> 0"),
        ({"resolution": None}, "resolution", "missing"),
        ({"origin": "[0.0, 0.0]"}, "origin", "[x, y, yaw]"),
        ({"origin": "[0.0, 0.0, 0.5]"}, "origin", "yaw 0"),
        ({"negate": "2"}, "negate", "0 or 1"),
        ({"image": "missing.png"}, "image", "not found"),
        ({"image": "m.yaml"}, "image", "cannot read"),
    ],
)
def test_bad_yaml_fields_name_file_and_field(
    tmp_path: Path, changes: dict[str, str | None], field: str, hint: str
) -> None:
    Image.fromarray(np.zeros((2, 2), dtype=np.uint8)).save(tmp_path / "m.png")
    fields = {**GOOD, **changes}
    path = tmp_path / "m.yaml"
    path.write_text("".join(f"{k}: {v}\n" for k, v in fields.items() if v is not None))
    with pytest.raises(MapFormatError) as info:
        load_map(path)
    message = str(info.value)
    assert str(path) in message and f"'{field}'" in message and hint in message


def test_malformed_yaml_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("image: [unclosed\nresolution: 0.05\n")
    with pytest.raises(MapFormatError, match=r"broken\.yaml: malformed YAML"):
        load_map(path)
    path.write_text("- just\n- a list\n")
    with pytest.raises(MapFormatError, match=r"broken\.yaml: field '<document>'"):
        load_map(path)


def test_missing_yaml_file(tmp_path: Path) -> None:
    with pytest.raises(MapFormatError, match=r"nothere\.yaml"):
        load_map(tmp_path / "nothere.yaml")


def test_stdr_sparse_obstacles_counts(stdr_maps_dir: Path) -> None:
    grid = load_map(stdr_maps_dir / "sparse_obstacles.yaml")
    assert (grid.width, grid.height, grid.resolution) == (775, 746, 0.02)
    assert grid.counts() == {"occupied": 76441, "free": 436990, "unknown": 64719}
