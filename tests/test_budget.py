"""ScanLocNet's cost on a large map, estimated up front (scanloc.stages.budget): the training
time the maps stage prints, fitted to the measured laptop runs, and the memory check that fails a
map whose pose grid would not fit, with the numbers."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from scanloc.stages.budget import (
    MapTooLargeError,
    PipelineSizes,
    check_memory,
    estimate_memory,
    format_bytes,
    free_pose_cells,
    pipeline_sizes,
    scanlocnet_training_seconds,
)
from scanloc.world.occupancy_grid import OCCUPIED, OccupancyGrid

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"
LAPTOP = PipelineSizes(
    datasets={"office_val": 2000},
    num_beams=667,
    scans_per_epoch=25_000,
    pose_cell_size=1.0,
    heading_bins=36,
    features=512,
    epochs=12,
    val_scans=2000,
)


def test_the_training_time_estimate_matches_the_measured_laptop_runs() -> None:
    """The three runs the fit rests on (budget.py's docstring; bf16-mixed, validation included,
    the laptop's floor of 560 scans per cell): 5.80 s per epoch on sparse_obstacles (222 cells,
    12 epochs), 175 s in all on the 50 x 25 m rooms map (1250 cells, 28 epochs), 988 s on the
    100 x 50 m one (5000 cells, 112 epochs); float32 costs 7.02 s per epoch where bf16 costs
    5.30."""
    floored = PipelineSizes(**{**LAPTOP.__dict__, "min_samples_per_cell": 560})
    assert scanlocnet_training_seconds(floored, 222) / 12 == pytest.approx(5.80, rel=0.05)
    assert scanlocnet_training_seconds(floored, 1250) == pytest.approx(175.0, rel=0.05)
    assert scanlocnet_training_seconds(floored, 5000) == pytest.approx(988.0, rel=0.05)
    float32 = scanlocnet_training_seconds(LAPTOP, 222, bf16=False)
    bf16 = scanlocnet_training_seconds(LAPTOP, 222)
    assert float32 / bf16 == pytest.approx(7.02 / 5.30, rel=0.05)
    # linear in the cells: each cell adds the same time, and more epochs cost proportionally
    step = [scanlocnet_training_seconds(LAPTOP, c) for c in (1000, 2000, 3000)]
    assert step[2] - step[1] == pytest.approx(step[1] - step[0])
    fewer = PipelineSizes(**{**LAPTOP.__dict__, "epochs": 6})
    assert scanlocnet_training_seconds(fewer, 1000) == pytest.approx(step[0] / 2)


def test_the_training_time_estimate_counts_the_epochs_a_large_map_adds() -> None:
    """With the laptop's floor of 560 scans per cell a 1250-cell map trains 28 epochs, not 12
    (scanloc.scanlocnet.schedule), and the estimate says so; a 200-cell map keeps 12."""
    floored = PipelineSizes(**{**LAPTOP.__dict__, "min_samples_per_cell": 560})
    assert scanlocnet_training_seconds(floored, 200) == scanlocnet_training_seconds(LAPTOP, 200)
    ratio = scanlocnet_training_seconds(floored, 1250) / scanlocnet_training_seconds(LAPTOP, 1250)
    assert ratio == pytest.approx(28 / 12)


def test_free_pose_cells_counts_the_cells_over_free_space(walled_room) -> None:
    room: OccupancyGrid = walled_room(4.0, 3.0, 0.05)  # 80 x 60 map cells, 4 x 3 pose cells
    assert free_pose_cells(room, LAPTOP) == 12
    cells = room.cells.copy()
    cells[0:20, 0:20] = OCCUPIED  # fill the pose cell in a corner
    assert free_pose_cells(OccupancyGrid(cells, 0.05), LAPTOP) == 11
    finer = PipelineSizes(**{**LAPTOP.__dict__, "pose_cell_size": 0.5})
    assert free_pose_cells(room, finer) == 48


def test_a_map_whose_pose_grid_does_not_fit_fails_with_the_numbers() -> None:
    """A 100 x 100 m map with a 0.25 m pose grid: 160 000 cells, whose cell head and decoded
    logits need more than the machine: the message names the stage, the part and the budget."""
    sizes = PipelineSizes(**{**LAPTOP.__dict__, "pose_cell_size": 0.25})
    est = estimate_memory(2000, 2000, 0.05, sizes)
    assert est.peak_stage == "train_scanlocnet"
    need = est.need
    with pytest.raises(MapTooLargeError) as err:
        check_memory(est, "map 'hall'", budget=0.8, total=16 * 10**9, available=12 * 10**9)
    message = str(err.value)
    assert message.startswith("map 'hall': 2000 x 2000 cells at 0.05 m (4.0 M cells)")
    assert f"needs an estimated {format_bytes(need)} in its largest stage (train_scanlocnet)" in (
        message
    )
    assert "over the budget of 12.80 GB (checks.memory_budget 0.8 of 16.00 GB of memory" in message
    assert "pose grid: 160000 cells of 0.25 m x 36 heading bins" in message
    assert "12.00 GB available now" in message
    # the same map with the pipeline's 1 m cells fits
    check_memory(estimate_memory(2000, 2000, 0.05, LAPTOP), "map 'hall'", 0.8, 16 * 10**9)


def test_pipeline_sizes_carry_the_training_length() -> None:
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        laptop = pipeline_sizes("office", "laptop")
        smoke = pipeline_sizes("office", "smoke")
        net = compose("scanlocnet", overrides=["profile=laptop"])
    assert (laptop.epochs, laptop.val_scans) == (int(net.training.epochs), 2000)
    assert smoke.epochs < laptop.epochs and smoke.val_scans < laptop.val_scans
    assert scanlocnet_training_seconds(smoke, 100) < scanlocnet_training_seconds(laptop, 100)
