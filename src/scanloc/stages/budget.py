"""The memory budget of a map: what every later stage would allocate for it, estimated from
the map's size before it is built, and the check that fails a map too large for this machine.

The maps stage runs it (scanloc.stages.maps) with the sizes the later stages' own configs give
at one profile (`pipeline_sizes`). Sizes that are code, not config, come from the modules that
own them: the planning graph's node spacing (scanloc.trajectory.planning), the scans simulated
at a time (scanloc.data.scan_dataset) and the scans decoded together (scanloc.scanlocnet.pose_grid).
What the map's content must be is checked in scanloc.world.map_checks.

ScanLocNet (train_scanlocnet) is the one stage whose cost grows with the map's free area: its
pose grid has one cell per `grid.cell_size` square of free space (x heading bins), its cell
head one logit per cell, and its validation decodes hypotheses over the whole grid.
Measured (2 CPU cores, float32, the laptop network, batch 256, 667 beams; a training step at
250, 1000 and 4000 cells, 3 steps each, on a machine shared with other jobs): a step took
1.32, 1.35 and 1.43 s, +0.03 ms per cell (the 512 x cells cell head is a small part of it),
and the peak RSS grew from 601 to 609 and 637 MB: ~10 KB per cell, inside the memory estimate
below (the cell head with Adam, 8 KB per cell, and the decoded logits of DECODE_BATCH scans,
74 KB per cell with 36 bins). The epoch time (its validation included) of the laptop runs,
25000 training and 2000 validation scans per epoch, bf16-mixed on a quiet 2-core Xeon with
AMX (2026-12-03, docs/benchmarks.md): 5.80 s on sparse_obstacles (222 cells, 12 epochs),
6.25 s on a 50 x 25 m rooms map (1250 cells, 28 epochs), 8.82 s on a 100 x 50 m one (5000
cells, 112 epochs: 16.5 min in all), which fit

    epoch_s = scans_per_epoch x TRAIN_S_PER_SCAN + val_scans x cells x DECODE_S_PER_SCAN_CELL

(0.226 ms and 0.32 us; in float32 the training scan costs FLOAT32_TRAIN_FACTOR as much:
7.02 against 5.30 s per epoch on sparse_obstacles). The maps stage prints this estimate for both
(`precision: auto` trains in bf16 only where the CPU has bf16 instructions); a memory estimate
over the budget fails it.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from hydra import compose
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig

from scanloc.data.scan_dataset import SIM_CHUNK
from scanloc.localize.catalog import localizer_overrides
from scanloc.scanlocnet.pose_grid import DECODE_BATCH
from scanloc.scanlocnet.schedule import training_epochs
from scanloc.trajectory.planning import PLAN_RESOLUTION
from scanloc.world.map_checks import MapCheckError
from scanloc.world.occupancy_grid import OccupancyGrid


class MapTooLargeError(MapCheckError):
    """A map whose arrays would not fit the memory budget; the message has the numbers."""


# Bytes per map cell of what the stages build from a map, measured as the peak RSS growth of
# each step on a 2000 x 2000-cell map (generated rooms, 100 x 100 m at 0.05 m).
LOAD_BYTES_PER_CELL = 20  # reading a map_server image: float64 colour average and thresholds
CLEARANCE_BYTES_PER_CELL = 43  # scipy's exact distance transform (float64 + int32 indices)
CAST_MAP_BYTES_PER_CELL = 10  # the ray caster's blocked mask and per-cell jump lengths
FIELD_BYTES_PER_CELL = 9  # kept per field: amcl's pz³ (float64), nav2's log pz and near mask
PROPOSAL_BYTES_PER_FREE_CELL = 32  # amcl's free-cell list (x, y float64) + np.nonzero's indices
PLAN_BYTES_PER_NODE = 160  # the trajectory's planning graph (0.1 m nodes, 8-neighbour edges)
CAST_BYTES_PER_READING = 12  # a cast range (float64) and its float32 reading
# Training scans of one epoch: worker cast + noise (float64 x 2, float32 x 3) and its copy
# into one of two shared buffers, the trainer's copy out (float32 each).
STREAM_BYTES_PER_READING = 44
# ScanLocNet's training time per epoch (module docstring: fitted to the laptop runs, 2 cores).
TRAIN_S_PER_SCAN = 2.26e-4  # a training scan in bf16-mixed: trunk, both heads, AdamW (batch 256)
FLOAT32_TRAIN_FACTOR = 1.32  # the same scan in float32 (32-true)
DECODE_S_PER_SCAN_CELL = 3.2e-7  # a validation scan's decoding, per cell (mean over training)
PROCESS_BYTES = 600 * 10**6  # Python, numpy, scipy, numba and torch in one stage process
ADAM_COPIES = 4  # a trained parameter: value, gradient, two Adam moments (float32 each)


@dataclass(frozen=True)
class PipelineSizes:
    """What the later stages allocate besides the map, from their configs at one profile.

    datasets: the scans datasets of this map, name -> samples (conf/dataset, conf/scale);
    num_beams: beams per scan (conf/sensor); scans_per_epoch: the learned model's fresh
    training scans per epoch (conf/scanlocnet.yaml training); pose_cell_size, heading_bins,
    features: its pose grid and the width of its cell head (grid, net); beam_lut: (cell size
    in m, heading bins) of amcl's beam-model range table when some localizer uses it, else None;
    epochs, val_scans, min_samples_per_cell: the learned model's epochs, validation scans and
    training scans per pose cell (its training time: scanloc.scanlocnet.schedule).
    """

    datasets: Mapping[str, int]
    num_beams: int
    scans_per_epoch: int = 0
    pose_cell_size: float = 1.0
    heading_bins: int = 36
    features: int = 512
    beam_lut: tuple[float, int] | None = None
    epochs: int = 0
    val_scans: int = 0
    min_samples_per_cell: int = 0


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


def pose_grid_cells(rows: int, cols: int, resolution: float, cell_size: float) -> int:
    """ScanLocNet's pose-grid cells on a rows x cols map with every cell free (cell_size
    rounded to whole map cells, as PoseGrid.from_map does): an upper bound."""
    step = max(1, round(cell_size / resolution))
    return math.ceil(rows / step) * math.ceil(cols / step)


def free_pose_cells(grid: OccupancyGrid, sizes: PipelineSizes) -> int:
    """The built map's pose-grid cells that hold a free map cell (PoseGrid.from_map also asks
    for the robot's clearance: this is an upper bound)."""
    step = max(1, round(sizes.pose_cell_size / grid.resolution))
    rows, cols = np.nonzero(grid.free)
    return len(np.unique((rows // step) * (grid.width // step + 1) + cols // step))


def scanlocnet_training_seconds(sizes: PipelineSizes, cells: int, bf16: bool = True) -> float:
    """Estimated wall seconds of ScanLocNet's training at `sizes` on a pose grid of `cells`,
    in bf16-mixed or (bf16 False) float32 (module docstring: the fit to the laptop runs on 2
    CPU cores)."""
    factor = 1.0 if bf16 else FLOAT32_TRAIN_FACTOR
    per_scan = sizes.scans_per_epoch * TRAIN_S_PER_SCAN * factor
    epochs = sizes.epochs
    if epochs and sizes.scans_per_epoch:  # raised on a large map, as the training raises them
        epochs = training_epochs(
            epochs, sizes.scans_per_epoch, max(cells, 1), sizes.min_samples_per_cell
        )
    return epochs * (per_scan + sizes.val_scans * cells * DECODE_S_PER_SCAN_CELL)


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
    pose_cells = pose_grid_cells(rows, cols, resolution, sizes.pose_cell_size)
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


def pipeline_sizes(map_name: str, profile: str, real_log: bool = False) -> PipelineSizes:
    """What the later stages allocate for map `map_name` at `profile`, read from their own
    configs as DVC composes them: the scans datasets of this map (its validation scans, and
    Table 1's where they are drawn on it), the learned model's training scans and pose grid
    (`real_log`: as a log's or a bag's training does), and whether some localizer builds
    amcl's beam-model range table."""

    def conf(name: str, *overrides: str) -> DictConfig:
        return compose(name, overrides=[f"profile={profile}", *overrides])

    val = conf("scans", "dataset=map_validation", f"dataset.map={map_name}")
    datasets = {str(val.dataset.name): int(val.dataset.num_samples)}
    for option in GlobalHydra.instance().config_loader().get_group_options("dataset"):
        dataset = conf("scans", f"dataset={option}").dataset
        if option != "map_validation" and dataset.map == map_name:
            datasets[str(dataset.name)] = int(dataset.num_samples)
    net = conf("scanlocnet", f"map_name={map_name}", f"real_log={str(real_log).lower()}")
    listed = localizer_overrides("localize")
    localizers = conf("localize", f"map_name={map_name}", *listed).localizers.values()
    beam = [loc for loc in localizers if loc.get("laser_model_type") == "beam"]
    return PipelineSizes(
        datasets=datasets,
        num_beams=int(val.sensor.num_beams),
        scans_per_epoch=int(net.training.scans_per_epoch),
        pose_cell_size=float(net.grid.cell_size),
        heading_bins=int(net.grid.heading_bins),
        features=int(net.net.features),
        epochs=int(net.training.epochs),
        min_samples_per_cell=int(
            net.training.real_log_min_samples_per_cell
            if real_log
            else net.training.min_samples_per_cell
        ),
        val_scans=int(val.dataset.num_samples),
        beam_lut=(
            (float(beam[0].beam_lut_resolution), int(beam[0].beam_lut_angles)) if beam else None
        ),
    )
