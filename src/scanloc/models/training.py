"""Train one network on a scan dataset with Lightning, resumably and reproducibly.

`fit` writes into out_dir (the DVC output):
- model.pt    the weights of the epoch with the lowest validation MAE: a plain dict
              {"model_cfg": ..., "state_dict": ...} (no paths, no times: byte-reproducible);
- last.pt     the final weights, same format;
- history.csv one row per epoch (HISTORY_COLUMNS; deterministic);
- metrics.json final and best validation MAE, epochs, sample counts, trainable parameters and
              precision: only what the run determines, so the folder is byte-reproducible;
              the returned metrics add the machine-dependent MACHINE_KEYS (epoch_s, the median
              wall seconds per epoch, and the device it ran on), which the train stage writes
              to reports/metrics/ (a DVC metric that is not cached);
- snapshots/epoch_<e>.pt for each e in snapshot_epochs.
Lightning checkpoints (last.ckpt, best.ckpt) go to checkpoint_dir/<key>/, where <key> hashes
everything that determines the result (configuration, dataset bytes, init weights, training
code). If a last.ckpt exists under the same key, training resumes from it and ends with the
weights an uninterrupted run would have produced.
"""

from __future__ import annotations

import hashlib
import json
import statistics
import tempfile
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Callback, ModelCheckpoint

import scanloc.data.datamodule as datamodule_py
import scanloc.data.rasterize as rasterize_py
from scanloc.data.datamodule import ScanDataModule
from scanloc.data.scan_dataset import ScanDataset, load_scan_dataset
from scanloc.hardware import MACHINE_KEYS, training_device
from scanloc.io import atomic_path, write_json
from scanloc.models.model_files import (
    PathLike,
    build_model,
    count_parameters,
    dataset_model_cfg,
    load_model,
    load_weights_,
    predict,
    read_model_file,
    save_model,
)
from scanloc.models.pose_regressor import HISTORY_COLUMNS, PoseRegressor
from scanloc.models.trainer_setup import (
    compile_requested,
    keep_freed_memory,
    quiet_lightning,
    trainer_arguments,
    uses_cuda,
)
from scanloc.progress import interactive, print_line, step_line

# Re-exported: `fit`'s callers load and run what it wrote through this module.
__all__ = [
    "MACHINE_KEYS",
    "build_model",
    "fit",
    "load_model",
    "predict",
    "read_model_file",
    "save_model",
]

# Figures that measure the machine rather than the run: kept out of the model folder.


def write_history(path: PathLike, history: Sequence[Mapping[str, float]]) -> None:
    """history.csv: exact float reprs, no times, so equal runs give equal bytes."""
    lines = [",".join(HISTORY_COLUMNS)]
    lines += [",".join(repr(row[column]) for column in HISTORY_COLUMNS) for row in history]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def write_run_metrics(out_dir: PathLike, metrics: Mapping[str, Any]) -> None:
    """out_dir/metrics.json: the run's metrics without MACHINE_KEYS (byte-reproducible)."""
    write_json(
        Path(out_dir) / "metrics.json", {k: v for k, v in metrics.items() if k not in MACHINE_KEYS}
    )


def best_index(history: Sequence[Mapping[str, float]]) -> int:
    """Row of the lowest val_mae, the first of ties (as ModelCheckpoint keeps it)."""
    return min(range(len(history)), key=lambda i: history[i]["val_mae"])


def split_counts(data: ScanDataset, max_samples: int | None) -> tuple[int, int]:
    """(train, val) samples among the first max_samples of the dataset."""
    count = len(data) if max_samples is None else min(max_samples, len(data))
    n_val = int(np.count_nonzero(data.is_val[:count]))
    return count - n_val, n_val


def training_metrics(
    history: Sequence[Mapping[str, float]],
    epoch_seconds: Sequence[float],
    counts: tuple[int, int],
    params: int,
) -> dict[str, Any]:
    best = best_index(history)
    last = history[-1]
    return {
        "val_mae": last["val_mae"],
        "train_mae": last["train_mae"],
        "val_pos_err_m": last["val_pos_err_m"],
        "val_heading_err_deg": last["val_heading_err_deg"],
        "best_val_mae": history[best]["val_mae"],
        "best_epoch": int(history[best]["epoch"]),
        "epochs": len(history),
        "epoch_s": round(statistics.median(epoch_seconds), 4) if epoch_seconds else None,
        "train_samples": counts[0],
        "val_samples": counts[1],
        "samples": counts[0] + counts[1],
        "params": params,
    }


