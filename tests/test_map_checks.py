"""Bad maps fail in the maps stage with a message that says what is wrong and what to do,
before anything is written; the paper's and the generated maps pass every check."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf
from PIL import Image

from scanloc.data.scan_dataset import generate_scan_dataset, load_scan_dataset
from scanloc.localize.mcl.proposals import UniformProposal
from scanloc.scanlocnet.pose_grid import DECODE_BATCH
from scanloc.sensor.simulate import laser_spec_from_config
from scanloc.stages.budget import (
    PROCESS_BYTES,
    MapTooLargeError,
    PipelineSizes,
    check_memory,
    estimate_memory,
    pipeline_sizes,
)
from scanloc.world.build import build_map, pad_cells
from scanloc.world.free_space import sample_free_poses
from scanloc.world.map_checks import (
    MAX_OCCUPIED_SHARE,
    MapCheckError,
    MapWarning,
    border_advice,
    cell_shares,
    check_map,
    free_component_sizes,
    map_label,
    planned_shape,
)
from scanloc.world.map_server import (
    classify_pixels,
    load_map,
    read_map_metadata,
    save_map,
    unknown_pixel_value,
)
from scanloc.world.occupancy_grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

REPO_ROOT = Path(__file__).resolve().parents[1]
CONF_DIR = REPO_ROOT / "conf"
CONF_MAPS = sorted(p.stem for p in (CONF_DIR / "map").glob("*.yaml") if p.stem != "ros_file")
YAML = "image: m.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\nnegate: {negate}\n"
YAML += "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
PIXEL = {"#": 0, ".": 254, "?": 205}  # map_saver's occupied, free, unknown


def grid_of(*rows: str, resolution: float = 0.1) -> OccupancyGrid:
    """A grid drawn as text, top row first: '#' occupied, '.' free, '?' unknown."""
    value = {"#": OCCUPIED, ".": FREE, "?": UNKNOWN}
    cells = np.array([[value[c] for c in row] for row in rows], dtype=np.int8)
    return OccupancyGrid(cells[::-1].copy(), resolution)


def write_ros_map(folder: Path, *rows: str, negate: int = 0) -> Path:
    """A map_server map (PGM + YAML) drawn as text, top row first (see PIXEL)."""
    pixels = np.array([[PIXEL[c] for c in row] for row in rows], dtype=np.uint8)
    Image.fromarray(pixels).save(folder / "m.pgm")
    path = folder / "m.yaml"
    path.write_text(YAML.format(negate=negate))
    return path


def room(width: int, height: int) -> list[str]:
    """A free room of width x height cells inside a one-cell wall."""
    return ["#" * (width + 2), *(["#" + "." * width + "#"] * height), "#" * (width + 2)]


def checked(path: Path) -> np.ndarray:
    """check_map on a ROS map file, labelled as the maps stage labels it."""
    label = map_label({"name": "m", "source": "file", "path": str(path)})
    return check_map(load_map(path), label, from_file=True)


def conf_map(name: str, *overrides: str) -> dict:
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        cfg = compose("maps", overrides=[f"map={name}", *overrides])
    return OmegaConf.to_container(cfg.map, resolve=True)


# --- maps that must pass ---------------------------------------------------------------------


@pytest.mark.parametrize("name", CONF_MAPS)
def test_conf_maps_pass_every_check_without_warnings(name: str) -> None:
    cfg = conf_map(name)
    grid = build_map(cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MapWarning)
        sizes = check_map(grid, map_label(cfg), from_file=False)
    assert len(sizes) == 1
    assert planned_shape(cfg) == (grid.height, grid.width, grid.resolution)
    # the threshold's margin: real maps are far from it (measured 0.07-0.31)
    counts = grid.counts()
    assert counts["occupied"] / (counts["occupied"] + counts["free"]) < 0.35


@pytest.mark.parametrize("name", ["sparse_obstacles", "simple_rooms"])
def test_stdr_originals_pass_and_their_negation_is_caught(
    stdr_maps_dir: Path, tmp_path: Path, name: str
) -> None:
    path = stdr_maps_dir / f"{name}.yaml"
    with warnings.catch_warnings():
        warnings.simplefilter("error", MapWarning)
        checked(path)
    negated = tmp_path / f"{name}.yaml"
    negated.write_text(path.read_text().replace("negate: 0", "negate: 1"))
    (tmp_path / f"{name}.png").symlink_to(stdr_maps_dir / f"{name}.png")
    with pytest.raises(MapCheckError, match=r"field 'negate'.*check `negate` in the map YAML"):
        checked(negated)


def test_generated_maps_at_pipeline_sizes_pass() -> None:
    """The issue's 50 x 25 m rooms and 30 x 30 m sparse maps, and a 60 x 60 m rooms map."""
    for name, width, height in (
        ("generated_rooms", 50, 25),
        ("generated_sparse", 30, 30),
        ("generated_rooms", 60, 60),
    ):
        cfg = conf_map(name, f"map.width={width}", f"map.height={height}")
        with warnings.catch_warnings():
            warnings.simplefilter("error", MapWarning)
            check_map(build_map(cfg), map_label(cfg), from_file=False)


