"""Train ScanLocNet (scanlocnet.py) on fresh simulated scans every epoch, with Lightning.

Objective per scan: cross-entropy of the true cell, cross-entropy of the true heading bin given
the true cell, and the Gaussian negative log-likelihood of the in-cell and in-bin offsets under
the predicted standard deviations (so they are calibrated, not only small). AdamW with a
one-cycle schedule over all steps. Validation every epoch on a fixed set of scans (a `scans`
stage dataset's validation split): the top-1 hypothesis' errors and the top-K recall (the share
of scans whose truth is within 0.5 m and 10° of one of the K best hypotheses).

`fit_scanlocnet` writes out_dir/model.pt (the network's config, the map's grid included, and
its weights), history.csv (one row per epoch) and metrics.json (deterministic figures only),
all at once (the folder appears complete or not at all); it returns those metrics plus the
machine-dependent epoch_s and device.

Stopping and resuming, as the paper's training (scanloc.models.training): every epoch ends with
checkpoint_dir/<key>/last.ckpt (written atomically), where <key> hashes what determines the
result (the configuration, the map's and the validation scans' bytes, the code). It holds the
weights, AdamW's and the one-cycle schedule's state, the history and the RNG states of torch,
numpy and Python; the scan stream needs no state but the epoch (its scans and their order
derive from (seed, epoch)). A run that finds last.ckpt under its key resumes after that epoch
and ends with the bytes of an uninterrupted run. SIGINT or SIGTERM (Ctrl-C, `kill`, also where
the process inherited them ignored) raise TrainingStopped in the main thread within moments:
the stream's worker dies with them, nothing is written to out_dir, and the caller says so.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from scanloc.data.scan_dataset import load_scan_dataset
from scanloc.hardware import training_device
from scanloc.io import atomic_dir, atomic_path, write_json
from scanloc.models.model_files import build_model, count_parameters, save_model
from scanloc.models.trainer_setup import keep_freed_memory, trainer_arguments, uses_cuda
from scanloc.models.training import print_epoch_line
from scanloc.pose import recall_within
from scanloc.progress import interactive
from scanloc.scanlocnet.model import ScanLocNet, top_k
from scanloc.scanlocnet.pose_grid import PoseGrid
from scanloc.scanlocnet.real_scans import RealScans
from scanloc.scanlocnet.resume import (
    EpochCheckpoint,
    TrainingStopped,
    restore_rng_states,
    rng_states,
    run_dir,
    run_key,
    stop_on_signals,
)
from scanloc.scanlocnet.scan_stream import ScanStream, StreamSpec

RECALL_K = (1, 5, 20)
# The epoch line's columns (scanloc.progress.EpochLine) and their formats.
EPOCH_KEYS = {
    "train_loss": ".3f",
    "val_loss": ".3f",
    "val_pos_err_median_m": ".3f",
    "val_heading_err_median_deg": ".1f",
    "val_top5_recall": ".3f",
}
HISTORY_COLUMNS = (
    "epoch",
    "train_loss",
    "val_loss",
    "val_pos_err_median_m",
    "val_heading_err_median_deg",
    "val_frac_gross_over_1m",
    "val_top1_recall",
    "val_top5_recall",
    "val_top20_recall",
    "lr",
)


def encode_targets(grid: PoseGrid, poses: np.ndarray, where: str) -> dict[str, Tensor]:
    """Training targets of poses (N, 3); every pose must lie in a cell of the grid."""
    enc = grid.encode(poses)
    outside = int((enc["cell"] < 0).sum())
    if outside:
        raise ValueError(f"{where}: {outside} poses lie outside the pose grid's cells")
    return {
        "cell": torch.from_numpy(enc["cell"]),
        "offset": torch.from_numpy(enc["offset"]).float(),
        "bin": torch.from_numpy(enc["bin"]),
        "bin_offset": torch.from_numpy(enc["bin_offset"]).float(),
    }


def scanlocnet_loss(model: ScanLocNet, ranges: Tensor, target: Mapping[str, Tensor]) -> Tensor:
    """Cell CE + heading-bin CE (at the true cell) + Gaussian NLL of the offsets."""
    feats = model.features(ranges)
    loss_cell = F.cross_entropy(model.cell_logits(feats).float(), target["cell"])
    cond = model.conditional_outputs(feats, target["cell"])
    loss_bin = F.cross_entropy(cond["bin_logits"], target["bin"])
    pred_bin_offset = cond["bin_offsets"].gather(1, target["bin"][:, None]).squeeze(1)
    error = torch.cat(
        [cond["offset"] - target["offset"], (pred_bin_offset - target["bin_offset"])[:, None]],
        dim=1,
    )
    log_std = cond["log_std"]
    nll = (0.5 * (error * torch.exp(-log_std)) ** 2 + log_std).sum(dim=1).mean()
    return loss_cell + loss_bin + nll


class _Epochs:
    """One epoch of training batches from the stream (with the real scans mixed in, if any);
    Lightning calls set_epoch (`.sampler`)."""

    batch_sampler = None

    def __init__(
        self,
        stream: ScanStream,
        grid: PoseGrid,
        batch_size: int,
        seed: int,
        real: RealScans | None = None,
    ) -> None:
        self.stream, self.grid, self.batch_size, self.seed = stream, grid, batch_size, seed
        self.real = real
        self.epoch = 0
        n = stream.spec.scans_per_epoch
        self.n_batches = n // batch_size  # full batches only: BatchNorm needs > 1 sample

    @property
    def sampler(self) -> _Epochs:
        return self

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.n_batches

    def __iter__(self) -> Iterator[tuple[Tensor, dict[str, Tensor]]]:
        ranges, poses = self.stream.epoch(self.epoch)
        if self.real is not None:
            ranges, poses = self.real.mix_into(ranges, poses, self.seed, self.epoch)
        x = torch.from_numpy(ranges)
        y = encode_targets(self.grid, poses, f"training epoch {self.epoch}")
        order = torch.randperm(
            len(x), generator=torch.Generator().manual_seed(self.seed * 100_003 + self.epoch)
        )
        for b in range(self.n_batches):
            idx = order[b * self.batch_size : (b + 1) * self.batch_size]
            yield x[idx], {k: v[idx] for k, v in y.items()}


class ScanLocModule(L.LightningModule):
    """ScanLocNet with its loss, AdamW + one-cycle, and the validation figures per epoch."""

    def __init__(
        self,
        model: ScanLocNet,
        lr: float,
        weight_decay: float,
        total_steps: int,
        pct_start: float,
        val_ranges: Tensor,
        val_poses: np.ndarray,
    ) -> None:
        super().__init__()
        self.model = model
        self.lr, self.weight_decay = lr, weight_decay
        self.total_steps, self.pct_start = total_steps, pct_start
        self.val_ranges, self.val_poses = val_ranges, val_poses
        self.val_targets = encode_targets(model.grid, val_poses, "validation scans")
        self.history: list[dict[str, float]] = []
        self.epoch_seconds: list[float] = []
        self._train_sum = torch.zeros((), dtype=torch.float64)
        self._train_count = 0
        self._start = 0.0

    def training_step(self, batch, batch_idx: int) -> Tensor:
        ranges, target = batch
        loss = scanlocnet_loss(self.model, ranges, target)
        self._train_sum += loss.detach().double()
        self._train_count += 1
        return loss

    def on_train_epoch_start(self) -> None:
        self._start = time.perf_counter()
        self._train_sum.zero_()
        self._train_count = 0

    def on_train_epoch_end(self) -> None:
        train_loss = float(self._train_sum) / max(self._train_count, 1)
        row = {"epoch": self.current_epoch + 1, "train_loss": train_loss}
        row |= self.evaluate()
        # With the validation: on a large map its decoding over the grid is a good part of the
        # epoch while the network is young (its flat scores make the exact top-K visit every cell).
        self.epoch_seconds.append(time.perf_counter() - self._start)
        row["lr"] = float(self.lr_schedulers().get_last_lr()[0])
        self.history.append(row)
        self.model.train()

    def print_epoch(self) -> None:
        """The epoch line, printed once the epoch's checkpoint is saved (EpochCheckpoint)."""
        print_epoch_line("scanlocnet epoch", EPOCH_KEYS, self)

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["scanloc"] = {
            "history": list(self.history),
            "epoch_seconds": list(self.epoch_seconds),
            "rng": rng_states(),
        }

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        state = checkpoint["scanloc"]
        self.history = list(state["history"])
        self.epoch_seconds = list(state["epoch_seconds"])
        restore_rng_states(state["rng"])

    @torch.no_grad()
    def evaluate(self) -> dict[str, float]:
        model = self.model.eval()
        losses = [
            float(
                scanlocnet_loss(
                    model,
                    self.val_ranges[s : s + 1024],
                    {k: v[s : s + 1024] for k, v in self.val_targets.items()},
                )
            )
            * len(self.val_ranges[s : s + 1024])
            for s in range(0, len(self.val_ranges), 1024)
        ]
        hyp = top_k(model, self.val_ranges, max(RECALL_K))
        return {"val_loss": sum(losses) / len(self.val_ranges)} | hypothesis_metrics(
            hyp.poses, self.val_poses, prefix="val_"
        )

    def configure_optimizers(self):
        decay, no_decay = [], []
        for name, param in self.model.named_parameters():
            (no_decay if param.ndim < 2 or "embedding" in name else decay).append(param)
        optimizer = torch.optim.AdamW(
            [
                {"params": decay, "weight_decay": self.weight_decay},
                {"params": no_decay, "weight_decay": 0.0},
            ],
            lr=self.lr,
        )
        schedule = torch.optim.lr_scheduler.OneCycleLR(
            optimizer, max_lr=self.lr, total_steps=self.total_steps, pct_start=self.pct_start
        )
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}


