"""Training driver: learning, exact resume, byte-determinism, transfer, model files, data order."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import torch

import scanloc.models.trainer_setup as trainer_setup
from scanloc.data.datamodule import ScanDataModule, batch_slices, epoch_permutation
from scanloc.models.model_files import load_model, predict, read_model_file
from scanloc.models.pose_regressor import HISTORY_COLUMNS, PoseRegressor
from scanloc.models.trainer_setup import resolve_precision
from scanloc.models.training import fit

CNN1D = {"_target_": "scanloc.models.cnn1d.Cnn1d", "pool_size": 8}


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def history(out_dir: Path) -> list[dict[str, float]]:
    with open(out_dir / "history.csv") as f:
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]


def train(scans: Path, out_dir: Path, **kwargs) -> dict:
    args = {
        "model_cfg": CNN1D,
        "dataset_dir": scans,
        "epochs": 1,
        "batch_size": 32,
        "lr": 0.006,
        "lr_decay": 0.0,
        "seed": 1,
        "max_samples": 128,
    } | kwargs
    return fit(out_dir=out_dir, **args)


@pytest.mark.parametrize(
    "model_cfg",
    [
        {"_target_": "scanloc.models.mlp.Mlp", "dropout": 0.0},
        CNN1D,
        {
            "_target_": "scanloc.models.cnn2d.Cnn2d",
            "image_size": 64,
            "dropout": 0.0,
            "head_dropout": 0,
        },
    ],
    ids=["mlp", "cnn1d", "cnn2d"],
)
def test_each_network_learns_a_tiny_dataset(scans: Path, tmp_path: Path, model_cfg) -> None:
    # The 2D CNN (as in the paper) is the slowest learner: give it more epochs.
    epochs = 30 if model_cfg["_target_"].endswith("Cnn2d") else 12
    metrics = train(scans, tmp_path, model_cfg=model_cfg, epochs=epochs, lr=0.01, lr_decay=0.001)
    rows = history(tmp_path)
    assert [r["epoch"] for r in rows] == list(range(1, epochs + 1))
    assert rows[-1]["train_mae"] < 0.45 * rows[0]["train_mae"]
    updates = epochs * len(batch_slices(metrics["train_samples"], 32))
    assert rows[-1]["lr"] == pytest.approx(0.01 / (1 + 0.001 * updates))
    assert metrics["epochs"] == epochs and metrics["samples"] == 128
    assert metrics["best_val_mae"] == min(r["val_mae"] for r in rows)
    assert metrics["val_mae"] == rows[-1]["val_mae"]


def test_resume_from_last_checkpoint_equals_an_uninterrupted_run(
    scans: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    common = {"epochs": 4, "model_cfg": CNN1D | {"dropout": 0.2}, "snapshot_epochs": (1, 3)}
    train(scans, tmp_path / "whole", checkpoint_dir=tmp_path / "ckpt_whole", **common)

    start_epoch = PoseRegressor.on_train_epoch_start

    def crash_in_epoch_3(self: PoseRegressor) -> None:
        if self.current_epoch == 2:
            raise RuntimeError("simulated crash")
        start_epoch(self)

    monkeypatch.setattr(PoseRegressor, "on_train_epoch_start", crash_in_epoch_3)
    with pytest.raises(RuntimeError, match="simulated crash"):
        train(scans, tmp_path / "resumed", checkpoint_dir=tmp_path / "ckpt", **common)
    assert not (tmp_path / "resumed" / "model.pt").exists()
    (last,) = (tmp_path / "ckpt").glob("*/last.ckpt")
    assert len(torch.load(last, weights_only=True)["scanloc"]["history"]) == 2
    monkeypatch.setattr(PoseRegressor, "on_train_epoch_start", start_epoch)
    train(scans, tmp_path / "resumed", checkpoint_dir=tmp_path / "ckpt", **common)
    for name in (
        "model.pt",
        "last.pt",
        "history.csv",
        "snapshots/epoch_1.pt",
        "snapshots/epoch_3.pt",
    ):
        assert (tmp_path / "whole" / name).read_bytes() == (
            tmp_path / "resumed" / name
        ).read_bytes()


def test_one_epoch_run_is_byte_deterministic(scans: Path, tmp_path: Path, capfd) -> None:
    a = train(scans, tmp_path / "a", model_cfg=CNN1D | {"dropout": 0.1})
    # Not on a terminal: one plain line per epoch with its losses, errors and times.
    epoch_line = [line for line in capfd.readouterr().err.splitlines() if line.startswith("epoch")]
    assert len(epoch_line) == 1 and "1/1: train_mae " in epoch_line[0], epoch_line
    assert "val_pos_err_m " in epoch_line[0] and " elapsed)" in epoch_line[0]
    b = train(scans, tmp_path / "b", model_cfg=CNN1D | {"dropout": 0.1})
    for name in ("model.pt", "last.pt", "history.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert {k: v for k, v in a.items() if k != "epoch_s"} == {
        k: v for k, v in b.items() if k != "epoch_s"
    }
    saved = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert saved["params"] == 450_501 and saved["train_samples"] + saved["val_samples"] == 128
    # the returned metrics time the epochs and name the device; the model folder's do not
    assert a["epoch_s"] > 0 and a["device"]["type"] == "cpu"
    assert "epoch_s" not in saved and "device" not in saved
    assert list(history(tmp_path / "a")[0]) == list(HISTORY_COLUMNS)
    content = read_model_file(tmp_path / "a" / "model.pt")
    # The dataset's beam count is filled into the stored config.
    assert content["model_cfg"] == CNN1D | {"dropout": 0.1, "num_beams": 64}
    assert str(tmp_path) not in (tmp_path / "a" / "model.pt").read_bytes().decode("latin-1")
    other_seed = train(scans, tmp_path / "c", seed=2, model_cfg=CNN1D | {"dropout": 0.1})
    assert other_seed["val_mae"] != a["val_mae"]


def test_transfer_starts_from_the_given_weights(scans: Path, tmp_path: Path) -> None:
    train(scans, tmp_path / "pre", epochs=6, lr=0.01)
    scratch = train(scans, tmp_path / "scratch", seed=5)
    transfer = train(scans, tmp_path / "transfer", seed=5, init_from=tmp_path / "pre" / "model.pt")
    assert transfer["train_mae"] < 0.7 * scratch["train_mae"]
    with pytest.raises(ValueError, match=r"pre/model\.pt: 'state_dict' does not fit"):
        train(
            scans,
            tmp_path / "bad",
            model_cfg={"_target_": "scanloc.models.mlp.Mlp"},
            init_from=tmp_path / "pre" / "model.pt",
        )


def test_load_model_and_predict(scans: Path, tmp_path: Path) -> None:
    train(scans, tmp_path, max_samples=None)
    model = load_model(tmp_path / "model.pt")
    assert not model.training
    ranges = np.load(scans / "ranges.npy")[:50]
    poses = predict(model, ranges, batch_size=16)
    assert poses.shape == (50, 3) and poses.dtype == np.float64
    with torch.no_grad():
        direct = model(torch.from_numpy(ranges)).double().numpy()
    np.testing.assert_allclose(poses, direct, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(predict(model, ranges, batch_size=50), poses, rtol=1e-5, atol=1e-5)
    assert predict(model, ranges[:0]).shape == (0, 3)
    with pytest.raises(FileNotFoundError, match=r"missing\.pt"):
        load_model(tmp_path / "missing.pt")


def test_bad_arguments_are_named(scans: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"ranges\.npy: scans have 64 beams"):
        train(scans, tmp_path, model_cfg=CNN1D | {"num_beams": 667})
    with pytest.raises(ValueError, match="max_epochs"):
        train(scans, tmp_path, trainer_cfg={"max_epochs": 3})
    with pytest.raises(ValueError, match="_target_"):
        train(scans, tmp_path, model_cfg={"pool_size": 8})
    with pytest.raises(ValueError, match="snapshot_epochs"):
        train(scans, tmp_path, snapshot_epochs=(2,))
    with pytest.raises(ValueError, match="max_samples=999"):
        train(scans, tmp_path, max_samples=999)


def test_epoch_order_is_seeded_and_covers_every_sample(scans: Path) -> None:
    assert torch.equal(epoch_permutation(100, 3, 7), epoch_permutation(100, 3, 7))
    assert not torch.equal(epoch_permutation(100, 3, 7), epoch_permutation(100, 3, 8))
    assert not torch.equal(epoch_permutation(100, 3, 7), epoch_permutation(100, 4, 7))
    data = ScanDataModule(scans, batch_size=50, seed=3)
    data.setup("fit")
    batches = data.train_batches()
    batches.set_epoch(2)
    xs = [x for x, _ in batches]
    # 192 training samples in batches of 50: 50, 50, 50, 42; all of them, once.
    assert [len(x) for x in xs] == [50, 50, 50, 42] == [len(x) for x, _ in batches]
    ranges = np.load(scans / "ranges.npy")[~np.load(scans / "is_val.npy")]
    order = epoch_permutation(192, 3, 2).numpy()
    np.testing.assert_array_equal(torch.cat(xs).numpy(), ranges[order])
    # The memory-mapped fallback gives the very same batches.
    mapped = ScanDataModule(scans, batch_size=50, seed=3, resident=False)
    mapped.setup("fit")
    again = mapped.train_batches()
    again.set_epoch(2)
    for (x, y), (x2, y2) in zip(batches, again, strict=True):
        assert torch.equal(x, x2) and torch.equal(y, y2) and y.dtype == torch.float32
    assert sum(len(x) for x, _ in data.val_batches()) == data.val_size == 64


def test_batch_slices_single_and_data_parallel() -> None:
    assert batch_slices(10, 4) == [slice(0, 4), slice(4, 8), slice(8, 10)]
    assert batch_slices(9, 4) == [slice(0, 4), slice(4, 8)]  # a lone last sample is dropped
    ranks = [batch_slices(10, 4, rank, 2) for rank in (0, 1)]
    assert ranks == [[slice(0, 2), slice(4, 6)], [slice(2, 4), slice(6, 8)]]
    with pytest.raises(ValueError, match="multiple of world_size"):
        batch_slices(10, 5, 0, 2)


@pytest.mark.slow
def test_data_parallel_spawn_on_two_cpu_processes(scans: Path, tmp_path: Path) -> None:
    trainer_cfg = {"accelerator": "cpu", "devices": 2, "strategy": "ddp_spawn"}
    metrics = train(scans, tmp_path, epochs=2, trainer_cfg=trainer_cfg)
    assert metrics["epochs"] == 2 and len(history(tmp_path)) == 2
    assert load_model(tmp_path / "model.pt")(torch.rand(3, 64)).shape == (3, 3)


def test_auto_precision_is_bf16_only_where_the_hardware_has_it(monkeypatch) -> None:
    assert resolve_precision("32-true", "cpu") == "32-true"
    assert resolve_precision("bf16-mixed", "cpu") == "bf16-mixed"
    for native, expected in ((True, "bf16-mixed"), (False, "32-true")):
        monkeypatch.setattr(trainer_setup, "cpu_has_native_bf16", lambda native=native: native)
        assert resolve_precision("auto", "cpu") == expected
        assert trainer_setup.trainer_arguments({"precision": "auto"})["precision"] == expected
    if not torch.cuda.is_available():
        assert resolve_precision("auto", "gpu") == "32-true"


def test_fit_records_its_resolved_precision(scans: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(trainer_setup, "cpu_has_native_bf16", lambda: False)
    metrics = train(scans, tmp_path, trainer_cfg={"precision": "auto"})
    assert metrics["precision"] == "32-true"
    assert json.loads((tmp_path / "metrics.json").read_text())["precision"] == "32-true"


def test_compile_option_is_checked(scans: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="compile: expected true or false, got 'yes'"):
        train(scans, tmp_path, trainer_cfg={"compile": "yes"})


MLP_NO_DROPOUT = {"_target_": "scanloc.models.mlp.Mlp", "dropout": 0.0}  # compiled dropout
# draws its masks from another generator than eager dropout


@pytest.mark.slow
def test_compiled_training_matches_eager(scans: Path, tmp_path: Path) -> None:
    eager = train(scans, tmp_path / "eager", model_cfg=MLP_NO_DROPOUT)
    compiled = train(
        scans,
        tmp_path / "compiled",
        model_cfg=MLP_NO_DROPOUT,
        trainer_cfg={"compile": True},
    )
    assert compiled["val_mae"] == pytest.approx(eager["val_mae"], rel=1e-4)
    state = read_model_file(tmp_path / "compiled" / "last.pt")["state_dict"]
    assert "layers.0.weight" in state  # keys as without compilation