# ---------------------------------------------------------------- resume key


def _file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 22):
            digest.update(chunk)
    return digest.hexdigest()


def _code_digest() -> str:
    """The training code's source: a checkpoint from other code must not be resumed."""
    files = sorted(Path(__file__).parent.glob("*.py"))
    files += [Path(datamodule_py.__file__), Path(rasterize_py.__file__)]
    return hashlib.sha256(b"".join(f.read_bytes() for f in files)).hexdigest()


def run_key(config: Mapping[str, Any], dataset_dir: PathLike, init_from: PathLike | None) -> str:
    """A short hash of everything that determines a training run's result."""
    dataset = Path(dataset_dir)
    names = ("meta.json", "ranges.npy", "poses.npy", "is_val.npy")
    content = {
        "config": config,
        "dataset": {n: _file_digest(dataset / n) for n in names},
        "init_from": None if init_from is None else _file_digest(Path(init_from)),
        "code": _code_digest(),
    }
    text = json.dumps(content, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@contextmanager
def _run_dir(checkpoint_dir: PathLike | None, key: Callable[[], str]) -> Iterator[Path]:
    """checkpoint_dir/<key()>, or a temporary folder (removed afterwards) without resume; the
    key (which hashes the whole dataset) is only computed when there is a folder to resume."""
    if checkpoint_dir is not None:
        path = Path(checkpoint_dir) / key()
        path.mkdir(parents=True, exist_ok=True)
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="scanloc-fit-") as tmp:
        yield Path(tmp)


# ---------------------------------------------------------------- training


# The epoch line's columns (scanloc.progress.EpochLine) and their formats.
EPOCH_KEYS = {
    "train_mae": ".4f",
    "val_mae": ".4f",
    "val_pos_err_m": ".3f",
    "val_heading_err_deg": ".2f",
}


def print_epoch_line(label: str, keys: Mapping[str, str], module: L.LightningModule) -> None:
    """One line per epoch when not on a terminal (Lightning's bar is off there): the epoch, the
    losses, the validation position error and the elapsed/expected time, from the module's
    newest `history` row and its `epoch_seconds` (PoseRegressor and ScanLocModule keep both)."""
    if interactive() or not module.trainer.is_global_zero or not module.history:
        return
    row = module.history[-1]
    values = {key: format(row[key], fmt) for key, fmt in keys.items() if key in row}
    elapsed = sum(module.epoch_seconds)
    print_line(step_line(label, int(row["epoch"]), module.trainer.max_epochs, elapsed, values))


class _EpochLine(Callback):
    """print_epoch_line after PoseRegressor's validation (which appends the history row)."""

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: PoseRegressor) -> None:
        print_epoch_line("epoch", EPOCH_KEYS, pl_module)


class _Snapshots(Callback):
    """Model files of chosen epochs, kept beside the checkpoints until the run ends."""

    def __init__(self, folder: Path, epochs: Sequence[int], model_cfg: Mapping[str, Any]):
        self.folder, self.epochs, self.model_cfg = folder, set(epochs), model_cfg

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: PoseRegressor) -> None:
        epoch = trainer.current_epoch + 1
        if epoch in self.epochs and trainer.is_global_zero:
            path = self.folder / f"epoch_{epoch}.pt"
            save_model(path, self.model_cfg, pl_module.model.state_dict())