def test_a_negated_generated_map_is_caught(tmp_path: Path) -> None:
    grid = build_map(conf_map("generated_rooms"))
    save_map(grid, tmp_path / "g.yaml")
    text = (tmp_path / "g.yaml").read_text()
    (tmp_path / "g.yaml").write_text(text.replace("negate: 0", "negate: 1"))
    negated = load_map(tmp_path / "g.yaml")
    assert cell_shares(negated)["occupied"] > 1 - MAX_OCCUPIED_SHARE
    with pytest.raises(MapCheckError, match=r"g\.yaml.*field 'negate'.*occupied"):
        checked(tmp_path / "g.yaml")


def test_free_space_bounded_by_unknown_cells_passes(tmp_path: Path) -> None:
    """A gmapping-style map: free space whose edge is unknown (never seen), not a wall."""
    rows = ["?" * 8, "??....??", "?......?", "?......?", "??....??", "?" * 8]
    checked(write_ros_map(tmp_path, *rows))


# --- bad maps --------------------------------------------------------------------------------


def test_free_space_on_the_border_is_an_error(tmp_path: Path) -> None:
    rows = room(6, 4)
    rows[2] = "." + rows[2][1:]  # a gap in the west wall: free cells on the left edge
    rows[3] = "." + rows[3][1:]
    rows[0] = "##..####"  # and two on the top edge
    path = write_ros_map(tmp_path, *rows)
    with pytest.raises(MapCheckError) as err:
        checked(path)
    message = str(err.value)
    assert str(path) in message
    assert "free space reaches the image border: 4 free border cells (top 2, left 2)" in message
    assert "enclosed by occupied cells or bounded by unknown cells" in message


def test_free_space_on_the_border_of_a_conf_map_is_an_error() -> None:
    cfg = conf_map("simple_rooms", "~map.rects")  # no walls at all: all free
    with pytest.raises(MapCheckError, match=r"map 'simple_rooms' \(conf/map, source: geometry\)"):
        check_map(build_map(cfg), map_label(cfg), from_file=False)


def test_no_free_cell_is_an_error(tmp_path: Path) -> None:
    path = write_ros_map(tmp_path, "????", "????", "????")
    with pytest.raises(MapCheckError, match=r"m\.yaml.*no free cell.*unknown 100\.0%"):
        checked(path)
    with pytest.raises(MapCheckError, match=r"no free cell.*occupied 100\.0%.*check `negate`"):
        checked(write_ros_map(tmp_path, "####", "####"))


def test_inverted_semantics_is_an_error_with_the_shares(tmp_path: Path) -> None:
    path = write_ros_map(tmp_path, *room(10, 6), negate=1)  # walls read free, the room occupied
    with pytest.raises(MapCheckError) as err:
        checked(path)
    message = str(err.value)
    assert str(path) in message and "field 'negate'" in message
    assert "62.5% of the known cells are occupied" in message
    assert "free 37.5%, occupied 62.5%, unknown 0.0%" in message
    assert "expected at most 50%" in message and "check `negate` in the map YAML" in message
    checked(write_ros_map(tmp_path, *room(10, 6)))  # the same room with the right negate


def test_max_occupied_share_is_a_setting() -> None:
    cluttered = grid_of("######", "#.####", "#..###", "######")
    with pytest.raises(MapCheckError, match=r"checks\.max_occupied_share"):
        check_map(cluttered, "m", from_file=False)
    check_map(cluttered, "m", from_file=False, max_occupied_share=0.9)


def two_rooms() -> OccupancyGrid:
    """Two closed rooms (4 x 3 m west, 2 x 3 m east at 0.1 m) with no door between them."""
    west, east = room(40, 30), room(20, 30)
    return grid_of(*(w + e[1:] for w, e in zip(west, east, strict=True)))


