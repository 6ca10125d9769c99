"""Section "Maps and scans": the paper's two maps with an example scan each, map 1's scan as
the networks see it (paper Fig. 1, 3, 5, 6, 8) and the scan datasets."""

from __future__ import annotations

import numpy as np
import torch

from scanloc.data.rasterize import rasterize_scans
from scanloc.io import read_json
from scanloc.report.artifacts import (
    SCANS_DIR,
    dataset_map_name,
    example_scan,
    find_dataset,
    laser_from_meta,
    map_yaml,
    required,
)
from scanloc.report.context import ReportContext, SectionSpec
from scanloc.report.paper import MAP1, MAPS, RASTER_MAX_RANGE, RASTER_SIZE
from scanloc.report.render import figures
from scanloc.report.render.document import Block, Builder, Para, Section, Table
from scanloc.report.render.tables import num
from scanloc.sensor.laser import LaserSpec
from scanloc.world.occupancy_grid import OccupancyGrid


def build(ctx: ReportContext, spec: SectionSpec) -> list[Section]:
    b, root = ctx.builder, ctx.artifacts.root
    section = spec.section()
    section.blocks.append(
        Para(
            "The two maps, each with one scan of its dataset (the first validation scan) "
            "drawn as red beams; beams without a return are drawn light to the maximum range. "
            "For map 1 the same scan is also shown as the 1D CNN sees it (range per beam), "
            "around the robot, and rasterised as the 2D CNN's input image."
        )
    )
    for map_name, label in MAPS.items():
        if map_name == MAP1:
            required(map_yaml(root, map_name), "map 1")
        grid = ctx.artifacts.grid(map_name)
        if grid is None:
            rel = map_yaml(root, map_name).relative_to(root).as_posix()
            section.blocks.append(Para(f"{label} ({map_name}): not available ({rel})."))
            continue
        section.blocks += _map_views(b, map_name, label, grid)
    dataset_rows = []
    for meta_path in sorted((root / SCANS_DIR).glob("*/meta.json")):
        meta = read_json(meta_path)
        is_val = np.load(required(meta_path.parent / "is_val.npy", "split"), mmap_mode="r")
        dataset_rows.append(
            [
                meta_path.parent.name,
                dataset_map_name(meta),
                num(meta.get("count")),
                f"{100 * float(np.mean(is_val)):.1f} %",
                num(meta.get("seed")),
            ]
        )
    if dataset_rows:
        section.blocks.append(Para("Scan datasets (poses uniform over the free space, θ uniform)."))
        section.blocks.append(
            Table(["dataset", "map", "scans", "validation share", "seed"], dataset_rows)
        )
    return [section]


def _map_views(b: Builder, map_name: str, label: str, grid: OccupancyGrid) -> list[Block]:
    """The map with an example scan, and for map 1 the scan's three other views."""
    dataset = find_dataset(b.root, map_name)
    if dataset is None:
        return [Para(f"{label}: no scan dataset found for {map_name}.")]
    laser = laser_from_meta(read_json(dataset / "meta.json"), dataset / "meta.json")
    pose, ranges, index = example_scan(dataset)
    angles = laser.beam_angles()
    if ranges.shape != angles.shape:
        raise ValueError(
            f"{dataset / 'ranges.npy'}: {ranges.size} beams, meta.json says {angles.size}"
        )
    width, height = grid.size_m
    title = f"{label}: {map_name}, {width:.2f} × {height:.2f} m"
    blocks: list[Block] = [
        b.figure(
            f"map_{map_name}.png",
            f"{title}; scan {index} of dataset {dataset.name} at x = {pose[0]:.2f} m, "
            f"y = {pose[1]:.2f} m, θ = {np.degrees(pose[2]):.1f}°.",
            lambda p: figures.plot_map_scan(grid, pose, ranges, angles, p, title, laser.range_max),
        )
    ]
    if map_name == MAP1:
        blocks += _scan_views(b, ranges, angles, laser)
    return blocks


def rasterize_scan(
    ranges: np.ndarray, angles: np.ndarray, size: int, max_range: float
) -> np.ndarray:
    """The binary (size, size) image the 2D CNN sees for one scan (paper eq. 1–4), made by the
    network's own rasteriser so the figure shows exactly its input."""
    image = rasterize_scans(
        torch.as_tensor(ranges, dtype=torch.float32)[None],
        torch.as_tensor(angles, dtype=torch.float32),
        size=size,
        max_range=max_range,
    )
    return image[0, 0].numpy().astype(np.uint8)


def _scan_views(b: Builder, ranges: np.ndarray, angles: np.ndarray, laser: LaserSpec) -> list:
    image = rasterize_scan(ranges, angles, RASTER_SIZE, RASTER_MAX_RANGE)
    return [
        b.figure(
            "scan_1d.png",
            "Paper Fig. 1a / 3: the raw scan, 667 ranges over ±120° "
            f"(no return = fill value {laser.no_return_value:g} m).",
            lambda p: figures.plot_scan_ranges(ranges, angles, p, laser.range_max),
        ),
        b.figure(
            "scan_2d.png",
            "Paper Fig. 1b: the scan's end points around the robot.",
            lambda p: figures.plot_scan_points(ranges, angles, p, laser.range_max),
        ),
        b.figure(
            "scan_image.png",
            f"Paper Fig. 5: the scan rasterised by eq. 1–4 "
            f"(x = sin α·r as row, y = cos α·r as column, {RASTER_SIZE}×{RASTER_SIZE} px, max "
            f"{RASTER_MAX_RANGE} m, fill-value points included, as in the author's code).",
            lambda p: figures.plot_scan_image(image, p, RASTER_MAX_RANGE),
        ),
    ]


SECTION = SectionSpec("maps-and-scans", "Maps and scans", build)