def fit(
    *,
    model_cfg: Mapping[str, Any],
    dataset_dir: PathLike,
    out_dir: PathLike,
    epochs: int,
    batch_size: int,
    lr: float,
    lr_decay: float,
    seed: int,
    max_samples: int | None = None,
    trainer_cfg: Mapping[str, Any] | None = None,
    init_from: PathLike | None = None,
    checkpoint_dir: PathLike | None = None,
    snapshot_epochs: Sequence[int] = (),
) -> dict[str, Any]:
    """Train `model_cfg` on the dataset and write out_dir (see the module docstring).

    Returns the metrics written to metrics.json.
    """
    if epochs < 1:
        raise ValueError(f"epochs must be >= 1, got {epochs}")
    if any(not 1 <= e <= epochs for e in snapshot_epochs):
        raise ValueError(f"snapshot_epochs must lie in 1..{epochs}, got {list(snapshot_epochs)}")
    data = load_scan_dataset(dataset_dir)
    model_cfg = dataset_model_cfg(model_cfg, data)
    out_dir = Path(out_dir)
    config = {
        "model_cfg": model_cfg,
        "epochs": epochs,
        "batch_size": batch_size,
        "lr": lr,
        "lr_decay": lr_decay,
        "seed": seed,
        "max_samples": max_samples,
        "trainer_cfg": dict(trainer_cfg or {}),
        "snapshot_epochs": sorted(snapshot_epochs),
    }
    kwargs = trainer_arguments(trainer_cfg)
    config["precision"] = kwargs["precision"]  # "auto" resolved on this machine
    counts = split_counts(data, max_samples)
    quiet_lightning()
    keep_freed_memory()
    with _run_dir(checkpoint_dir, lambda: run_key(config, dataset_dir, init_from)) as run_dir:
        L.seed_everything(seed, workers=True, verbose=False)
        model = build_model(model_cfg)
        if init_from is not None:
            load_weights_(model, init_from)
        if compile_requested(trainer_cfg):
            model.compile()
        module = PoseRegressor(model, lr, lr_decay)
        data = ScanDataModule(dataset_dir, batch_size, seed=seed, max_samples=max_samples)
        # Best first: last.ckpt then holds the best-tracker's state of the same epoch.
        best_checkpoint = ModelCheckpoint(
            dirpath=run_dir,
            filename="best",
            monitor="val_mae",
            mode="min",
            save_top_k=1,
            save_on_train_epoch_end=True,
            enable_version_counter=False,
        )
        last_checkpoint = ModelCheckpoint(
            dirpath=run_dir,
            filename="last",
            save_top_k=1,
            save_on_train_epoch_end=True,
            enable_version_counter=False,
        )
        snapshots = _Snapshots(run_dir / "snapshots", snapshot_epochs, model_cfg)
        trainer = L.Trainer(
            max_epochs=epochs,
            logger=False,
            callbacks=[best_checkpoint, last_checkpoint, snapshots, _EpochLine()],
            default_root_dir=run_dir,
            num_sanity_val_steps=0,
            check_val_every_n_epoch=1,
            **{
                "enable_progress_bar": interactive(),
                "enable_model_summary": interactive(),
                **kwargs,
            },
        )
        last = run_dir / "last.ckpt"
        with warnings.catch_warnings():
            # Expected when resuming: the folder holds this very run's checkpoints.
            warnings.filterwarnings("ignore", "Checkpoint directory .* is not empty")
            trainer.fit(module, datamodule=data, ckpt_path=last if last.is_file() else None)
        if not trainer.is_global_zero:
            return {}
        # Read the results back from the checkpoints: that also works when the training ran
        # in spawned processes.
        final = torch.load(last, map_location="cpu", weights_only=True)
        best = torch.load(run_dir / "best.ckpt", map_location="cpu", weights_only=True)
        history = final["scanloc"]["history"]
        if len(history) != epochs:
            raise RuntimeError(f"{last}: holds {len(history)} epochs, expected {epochs}")
        metrics = training_metrics(
            history, final["scanloc"]["epoch_seconds"], counts, count_parameters(model)
        )
        metrics["precision"] = kwargs["precision"]
        metrics["device"] = training_device(uses_cuda(str(kwargs["accelerator"])))
        out_dir.mkdir(parents=True, exist_ok=True)
        save_model(out_dir / "model.pt", model_cfg, _net_state(best["state_dict"]))
        save_model(out_dir / "last.pt", model_cfg, _net_state(final["state_dict"]))
        for epoch in sorted(snapshot_epochs):
            name = f"epoch_{epoch}.pt"
            with atomic_path(out_dir / "snapshots" / name) as tmp:
                tmp.write_bytes((run_dir / "snapshots" / name).read_bytes())
        write_history(out_dir / "history.csv", history)
        write_run_metrics(out_dir, metrics)
    return metrics


def _net_state(lightning_state: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The network's own state dict out of the PoseRegressor's ("model." prefix removed)."""
    prefix = "model."
    return {k[len(prefix) :]: v for k, v in lightning_state.items() if k.startswith(prefix)}
