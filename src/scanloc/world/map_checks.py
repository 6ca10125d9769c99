"""Is a map fit for the pipeline? Checked by the maps stage before it writes anything.

Every later stage assumes what a real map gives: trinary cells with free space to stand in,
enclosed by walls or bounded by unknown cells, occupied cells a minority. A map that breaks
one of these does not crash later: it gives scans of open space, particles off the map or a
robot living inside walls, and results that look merely bad. So the maps stage fails first,
naming the file and what was expected (`check_map`), and fails before building a map whose
arrays would not fit in memory (`estimate_memory`, `check_memory`).

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

import math
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from scipy import ndimage

from scanloc.world.map_server import read_map_metadata
from scanloc.world.occupancy_grid import OccupancyGrid

MAX_OCCUPIED_SHARE = 0.5  # occupied / (occupied + free); real maps 0.06-0.31, negated >= 0.69
LISTED_COMPONENTS = 5  # the warning names this many component sizes, then sums the rest


class MapCheckError(ValueError):
    """A map the pipeline cannot use; the message names the map, what is wrong and what to do."""


class MapTooLargeError(MapCheckError):
    """A map whose arrays would not fit the memory budget; the message has the numbers."""


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
        return rows, cols, meta.resolution
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
) -> np.ndarray:
    """Raise MapCheckError for a map the pipeline cannot use; warn (MapWarning) when its free
    space splits into several components. `label` names the map (see `map_label`);
    `from_file`: a ROS map_server map, whose YAML's `negate` is the likely culprit.
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
            "bounded by unknown cells, so that rays and sampled poses stay on the map (pad the "
            "image with unknown pixels, 205, or close the outer wall)"
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


# --- memory ---------------------------------------------------------------------------------

# Bytes per map cell of what the stages build from a map, measured as the peak RSS growth of
# each step on a 2000 x 2000-cell map (generated rooms, 100 x 100 m at 0.05 m).
LOAD_BYTES_PER_CELL = 20  # reading a map_server image: float64 colour average and thresholds
CLEARANCE_BYTES_PER_CELL = 43  # scipy's exact distance transform (float64 + int32 indices)
CAST_MAP_BYTES_PER_CELL = 10  # the ray caster's blocked mask and per-cell jump lengths
FIELD_BYTES_PER_CELL = 9  # kept per field: amcl's pz³ (float64), nav2's log pz and near mask
PROPOSAL_BYTES_PER_FREE_CELL = 32  # amcl's free-cell list (x, y float64) + np.nonzero's indices
PLAN_BYTES_PER_NODE = 160  # the trajectory's planning graph (0.1 m nodes, 8-neighbour edges)
PLAN_RESOLUTION = 0.1  # scanloc.trajectory.PLAN_RESOLUTION
SIM_CHUNK = 8192  # scans cast at a time by the scans stage (scan_dataset chunk_size)
CAST_BYTES_PER_READING = 12  # a cast range (float64) and its float32 reading
# Training scans of one epoch: worker cast + noise (float64 x 2, float32 x 3) and its copy
# into one of two shared buffers, the trainer's copy out (float32 each).
STREAM_BYTES_PER_READING = 44
PROCESS_BYTES = 600 * 10**6  # Python, numpy, scipy, numba and torch in one stage process
ADAM_COPIES = 4  # a trained parameter: value, gradient, two Adam moments (float32 each)
DECODE_BATCH = 256  # scans decoded together when validating (scanlocnet.top_k's batch_size)


@dataclass(frozen=True)
class PipelineSizes:
    """What the later stages allocate besides the map, from their configs at one profile.

    datasets: the scans datasets of this map, name -> samples (conf/dataset, conf/scale);
    num_beams: beams per scan (conf/sensor); scans_per_epoch: the learned model's fresh
    training scans per epoch (conf/scanlocnet.yaml training); pose_cell_size, heading_bins,
    features: its pose grid and the width of its cell head (grid, net); beam_lut: (cell size
    in m, heading bins) of amcl's beam-model range table when some localizer uses it, else None.
    """

    datasets: Mapping[str, int]
    num_beams: int
    scans_per_epoch: int = 0
    pose_cell_size: float = 1.0
    heading_bins: int = 36
    features: int = 512
    beam_lut: tuple[float, int] | None = None


