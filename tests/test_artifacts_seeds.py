"""A Table 1 row's further seeds, as the report reads them: its own (models/<row>/seeds/<seed>/)
and, for the 1D CNN 200k, the ensemble's members where the ensemble was trained exactly like it."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from scanloc.report.artifacts import load_run

CONFIG = {
    "model": "Cnn1d",
    "dataset": "map1_large",
    "samples": 20000,
    "epochs": 2,
    "batch_size": 400,
    "lr": 0.006,
    "lr_decay": 0.0,
    "dropout": 0.0,
    "seed": 3,
}


def _write_run(folder: Path, final_val: float) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    history = pd.DataFrame({"epoch": [1, 2], "train_mae": [3.0, 2.0], "val_mae": [3.1, final_val]})
    history.to_csv(folder / "history.csv", index=False)
    (folder / "metrics.json").write_text(json.dumps({"val_mae": final_val}))


def _row(root: Path, name: str, config: dict) -> None:
    _write_run(root / "models" / name, 2.0)
    (root / "models" / name / "config.json").write_text(json.dumps(config))
    metrics = root / "reports" / "metrics" / f"train_{name}.json"
    metrics.parent.mkdir(parents=True, exist_ok=True)
    metrics.write_text(json.dumps({"val_mae": 2.0}))


def test_a_rows_own_further_seeds_are_its_replicates(tmp_path: Path) -> None:
    _row(tmp_path, "cnn1d_20k", CONFIG | {"dataset": "map1_small", "seed": 2})
    for seed, val in ((3, 1.5), (4, 1.8)):
        _write_run(tmp_path / "models" / "cnn1d_20k" / "seeds" / str(seed), val)
    run = load_run(tmp_path, "cnn1d_20k")
    assert [r.val_mae for r in run.seeds] == [2.0, 1.5, 1.8]


def test_the_ensembles_members_are_the_200k_rows_seeds_only_when_trained_alike(
    tmp_path: Path,
) -> None:
    _row(tmp_path, "cnn1d_200k", CONFIG)
    ensemble = tmp_path / "models" / "ensemble"
    for k, val in ((1, 1.2), (2, 1.4)):
        _write_run(ensemble / f"member_{k}", val)
    (ensemble / "config.json").write_text(json.dumps(CONFIG | {"members": 3}))
    assert [r.val_mae for r in load_run(tmp_path, "cnn1d_200k").seeds] == [2.0, 1.2, 1.4]
    # Members trained longer than the row are not its seeds.
    (ensemble / "config.json").write_text(json.dumps(CONFIG | {"members": 3, "epochs": 4}))
    assert len(load_run(tmp_path, "cnn1d_200k").seeds) == 1