def test_two_rooms_without_a_door_warn_with_the_sizes() -> None:
    with pytest.warns(MapWarning) as record:
        sizes = check_map(two_rooms(), "map 'two_rooms'", from_file=False)
    assert sizes.tolist() == [1200, 600]
    message = str(record[0].message)
    assert "free space splits into 2 separate components: 12.00 m² (1200 cells), " in message
    assert "6.00 m² (600 cells)" in message
    assert "trajectory stage drives (and kidnaps) in the largest only" in message


def test_many_components_are_summed_after_the_largest() -> None:
    rooms = "#" + ".....#" * 7  # seven closed rooms of 5 x 4 cells in a row
    specks = grid_of("#" * len(rooms), *[rooms] * 4, "#" * len(rooms))
    assert free_component_sizes(specks).tolist() == [20] * 7
    with pytest.warns(
        MapWarning, match=r"7 separate components: .* and 2 more \(0\.40 m² in all\)"
    ):
        check_map(specks, "m", from_file=False)


def test_dataset_and_amcl_samplers_draw_poses_in_both_rooms(tmp_path: Path) -> None:
    grid = two_rooms()
    east = grid.origin[0] + 41 * grid.resolution  # the shared wall is column 41
    sensor = yaml.safe_load((CONF_DIR / "sensor" / "urg04lx.yaml").read_text())
    noise = yaml.safe_load((CONF_DIR / "noise" / "ug01.yaml").read_text())
    generate_scan_dataset(
        tmp_path / "scans",
        grid,
        laser_spec_from_config(sensor),
        noise,
        num_samples=600,
        seed=3,
        clearance_radius=0.15,
    )
    poses = load_scan_dataset(tmp_path / "scans").poses
    # uniform over the area that keeps 0.15 m clearance: 1.7 x 2.7 m of 3.7 x 2.7 + 1.7 x 2.7
    assert 0.25 < float(np.mean(poses[:, 0] > east)) < 0.38
    alone = sample_free_poses(grid, 600, 0.15, np.random.default_rng(1))  # the sampler itself
    assert 0.25 < float(np.mean(alone[:, 0] > east)) < 0.38
    particles = UniformProposal(grid).sample(2000, np.random.default_rng(0))
    assert 0.25 < float(np.mean(particles[:, 0] > east)) < 0.42


# --- memory ----------------------------------------------------------------------------------

SIZES = PipelineSizes(
    datasets={"office_val": 2000, "big": 100_000},
    num_beams=667,
    scans_per_epoch=25_000,
    pose_cell_size=1.0,
    heading_bins=36,
    features=512,
)


def test_memory_estimate_counts_each_part() -> None:
    est = estimate_memory(2000, 1000, 0.05, SIZES)  # 100 x 50 m
    parts = {(p.stage, p.what.split(":")[0]): p.nbytes for p in est.parts}
    assert parts["scans office_val", "ranges"] == 2000 * (667 * 4 + 25)
    assert parts["scans big", "ranges"] == 100_000 * (667 * 4 + 25)
    pose_cells = 100 * 50
    assert parts["train_scanlocnet", "pose grid"] == (
        pose_cells * 512 * 16 + DECODE_BATCH * pose_cells * 36 * 8
    )
    assert parts["localize", "map, distance map and likelihood fields (amcl's and nav2's)"] == (
        2_000_000 * (20 + 43 + 18)
    )
    assert not any("range table" in p.what for p in est.parts)
    totals = est.by_stage()
    assert set(totals) == {"maps", "scans office_val", "scans big", "train_scanlocnet"} | {
        "trajectory",
        "localize",
    }
    assert totals["maps"] == PROCESS_BYTES + 2_000_000 * 20
    assert est.need == max(totals.values()) == totals[est.peak_stage]
    # memory grows with the cells: a map at half the resolution needs ~4x the per-cell parts
    finer = estimate_memory(4000, 2000, 0.025, SIZES)
    assert finer.by_stage()["localize"] - PROCESS_BYTES > 3.5 * (totals["localize"] - PROCESS_BYTES)