@dataclass(frozen=True)
class MemoryPart:
    """One array (or group of arrays) a stage holds at its peak."""

    stage: str
    what: str
    nbytes: int


@dataclass(frozen=True)
class MemoryEstimate:
    """The peak memory of each pipeline stage for one map. Stages run as separate processes,
    one at a time under `dvc repro`, so the pipeline needs its largest stage's peak."""

    rows: int
    cols: int
    resolution: float
    parts: tuple[MemoryPart, ...] = field(default_factory=tuple)

    def by_stage(self) -> dict[str, int]:
        """Each stage's peak: its parts plus one process's libraries."""
        totals: dict[str, int] = {}
        for part in self.parts:
            totals[part.stage] = totals.get(part.stage, PROCESS_BYTES) + part.nbytes
        return totals

    @property
    def peak_stage(self) -> str:
        totals = self.by_stage()
        return max(totals, key=totals.__getitem__)

    @property
    def need(self) -> int:
        """Bytes the pipeline needs for this map: its largest stage's peak."""
        return max(self.by_stage().values())

    def table(self) -> str:
        """The parts by stage, largest stage first, one line each."""
        totals = self.by_stage()
        lines = []
        for stage in sorted(totals, key=lambda s: (-totals[s], s)):
            lines.append(f"  {stage}: {format_bytes(totals[stage])}")
            lines += [
                f"    {p.what}: {format_bytes(p.nbytes)}" for p in self.parts if p.stage == stage
            ]
            lines.append(f"    Python and libraries: {format_bytes(PROCESS_BYTES)}")
        return "\n".join(lines)


def format_bytes(n: float) -> str:
    """Bytes in MB or GB (decimal), as memory is sold and `free -h` nearly shows it."""
    return f"{n / 1e9:.2f} GB" if n >= 1e9 else f"{n / 1e6:.1f} MB"


