"""Machine-dependent figures leave the hashed metrics files for the unhashed timing files."""

from __future__ import annotations

import json
from pathlib import Path

from scanloc.hardware import split_machine_figures
from scanloc.stages._app import timed_stage


def test_split_keeps_the_parameters_figures_and_moves_the_machines() -> None:
    metrics = {
        "val_mae": 1.5,
        "epoch_s": 2.0,
        "device": {"type": "cpu"},
        "member_1": {"val_mae": 1.2, "epoch_s": 3.0},
        "member_2": {"val_mae": 1.3},
    }
    kept, machine = split_machine_figures(metrics)
    assert kept == {"val_mae": 1.5, "member_1": {"val_mae": 1.2}, "member_2": {"val_mae": 1.3}}
    assert machine == {"epoch_s": 2.0, "device": {"type": "cpu"}, "member_1": {"epoch_s": 3.0}}


def test_timed_stage_writes_the_figures_beside_the_wall_time(tmp_path: Path) -> None:
    with timed_stage("train_x", tmp_path) as machine:
        machine["epoch_s"] = 0.25
    doc = json.loads((tmp_path / "train_x.json").read_text())
    assert doc["stage"] == "train_x" and doc["wall_s"] >= 0 and doc["epoch_s"] == 0.25
