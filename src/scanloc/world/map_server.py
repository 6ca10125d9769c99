"""Read and write ROS 1 `map_server` maps (a YAML file next to a PGM/PNG image).

The reader follows `map_server/src/image_loader.cpp` (noetic) in trinary mode: the colour
channels AND the alpha channel are averaged, `p = (255 - mean) / 255` (`mean` replaced by
`255 - mean` when `negate` is set), `p > occupied_thresh` is occupied, `p < free_thresh` free,
anything in between unknown. Image row 0 is the top of the map, so rows are flipped to put
cell (0, 0) at the bottom-left corner, placed at `origin`. `scale` and `raw` modes produce
graded values that `OccupancyGrid` does not model, so they are rejected.

The writer mirrors `map_saver`: occupied 0, free 254, unknown 205, with thresholds 0.65 /
0.196 so that 205 (p = 50/255 = 0.19608) reads back as unknown, here and in ROS.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError

from scanloc.io import atomic_path
from scanloc.world.occupancy_grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid

SAVED_OCCUPIED_THRESH = 0.65
SAVED_FREE_THRESH = 0.196
PIXEL_OCCUPIED, PIXEL_FREE, PIXEL_UNKNOWN = 0, 254, 205
REQUIRED_FIELDS = ("image", "resolution", "origin", "occupied_thresh", "free_thresh", "negate")


class MapFormatError(ValueError):
    """A map file that does not follow the map_server format; the message names file and field."""


@dataclass(frozen=True)
class MapMetadata:
    """The fields of a trinary map_server YAML file, validated; `image` resolved to a path."""

    image: Path
    resolution: float
    origin: tuple[float, float, float]
    occupied_thresh: float
    free_thresh: float
    negate: bool


def _error(path: Path, field: str, expected: str, got: object) -> MapFormatError:
    return MapFormatError(f"{path}: field '{field}': expected {expected}, got {got!r}")


def _number(path: Path, doc: Mapping[str, Any], field: str) -> float:
    value = doc[field]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _error(path, field, "a finite number", value)
    return float(value)


def read_map_metadata(yaml_path: str | os.PathLike[str]) -> MapMetadata:
    """Parse and validate a map_server YAML file; the image path is relative to its folder."""
    path = Path(yaml_path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise MapFormatError(f"{path}: cannot read map YAML ({exc.strerror})") from exc
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise MapFormatError(f"{path}: malformed YAML: {exc}") from exc
    if not isinstance(doc, dict):
        raise _error(path, "<document>", "a mapping of map_server fields", type(doc).__name__)
    for field in REQUIRED_FIELDS:
        if field not in doc:
            raise MapFormatError(f"{path}: field '{field}': missing (required by map_server)")

    image = doc["image"]
    if not isinstance(image, str) or not image:
        raise _error(path, "image", "an image file name", image)
    resolution = _number(path, doc, "resolution")
    if resolution <= 0:
        raise _error(path, "resolution", "a number > 0 (metres per cell)", doc["resolution"])
    origin = doc["origin"]
    if not isinstance(origin, list) or len(origin) != 3:
        raise _error(path, "origin", "a list [x, y, yaw]", origin)
    origin_values = tuple(_number(path, {"origin": v}, "origin") for v in origin)
    if origin_values[2] != 0.0:
        raise _error(path, "origin", "yaw 0 (rotated maps are not supported)", origin)
    occupied_thresh = _number(path, doc, "occupied_thresh")
    free_thresh = _number(path, doc, "free_thresh")
    for field, value in (("occupied_thresh", occupied_thresh), ("free_thresh", free_thresh)):
        if not 0.0 <= value <= 1.0:
            raise _error(path, field, "a number in [0, 1]", doc[field])
    if free_thresh >= occupied_thresh:
        raise _error(
            path,
            "free_thresh",
            f"a number < occupied_thresh ({occupied_thresh})",
            doc["free_thresh"],
        )
    negate = doc["negate"]
    if negate not in (0, 1) or not isinstance(negate, (bool, int)):
        raise _error(path, "negate", "0 or 1", negate)
    mode = doc.get("mode", "trinary")
    if mode != "trinary":
        expected = "'trinary' ('scale' and 'raw' are not supported by scanloc)"
        raise _error(path, "mode", expected, mode)
    return MapMetadata(
        image=path.parent / image,
        resolution=resolution,
        origin=(origin_values[0], origin_values[1], origin_values[2]),
        occupied_thresh=occupied_thresh,
        free_thresh=free_thresh,
        negate=bool(negate),
    )


def _image_channels(image: Image.Image) -> np.ndarray:
    """Pixels as uint8 (rows, cols, channels), expanded the way SDL_image hands them to ROS."""
    if image.mode == "1":
        image = image.convert("L")
    elif image.mode in ("LA", "PA") or (image.mode == "P" and "transparency" in image.info):
        image = image.convert("RGBA")
    elif image.mode == "P":
        image = image.convert("RGB")
    if image.mode not in ("L", "RGB", "RGBA"):
        raise ValueError(f"unsupported pixel mode {image.mode} (need 8-bit grey, RGB or RGBA)")
    pixels = np.asarray(image, dtype=np.uint8)
    return pixels[:, :, None] if pixels.ndim == 2 else pixels


def classify_pixels(
    pixels: np.ndarray, occupied_thresh: float, free_thresh: float, negate: bool
) -> np.ndarray:
    """Trinary cells (image row order) from uint8 pixels (rows, cols[, channels]).

    Same float64 arithmetic as image_loader.cpp, so threshold ties resolve as in ROS.
    """
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    color_avg = pixels.sum(axis=2, dtype=np.float64) / float(pixels.shape[2])
    if negate:
        color_avg = 255.0 - color_avg
    occ = (255.0 - color_avg) / 255.0
    cells = np.full(occ.shape, UNKNOWN, dtype=np.int8)
    cells[occ > occupied_thresh] = OCCUPIED
    cells[occ < free_thresh] = FREE
    return cells


def unknown_pixel_value(meta: MapMetadata) -> int | None:
    """The 8-bit grey value that reads as unknown under this map's own thresholds (the one
    nearest map_saver's 205), or None when no value does. map_saver's 205 itself reads as
    free under a `free_thresh` above 0.196 (e.g. slam_toolbox's 0.25 or gmapping maps at 0.3),
    so padding advice must come from the map's thresholds, not from the convention."""
    values = np.arange(256, dtype=np.uint8)
    cells = classify_pixels(values[None, :], meta.occupied_thresh, meta.free_thresh, meta.negate)
    unknown = values[cells[0] == UNKNOWN].astype(np.int64)
    if unknown.size == 0:
        return None
    return int(unknown[np.argmin(np.abs(unknown - PIXEL_UNKNOWN))])


def pad_with_unknown(grid: OccupancyGrid, cells: int) -> OccupancyGrid:
    """The grid with `cells` unknown cells added on every side, placed so that every original
    cell keeps its world position (as padding the image with unknown pixels would)."""
    if cells < 0:
        raise ValueError(f"pad_unknown: expected a number of cells >= 0, got {cells}")
    if cells == 0:
        return grid
    padded = np.pad(grid.cells, cells, constant_values=UNKNOWN)
    x0, y0, yaw = grid.origin
    origin = (x0 - cells * grid.resolution, y0 - cells * grid.resolution, yaw)
    return OccupancyGrid(np.ascontiguousarray(padded), grid.resolution, origin)


def load_map(yaml_path: str | os.PathLike[str]) -> OccupancyGrid:
    """Load a ROS map_server map (trinary mode) as an OccupancyGrid with row 0 at the bottom."""
    meta = read_map_metadata(yaml_path)
    if not meta.image.is_file():
        raise MapFormatError(f"{yaml_path}: field 'image': image file {meta.image} not found")
    try:
        with Image.open(meta.image) as image:
            pixels = _image_channels(image)
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise MapFormatError(
            f"{yaml_path}: field 'image': cannot read {meta.image}: {exc}"
        ) from exc
    cells = classify_pixels(pixels, meta.occupied_thresh, meta.free_thresh, meta.negate)
    return OccupancyGrid(np.ascontiguousarray(cells[::-1]), meta.resolution, meta.origin)


def _yaml_float(value: float) -> str:
    """Shortest exact text of a float that YAML 1.1 (PyYAML) and yaml-cpp read as a float."""
    if not math.isfinite(value):
        raise ValueError(f"cannot write non-finite value {value} to a map YAML")
    text = repr(float(value))
    if "e" in text and "." not in text:
        text = text.replace("e", ".0e")
    return text


def _encode_image(pixels: np.ndarray, image_name: str, resolution: float) -> bytes:
    if image_name.lower().endswith(".pgm"):
        height, width = pixels.shape
        header = f"P5\n# CREATOR: scanloc {resolution:.3f} m/pix\n{width} {height}\n255\n"
        return header.encode("ascii") + pixels.tobytes()
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG", optimize=False)
    return buffer.getvalue()


def save_map(
    grid: OccupancyGrid, yaml_path: str | os.PathLike[str], image_name: str = "map.pgm"
) -> Path:
    """Write `grid` as map_saver does (trinary PGM or PNG + YAML); deterministic bytes.

    As in map_saver, cell values 0..25 are written free (254), >= 65 occupied (0) and anything
    else unknown (205); the result reads back exactly through `load_map` and ROS map_server.
    Returns the path of the YAML file.
    """
    path = Path(yaml_path)
    if Path(image_name).name != image_name or not image_name.lower().endswith((".pgm", ".png")):
        raise ValueError(f"image_name must be a plain *.pgm or *.png file name, got {image_name!r}")
    values = grid.cells[::-1]
    pixels = np.full(values.shape, PIXEL_UNKNOWN, dtype=np.uint8)
    pixels[(values >= 0) & (values <= 25)] = PIXEL_FREE
    pixels[values >= 65] = PIXEL_OCCUPIED
    ox, oy, oyaw = grid.origin
    text = (
        f"image: {image_name}\n"
        f"resolution: {_yaml_float(grid.resolution)}\n"
        f"origin: [{_yaml_float(ox)}, {_yaml_float(oy)}, {_yaml_float(oyaw)}]\n"
        f"negate: 0\n"
        f"occupied_thresh: {SAVED_OCCUPIED_THRESH}\n"
        f"free_thresh: {SAVED_FREE_THRESH}\n"
    )
    with atomic_path(path.parent / image_name) as tmp:
        tmp.write_bytes(_encode_image(pixels, image_name, grid.resolution))
    with atomic_path(path) as tmp:
        tmp.write_bytes(text.encode("ascii"))
    return path