def estimate_memory(
    rows: int, cols: int, resolution: float, sizes: PipelineSizes
) -> MemoryEstimate:
    """The peak memory of every stage that works on a rows x cols map at `resolution` (m).

    An upper bound where the map's content matters: every cell is taken to be free (the map
    is estimated before it is built). Per-cell costs are the measured constants above.
    """
    cells = rows * cols
    beams = sizes.num_beams
    sampler = cells * (LOAD_BYTES_PER_CELL + CLEARANCE_BYTES_PER_CELL + CAST_MAP_BYTES_PER_CELL)
    step = max(1, round(PLAN_RESOLUTION / resolution))
    pose_step = max(1, round(sizes.pose_cell_size / resolution))
    pose_cells = math.ceil(rows / pose_step) * math.ceil(cols / pose_step)
    hypotheses = pose_cells * sizes.heading_bins
    parts = [
        MemoryPart("maps", f"{rows} x {cols} cells (image, cells)", cells * LOAD_BYTES_PER_CELL)
    ]
    for name, samples in sizes.datasets.items():
        stage = f"scans {name}"
        parts += [
            MemoryPart(
                stage,
                f"ranges: {samples} samples x {beams} beams x 4 B (+ poses)",
                samples * (beams * 4 + 3 * 8 + 1),
            ),
            MemoryPart(stage, "map, free-space sampler and ray caster", sampler),
            MemoryPart(
                stage,
                f"simulation chunk: {min(samples, SIM_CHUNK)} scans",
                min(samples, SIM_CHUNK) * beams * CAST_BYTES_PER_READING,
            ),
        ]
    if sizes.scans_per_epoch:
        stage = "train_scanlocnet"
        parts += [
            MemoryPart(
                stage,
                f"training scans: {sizes.scans_per_epoch} per epoch x {beams} beams, "
                "double-buffered",
                sizes.scans_per_epoch * beams * STREAM_BYTES_PER_READING,
            ),
            MemoryPart(
                stage, "map, free-space sampler and ray caster (simulation worker)", sampler
            ),
            MemoryPart(
                stage,
                f"pose grid: {pose_cells} cells of {pose_step * resolution:g} m x "
                f"{sizes.heading_bins} heading bins: cell head ({sizes.features} x cells, "
                f"with Adam) and the logits of {DECODE_BATCH} scans decoded",
                pose_cells * sizes.features * 4 * ADAM_COPIES + DECODE_BATCH * hypotheses * 8,
            ),
        ]
    parts += [
        MemoryPart("trajectory", "map and clearance (distance transform)", sampler),
        MemoryPart(
            "trajectory",
            f"planning graph: {math.ceil(rows / step) * math.ceil(cols / step)} nodes",
            math.ceil(rows / step) * math.ceil(cols / step) * PLAN_BYTES_PER_NODE,
        ),
        MemoryPart(
            "localize",
            "map, distance map and likelihood fields (amcl's and nav2's)",
            cells * (LOAD_BYTES_PER_CELL + CLEARANCE_BYTES_PER_CELL + 2 * FIELD_BYTES_PER_CELL),
        ),
        MemoryPart(
            "localize",
            "free-cell list (amcl's uniform proposal)",
            cells * PROPOSAL_BYTES_PER_FREE_CELL,
        ),
    ]
    if sizes.beam_lut is not None:
        lut_resolution, lut_angles = sizes.beam_lut
        lut_cells = math.ceil(cols * resolution / lut_resolution) * math.ceil(
            rows * resolution / lut_resolution
        )
        parts.append(
            MemoryPart(
                "localize",
                f"beam model range table: {lut_cells} cells x {lut_angles} angles x 2 B",
                lut_cells * (2 * lut_angles + 4),  # beam_model.table_bytes
            )
        )
    return MemoryEstimate(rows, cols, resolution, tuple(parts))


def physical_memory() -> int:
    """Bytes of memory this process may use: physical memory, or a smaller cgroup limit (a
    container's)."""
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    for limit_file in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(limit_file).read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            total = min(total, int(text))
    return total


def available_memory() -> int | None:
    """MemAvailable of /proc/meminfo (what can be allocated now without swapping), if known."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_memory(
    estimate: MemoryEstimate,
    label: str,
    budget: float,
    total: int | None = None,
    available: int | None = None,
) -> None:
    """Raise MapTooLargeError with the numbers when the largest stage needs more than `budget`
    (a share, conf/maps.yaml checks.memory_budget) of `total` bytes (default: this machine's)."""
    if not 0.0 < budget <= 1.0:
        raise ValueError(
            "conf/maps.yaml: field 'checks.memory_budget': expected a share in (0, 1], "
            f"got {budget!r}"
        )
    total = physical_memory() if total is None else total
    limit = budget * total
    if estimate.need <= limit:
        return
    now = available_memory() if available is None else available
    now_text = f", {format_bytes(now)} available now" if now is not None else ""
    raise MapTooLargeError(
        f"{label}: {estimate.rows} x {estimate.cols} cells at {estimate.resolution:g} m "
        f"({estimate.rows * estimate.cols / 1e6:.1f} M cells) needs an estimated "
        f"{format_bytes(estimate.need)} in its largest stage ({estimate.peak_stage}), over the "
        f"budget of {format_bytes(limit)} (checks.memory_budget {budget:g} of "
        f"{format_bytes(total)} of memory{now_text}). Per stage:\n{estimate.table()}\n"
        "Expected a map whose largest stage fits the budget: coarsen its resolution (memory "
        "grows with the cells), crop it to the area the robot uses, use a smaller profile, or "
        "raise checks.memory_budget in conf/maps.yaml"
    )