def hypothesis_metrics(hyp_poses: np.ndarray, truth: np.ndarray, prefix: str = "") -> dict:
    """Top-1 errors and top-K recall of hypotheses (N, K, 3) against true poses (N, 3)."""
    top1 = hyp_poses[:, 0]
    pos = np.hypot(top1[:, 0] - truth[:, 0], top1[:, 1] - truth[:, 1])
    heading = np.degrees(np.abs(np.angle(np.exp(1j * (top1[:, 2] - truth[:, 2])))))
    out = {
        f"{prefix}pos_err_median_m": float(np.median(pos)),
        f"{prefix}heading_err_median_deg": float(np.median(heading)),
        f"{prefix}frac_gross_over_1m": float(np.mean(pos > 1.0)),
    }
    for k in RECALL_K:
        out[f"{prefix}top{k}_recall"] = float(recall_within(hyp_poses[:, :k], truth).mean())
    return out


def write_history(path: Path, history: Sequence[Mapping[str, float]]) -> None:
    lines = [",".join(HISTORY_COLUMNS)]
    lines += [",".join(repr(row[c]) for c in HISTORY_COLUMNS) for row in history]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def run_metrics(
    module: ScanLocModule, scans_per_epoch: int, batch_size: int, precision: str
) -> dict[str, Any]:
    """metrics.json: the last epoch's figures and the run's sizes (deterministic only)."""
    history, grid = module.history, module.model.grid
    metrics: dict[str, Any] = {k: v for k, v in history[-1].items() if k not in ("epoch", "lr")}
    return metrics | {
        "epochs": len(history),
        "scans_per_epoch": scans_per_epoch,
        "samples_seen": len(history) * (scans_per_epoch // batch_size) * batch_size,
        "val_scans": len(module.val_poses),
        "cells": grid.num_cells,
        "heading_bins": grid.heading_bins,
        "params": count_parameters(module.model),
        "precision": precision,
    }


def fit_scanlocnet(
    *,
    model_cfg: Mapping[str, Any],
    grid: PoseGrid,
    stream: StreamSpec,
    val_dataset: Path,
    out_dir: Path,
    epochs: int,
    batch_size: int,
    lr: float,
    weight_decay: float,
    pct_start: float,
    trainer_cfg: Mapping[str, Any] | None,
    max_val: int | None = None,
    checkpoint_dir: Path | None = None,
    real_scans: RealScans | None = None,
) -> dict[str, Any]:
    """Train ScanLocNet for `grid` on the stream and validate on `val_dataset`'s validation
    split, resuming from checkpoint_dir/<key>/last.ckpt where there is one (see the module
    docstring; checkpoint_dir None: no checkpoints kept). Returns the metrics; raises
    TrainingStopped on SIGINT or SIGTERM. `real_scans`: real scans mixed into every epoch.
    """
    if epochs < 1 or batch_size < 2 or stream.scans_per_epoch < batch_size:
        raise ValueError(
            f"need epochs >= 1, batch_size >= 2 and scans_per_epoch >= batch_size, got {epochs}, "
            f"{batch_size}, {stream.scans_per_epoch}"
        )
    data = load_scan_dataset(val_dataset)
    rows = np.flatnonzero(data.is_val)[: max_val or None]
    val_ranges = torch.from_numpy(np.ascontiguousarray(data.ranges[rows], dtype=np.float32))
    val_poses = np.asarray(data.poses[rows], dtype=np.float64)
    if val_ranges.shape[1] != stream.num_beams:
        raise ValueError(
            f"{val_dataset}/ranges.npy: {val_ranges.shape[1]} beams, the stream's sensor has "
            f"{stream.num_beams}"
        )
    cfg = dict(model_cfg) | {"grid": grid.to_dict(), "num_beams": stream.num_beams}
    cfg.setdefault("range_max", float(stream.sensor["range_max"]))
    kwargs = trainer_arguments(trainer_cfg)
    config = {
        "model_cfg": cfg,
        "epochs": epochs,
        "batch_size": batch_size,
        "lr": lr,
        "weight_decay": weight_decay,
        "pct_start": pct_start,
        "trainer_cfg": dict(trainer_cfg or {}),
        "precision": kwargs["precision"],  # "auto" resolved on this machine
        "max_val": max_val,
    }
    if real_scans is not None:  # absent otherwise: the keys of earlier runs stay valid
        config["real_scans"] = {"share": real_scans.share, "digest": real_scans.digest}
    key = "" if checkpoint_dir is None else run_key(config, stream, Path(val_dataset))
    saver: EpochCheckpoint | None = None
    try:
        with stop_on_signals(), run_dir(checkpoint_dir, key) as folder:
            keep_freed_memory()
            L.seed_everything(stream.seed, workers=True, verbose=False)
            model = build_model(cfg)
            steps_per_epoch = stream.scans_per_epoch // batch_size
            module = ScanLocModule(
                model, lr, weight_decay, epochs * steps_per_epoch, pct_start, val_ranges, val_poses
            )
            saver = EpochCheckpoint(folder / "last.ckpt", module.print_epoch)
            trainer = L.Trainer(
                max_epochs=epochs,
                logger=False,
                callbacks=[saver],
                default_root_dir=folder,
                num_sanity_val_steps=0,
                limit_val_batches=0,
                enable_progress_bar=interactive(),
                enable_model_summary=False,
                **kwargs,
            )
            resume = saver.path if saver.path.is_file() else None
            with ScanStream(stream) as scans:
                batches = _Epochs(scans, grid, batch_size, stream.seed, real_scans)
                trainer.fit(module, train_dataloaders=batches, ckpt_path=resume, weights_only=True)
            if len(module.history) != epochs:
                raise RuntimeError(
                    f"{saver.path}: holds {len(module.history)} epochs, expected {epochs}"
                )
            metrics = run_metrics(module, stream.scans_per_epoch, batch_size, kwargs["precision"])
            if real_scans is not None:
                metrics |= {"real_scans": len(real_scans.ranges), "real_share": real_scans.share}
            with atomic_dir(out_dir) as tmp:
                save_model(tmp / "model.pt", cfg, model.state_dict())
                write_history(tmp / "history.csv", module.history)
                write_json(tmp / "metrics.json", metrics)
    except TrainingStopped as stop:
        stop.epochs = epochs
        if checkpoint_dir is not None and saver is not None and saver.path.is_file():
            stop.checkpoint, stop.epochs_done = saver.path, saver.epochs_saved
        raise
    metrics["epoch_s"] = round(statistics.median(module.epoch_seconds), 4)
    metrics["train_s"] = round(sum(module.epoch_seconds), 2)
    metrics["device"] = training_device(uses_cuda(str(kwargs["accelerator"])))
    return metrics