def test_memory_estimate_adds_the_beam_model_range_table_when_used() -> None:
    sizes = PipelineSizes(datasets={}, num_beams=667, beam_lut=(0.05, 360))
    est = estimate_memory(2000, 2000, 0.05, sizes)
    (table,) = [p for p in est.parts if "range table" in p.what]
    assert table.stage == "localize"
    assert table.nbytes == 2000 * 2000 * (2 * 360 + 4)  # beam_model.table_bytes, 2.9 GB
    assert "train_scanlocnet" not in est.by_stage()  # no training scans given


def test_check_memory_fails_with_the_numbers() -> None:
    est = estimate_memory(20_000, 20_000, 0.05, SIZES)  # 1 x 1 km at 0.05 m: 400 M cells
    check_memory(est, "map 'km'", budget=0.8, total=10 * est.need)
    with pytest.raises(MapTooLargeError) as err:
        check_memory(est, "map 'km'", budget=0.8, total=16 * 10**9, available=9 * 10**9)
    message = str(err.value)
    assert message.startswith("map 'km': 20000 x 20000 cells at 0.05 m (400.0 M cells)")
    assert f"in its largest stage ({est.peak_stage})" in message
    assert "over the budget of 12.80 GB (checks.memory_budget 0.8 of 16.00 GB of memory" in message
    assert "9.00 GB available now" in message
    assert "scans big: " in message and "ranges: 100000 samples x 667 beams x 4 B" in message
    assert "likelihood fields" in message and "pose grid" in message
    assert "coarsen its resolution" in message
    with pytest.raises(ValueError, match=r"checks\.memory_budget"):
        check_memory(est, "m", budget=1.5)


def test_pipeline_sizes_come_from_the_stage_configs() -> None:
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        paper = pipeline_sizes("sparse_obstacles", "paper")
        laptop = pipeline_sizes("office", "laptop")
    assert paper.datasets == {
        "sparse_obstacles_val": 2000,
        "map1_small": 20000,
        "map1_large": 200000,
    }
    assert paper.num_beams == 667 and paper.scans_per_epoch == 100_000
    assert (paper.pose_cell_size, paper.heading_bins, paper.beam_lut) == (1.0, 36, None)
    assert laptop.datasets == {"office_val": 2000} and laptop.scans_per_epoch == 25_000


def test_planned_shape_reads_only_the_image_header(tmp_path: Path) -> None:
    path = write_ros_map(tmp_path, *room(6, 4))
    assert planned_shape({"source": "file", "path": str(path)}) == (6, 8, 0.1)
    assert planned_shape(
        {"source": "generated", "width": 24.0, "height": 18.0, "resolution": 0.05}
    ) == (
        360,
        480,
        0.05,
    )
    assert planned_shape({"source": "geometry"}) is None  # build_map says what is missing


# --- the maps stage ----------------------------------------------------------------------------


def run_maps_stage(tmp_path: Path, *overrides: str) -> subprocess.CompletedProcess[str]:
    """The maps stage from the repository root, writing under tmp_path only."""
    env = {k: v for k, v in os.environ.items() if k not in ("SCANLOC_CONF", "DVC_STAGE")}
    command = [
        sys.executable,
        "-m",
        "scanloc.stages.maps",
        f"out_dir={tmp_path / 'maps' / 'bad'}",
        f"timing_dir={tmp_path / 'timing'}",
        f"hydra.run.dir={tmp_path / 'hydra'}",
        *overrides,
    ]
    return subprocess.run(
        command, cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=300
    )


def test_maps_stage_on_a_bad_ros_map_writes_nothing(tmp_path: Path) -> None:
    source = tmp_path / "src"
    source.mkdir()
    rows = room(6, 4)
    rows[2] = "." + rows[2][1:]
    path = write_ros_map(source, *rows)
    result = run_maps_stage(tmp_path, "map=ros_file", f"map.path={path}", "map.name=bad")
    assert result.returncode != 0
    assert f"{path} (map 'bad'): free space reaches the image border" in result.stderr
    assert not (tmp_path / "maps").exists()  # not even a temporary folder
    assert not (tmp_path / "timing").exists()


def test_maps_stage_on_a_map_too_large_writes_nothing(tmp_path: Path) -> None:
    result = run_maps_stage(
        tmp_path, "map=generated_rooms", "map.name=bad", "checks.memory_budget=0.001"
    )
    assert result.returncode != 0
    assert (
        "scanloc.stages.maps: error: map 'bad' (conf/map, source: generated): 360 x 480 cells"
        in (result.stderr)
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert not (tmp_path / "maps").exists()


def test_maps_stage_writes_a_good_map_whole(tmp_path: Path) -> None:
    source = tmp_path / "src"
    source.mkdir()
    path = write_ros_map(source, *room(6, 4))
    result = run_maps_stage(tmp_path, "map=ros_file", f"map.path={path}", "map.name=bad")
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in (tmp_path / "maps").iterdir()) == ["bad"]
    assert sorted(p.name for p in (tmp_path / "maps" / "bad").iterdir()) == [
        "map.pgm",
        "map.yaml",
        "preview.png",
    ]
    assert np.array_equal(
        load_map(tmp_path / "maps" / "bad" / "map.yaml").cells, load_map(path).cells
    )
    assert "8 x 6 cells at 0.1 m, free 50.0%" in result.stderr


def test_border_advice_follows_the_maps_own_thresholds(tmp_path: Path) -> None:
    """Under free_thresh 0.3, map_saver's 205 reads as free: the advice names a value that
    reads as unknown under the map's thresholds, and padding with it passes the check."""
    rows = room(6, 4)
    rows[2] = "." + rows[2][1:]
    path = write_ros_map(tmp_path, *rows)
    path.write_text(path.read_text().replace("free_thresh: 0.196", "free_thresh: 0.3"))
    meta = read_map_metadata(path)
    advice = border_advice(meta)
    value = int(advice.split("pixels of value ")[1].split(",")[0])
    assert value != 205
    assert classify_pixels(np.array([[value]], np.uint8), 0.65, 0.3, False)[0, 0] == UNKNOWN
    assert classify_pixels(np.array([[205]], np.uint8), 0.65, 0.3, False)[0, 0] == FREE
    with pytest.raises(MapCheckError, match=f"pixels of value {value}, which read as unknown"):
        check_map(load_map(path), "m", from_file=True, border_fix=advice)
    # Following the advice by hand: the padded image passes.
    pixels = np.pad(np.asarray(Image.open(tmp_path / "m.pgm")), 1, constant_values=value)
    Image.fromarray(pixels).save(tmp_path / "m.pgm")
    check_map(load_map(path), "m", from_file=True, border_fix=advice)


def test_no_unknown_value_under_a_closed_band_says_so(tmp_path: Path) -> None:
    path = write_ros_map(tmp_path, *room(3, 3))
    # No k / 255 lies in [0.1961, 0.199]: 50 / 255 = 0.19608 reads free, 51 / 255 = 0.2 occupied.
    text = path.read_text().replace("occupied_thresh: 0.65", "occupied_thresh: 0.199")
    text = text.replace("free_thresh: 0.196", "free_thresh: 0.1961")
    path.write_text(text)
    meta = read_map_metadata(path)
    assert unknown_pixel_value(meta) is None
    assert "no 8-bit pixel value reads as unknown" in border_advice(meta)


def test_pad_unknown_keeps_world_positions_and_is_recorded(tmp_path: Path) -> None:
    source = tmp_path / "src"
    source.mkdir()
    rows = room(6, 4)
    rows[2] = "." + rows[2][1:]
    path = write_ros_map(source, *rows)
    failed = run_maps_stage(tmp_path, "map=ros_file", f"map.path={path}", "map.name=bad")
    assert "set map.pad_unknown: <cells>" in failed.stderr
    result = run_maps_stage(
        tmp_path, "map=ros_file", f"map.path={path}", "map.name=bad", "map.pad_unknown=3"
    )
    assert result.returncode == 0, result.stderr
    out = tmp_path / "maps" / "bad"
    padded, original = load_map(out / "map.yaml"), load_map(path)
    assert padded.cells.shape == (original.height + 6, original.width + 6)
    assert np.array_equal(padded.cells[3:-3, 3:-3], original.cells)
    assert (padded.cells[:3] == UNKNOWN).all() and (padded.cells[:, -3:] == UNKNOWN).all()
    x, y = original.cell_center(np.array([2]), np.array([1]))
    col, row = padded.world_to_cell(x, y)
    assert padded.cells[row[0], col[0]] == original.cells[1, 2]
    meta = json.loads((out / "meta.json").read_text())
    assert meta["pad_unknown"]["cells"] == 3
    assert meta["pad_unknown"]["pixel_value"] == 205  # unknown under this map's 0.196 / 0.65


def test_pad_unknown_must_be_a_cell_count() -> None:
    with pytest.raises(ValueError, match="field 'pad_unknown': expected a number of cells >= 0"):
        pad_cells({"name": "m", "source": "file", "pad_unknown": -1})
